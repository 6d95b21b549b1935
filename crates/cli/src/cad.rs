//! The CAD model as an oriented point cloud, one loader for `trimctl run` (`part.cad`) and
//! `trimctl register` (`--cad`): an STL or PLY mesh is sampled area-weighted; a point cloud
//! (PLY/PCD/XYZ) is taken with its normals, and one without normals is refused or given normals
//! estimated outward from its centroid, as the caller says.

use std::path::Path;

use anyhow::bail;
use trim_geom::formats::{Geometry, read_geometry};
use trim_geom::normals::{Orientation, estimate_normals};
use trim_geom::{PointCloud, Vector3};

/// Neighbours for estimating the normals of a CAD point cloud given without them.
const CAD_NORMAL_NEIGHBOURS: usize = 12;

/// What a CAD point cloud without normals gets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WithoutNormals {
    /// Refused: the caller wants the mesh instead.
    Refuse,
    /// Normals estimated, oriented outward from the cloud's centroid.
    Estimate,
}

/// How to load a CAD model.
#[derive(Debug, Clone, Copy)]
pub struct CadOptions<'a> {
    /// The setting that names the file, in messages (`part.cad`, `--cad`).
    pub key: &'a str,
    /// Points sampled from a mesh.
    pub sample_points: usize,
    /// The seed of the area-weighted sampling (fixed: the same CAD gives the same samples).
    pub seed: u64,
    /// A point cloud without normals.
    pub without_normals: WithoutNormals,
}

/// The CAD model in `file` as a point cloud with outward normals.
pub fn load_cad(file: &Path, options: &CadOptions<'_>) -> anyhow::Result<PointCloud> {
    match read_geometry(file)? {
        Geometry::Mesh(mesh) => Ok(mesh.sample_area_weighted(options.sample_points, options.seed)),
        Geometry::Points(cloud) if cloud.has_normals() => Ok(cloud),
        Geometry::Points(cloud) => match options.without_normals {
            WithoutNormals::Refuse => bail!(
                "{}: a CAD point cloud needs outward normals (nx ny nz); give the STL mesh instead",
                file.display()
            ),
            WithoutNormals::Estimate => with_outward_normals(&cloud),
        },
        Geometry::Path(_) => bail!(
            "{}: {} is a path CSV; give the CAD model (STL/PLY mesh or point cloud)",
            file.display(),
            options.key
        ),
    }
}

/// `cloud` with estimated normals, oriented from the centroid outward: right for closed,
/// convex-ish parts; point-to-plane residuals do not depend on the sign, visibility culling
/// does.
fn with_outward_normals(cloud: &PointCloud) -> anyhow::Result<PointCloud> {
    let centre = cloud.bounds().map(|b| b.center()).unwrap_or_default();
    let normals = estimate_normals(
        cloud.points(),
        CAD_NORMAL_NEIGHBOURS,
        Orientation::AlongReference(Vector3::z()),
    )?;
    let oriented = cloud
        .points()
        .iter()
        .zip(normals)
        .map(|(p, n)| if n.dot(&(p - centre)) < 0.0 { -n } else { n })
        .collect();
    Ok(PointCloud::with_normals(cloud.points().to_vec(), oriented)?)
}
