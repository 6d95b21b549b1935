//! Geometry core of trimctl.
//!
//! Everything here is in millimetres and radians, in the frame its name says (`point_in_scan`,
//! `scan_from_cad`). Transforms are named `b_from_a`: they take coordinates in frame `a` to frame
//! `b`, and compose right to left (`c_from_a = c_from_b * b_from_a`).
//!
//! - [`cloud`]: point clouds with optional unit normals.
//! - [`cancel`]: cooperative cancellation of long work (a per-thread flag the loops check).
//! - [`path`]: trimming paths made of contours with ids and feature vectors (the path CSV contract).
//! - [`transform`]: rigid and similarity transforms on nalgebra.
//! - [`kdtree`]: nearest, k-nearest and radius queries on kiddo.
//! - [`normals`], [`voxel`], [`crop`]: point-cloud processing.
//! - [`mesh`]: triangle meshes on parry3d, area-weighted sampling, point-to-mesh distance.
//! - [`formats`]: PLY, PCD, XYZ, STL and path CSV readers and writers.
//! - [`fs`]: writing a file whole or not at all.

pub mod cancel;
pub mod cloud;
pub mod crop;
pub mod error;
pub mod formats;
pub mod fs;
pub mod kdtree;
pub mod math;
pub mod mesh;
pub mod normals;
pub mod number;
pub mod path;
pub mod stats;
pub mod transform;
pub mod voxel;

pub use cloud::{Aabb, PointCloud};
pub use error::{GeomError, Location, Result};
pub use kdtree::{KdTree, Neighbour};
pub use math::{Point3, Rigid3, Similarity3, UnitVector3, Vector3};
pub use number::Num;
pub use path::{Contour, ContourId, Path};
