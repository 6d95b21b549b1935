//! `trimctl info FILE`: what a point cloud, mesh or path file holds, as one JSON object on stdout.
//!
//! Keys: `file`; `kind` ("points", "mesh" or "path"); `points` (points, mesh vertices or path
//! points); `has_normals` (whether the file stores a normal per point: meshes and paths never
//! do); `bounds_min` and `bounds_max` (`[x, y, z]` in the file's units, millimetres for trimctl's
//! own files). Paths add `contours`; meshes add `triangles`,
//! `degenerate_triangles` and `area_mm2`.
//!
//! The kind comes from the extension: `.csv` → path, `.stl` → mesh, `.ply` → mesh if it has
//! faces, else points; `.pcd`, `.xyz`, `.txt` → points. A file that cannot be read is an error
//! (exit 1) naming the file and the line or element; so is a point file with no points
//! ("FILE: no points").

use std::path::PathBuf;

use serde_json::{Value, json};
use trim_geom::Aabb;
use trim_geom::formats::{Geometry, read_geometry};

/// Arguments of `trimctl info`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The file: .ply, .pcd, .xyz/.txt (points), .stl or .ply with faces (mesh), .csv (path).
    pub file: PathBuf,
}

/// `[x, y, z]` of the box corners, or nulls for an empty cloud.
fn bounds_json(bounds: Option<Aabb>) -> (Value, Value) {
    match bounds {
        Some(b) => (
            json!([b.min.x, b.min.y, b.min.z]),
            json!([b.max.x, b.max.y, b.max.z]),
        ),
        None => (Value::Null, Value::Null),
    }
}

/// The JSON description of what a file holds.
fn describe(geometry: &Geometry) -> Value {
    match geometry {
        Geometry::Points(cloud) => {
            let (min, max) = bounds_json(cloud.bounds());
            json!({
                "kind": "points",
                "points": cloud.len(),
                "has_normals": cloud.has_normals(),
                "bounds_min": min,
                "bounds_max": max,
            })
        }
        Geometry::Mesh(mesh) => {
            let (min, max) = bounds_json(Some(mesh.bounds()));
            json!({
                "kind": "mesh",
                "points": mesh.vertices().len(),
                "has_normals": false,
                "bounds_min": min,
                "bounds_max": max,
                "triangles": mesh.triangles().len(),
                "degenerate_triangles": mesh.degenerate_triangles(),
                "area_mm2": mesh.area(),
            })
        }
        Geometry::Path(path) => {
            let (min, max) = bounds_json(Some(path.bounds()));
            json!({
                "kind": "path",
                "points": path.num_points(),
                "has_normals": false,
                "bounds_min": min,
                "bounds_max": max,
                "contours": path.len(),
            })
        }
    }
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    let geometry = read_geometry(&args.file)?;
    let mut info = describe(&geometry);
    if let Value::Object(map) = &mut info {
        map.insert(
            "file".into(),
            Value::String(args.file.display().to_string()),
        );
    }
    println!("{}", serde_json::to_string(&info)?);
    Ok(())
}
