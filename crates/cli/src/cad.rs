//! The CAD model as an oriented point cloud, the one loader of `trimctl run` (`part.cad`) and
//! `trimctl register` (`--cad`): an STL or PLY mesh is sampled area-weighted with one fixed seed
//! (the same CAD gives the same samples in both); a point cloud (PLY/PCD/XYZ) must carry its
//! outward normals.
//!
//! A cloud without normals is refused rather than given estimated ones: registration culls the
//! CAD faces turned away from the scanner by the normals' sign, and no local rule orients them
//! right on a core (outward from the centroid turns half of every hole wall inward).

use std::path::Path;

use anyhow::bail;
use trim_geom::PointCloud;
use trim_geom::formats::{Geometry, read_geometry};

/// The seed of the area-weighted sampling of a CAD mesh.
pub const CAD_SAMPLE_SEED: u64 = 1;

/// The CAD model in `file` as a point cloud with outward normals, `sample_points` points when
/// it is a mesh. `key` names the setting that gave the file (`part.cad`, `--cad`) in messages.
pub fn load_cad(file: &Path, key: &str, sample_points: usize) -> anyhow::Result<PointCloud> {
    match read_geometry(file)? {
        Geometry::Mesh(mesh) => Ok(mesh.sample_area_weighted(sample_points, CAD_SAMPLE_SEED)),
        Geometry::Points(cloud) if cloud.has_normals() => Ok(cloud),
        Geometry::Points(_) => bail!(
            "{}: {key} is a point cloud without normals; registration needs outward normals (nx ny nz) to tell the faces the scanner sees: give the STL/PLY mesh, or the cloud with its normals",
            file.display()
        ),
        Geometry::Path(_) => bail!(
            "{}: {key} is a path CSV; give the CAD model (STL/PLY mesh or point cloud with normals)",
            file.display()
        ),
    }
}
