//! File formats: PLY, PCD and XYZ point clouds, STL and PLY meshes, and the path CSV.
//!
//! Every reader has a twin taking the file's bytes and the name to put in errors
//! (`read_points_from_bytes(bytes, name)`), so parsers are tested and fuzzed without touching the
//! disk; the file-based functions read the whole file and call it. Writers likewise have
//! `encode_*` twins returning the bytes.
//!
//! Errors name the file and the place: the 1-based line for text, the 0-based element (vertex,
//! point, facet) for binary bodies. A truncated binary body says how many elements the header
//! declared and how many were found. Readers never panic and never drop a row: a row they cannot
//! use is an error. Header counts are never trusted for allocation: capacity is capped by the
//! bytes that remain.
//!
//! Coordinates are read as written (trimctl works in millimetres; a file in metres stays in
//! metres, the caller scales it).

mod path_csv;
mod pcd;
mod ply;
mod stl;
mod text;
mod xyz;

use std::path::Path as FsPath;

use crate::cloud::PointCloud;
use crate::error::{GeomError, Location, Result};
use crate::mesh::Mesh;
use crate::path::Path;

pub use ply::PlyScalar;
pub use text::warn_if_unterminated;

/// The encoding of a PLY file body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlyEncoding {
    /// One element per text line.
    Ascii,
    /// Packed binary, little-endian.
    BinaryLittleEndian,
    /// Packed binary, big-endian.
    BinaryBigEndian,
}

/// The encoding of a PCD file body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PcdEncoding {
    /// One point per text line.
    Ascii,
    /// Packed binary, little-endian, point after point.
    Binary,
}

/// What a file holds, for readers that accept more than one kind ([`read_geometry`]).
#[derive(Debug, Clone, PartialEq)]
pub enum Geometry {
    /// A point cloud (PLY without faces, PCD, XYZ).
    Points(PointCloud),
    /// A triangle mesh (STL, PLY with faces).
    Mesh(Box<Mesh>),
    /// A trimming path (path CSV).
    Path(Path),
}

/// The formats trimctl knows, by file extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Ply,
    Pcd,
    Xyz,
    Stl,
    PathCsv,
}

const KNOWN_EXTENSIONS: &str = ".ply, .pcd, .xyz, .txt, .stl, .csv";

fn format_of(name: &FsPath) -> Result<Format> {
    let ext = name
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    match ext.as_deref() {
        Some("ply") => Ok(Format::Ply),
        Some("pcd") => Ok(Format::Pcd),
        Some("xyz" | "txt") => Ok(Format::Xyz),
        Some("stl") => Ok(Format::Stl),
        Some("csv") => Ok(Format::PathCsv),
        Some(other) => Err(GeomError::UnsupportedFormat {
            path: name.into(),
            message: format!("unknown extension .{other} (known: {KNOWN_EXTENSIONS})"),
        }),
        None => Err(GeomError::UnsupportedFormat {
            path: name.into(),
            message: format!("no file extension to tell the format by (known: {KNOWN_EXTENSIONS})"),
        }),
    }
}

/// An error about an in-memory value built from a file, placed in that file: a non-finite value
/// by its element, anything else about the file as a whole (at its end, once all was read).
fn in_file(name: &FsPath, e: GeomError) -> GeomError {
    match e {
        GeomError::NonFinite { what, index } => GeomError::parse(
            name,
            Location::Element(index),
            format!("{what} {index} is not finite"),
        ),
        GeomError::ZeroVector { index, .. } => {
            let message = e.to_string();
            GeomError::parse(name, Location::Element(index), message)
        }
        e @ (GeomError::Parse { .. }
        | GeomError::Io { .. }
        | GeomError::UnsupportedFormat { .. }
        | GeomError::NoPoints { .. }) => e,
        other => GeomError::parse(name, Location::End, other.to_string()),
    }
}

pub(crate) use crate::math::unit_or_none;

fn read_file(path: &FsPath) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| GeomError::io(path, e))
}

fn write_file(path: &FsPath, bytes: &[u8]) -> Result<()> {
    crate::fs::write_atomic(path, bytes).map_err(|e| GeomError::io(path, e))
}

/// Reads a point cloud, by extension: `.ply` (ascii or binary; faces ignored), `.pcd` (ascii or
/// binary), `.xyz` or `.txt` (`x y z [nx ny nz]` per line). A `.stl` is refused with a pointer to
/// [`read_mesh`]; other extensions are refused by name. A file with no points is refused
/// ([`GeomError::NoPoints`], naming it): every use of a cloud needs points.
pub fn read_points(path: &FsPath) -> Result<PointCloud> {
    match format_of(path)? {
        Format::Ply | Format::Pcd | Format::Xyz => read_points_from_bytes(&read_file(path)?, path),
        other => Err(wrong_kind(path, other, "a point cloud")),
    }
}

/// [`read_points`] on bytes already in memory; `name` gives the format (by extension) and is the
/// file named in errors.
pub fn read_points_from_bytes(bytes: &[u8], name: &FsPath) -> Result<PointCloud> {
    let cloud = match format_of(name)? {
        Format::Ply => ply::parse(bytes, name)?.cloud,
        Format::Pcd => pcd::parse(bytes, name)?,
        Format::Xyz => xyz::parse(bytes, name)?,
        other => return Err(wrong_kind(name, other, "a point cloud")),
    };
    non_empty(cloud, name)
}

/// The cloud, or [`GeomError::NoPoints`] naming the file when it has none.
fn non_empty(cloud: PointCloud, name: &FsPath) -> Result<PointCloud> {
    if cloud.is_empty() {
        Err(GeomError::NoPoints { path: name.into() })
    } else {
        Ok(cloud)
    }
}

/// The error for a file whose format holds another kind of data than the one asked for.
fn wrong_kind(name: &FsPath, format: Format, wanted: &str) -> GeomError {
    let message = match format {
        Format::Stl => format!(
            "an STL file is a mesh, not {wanted}: read it with read_mesh (and sample it with \
             Mesh::sample_area_weighted)"
        ),
        Format::PathCsv => {
            format!("a .csv file is a trimming path, not {wanted}: read it with read_path")
        }
        Format::Pcd | Format::Xyz => format!(
            "a point-cloud format, not {wanted}: read it with read_points (meshes are read from \
             .stl or .ply with faces)"
        ),
        Format::Ply => format!("a PLY file does not hold {wanted}"),
    };
    GeomError::UnsupportedFormat {
        path: name.into(),
        message,
    }
}

/// Reads a triangle mesh: `.stl` (ascii or binary) or `.ply` with a `face` element (polygons are
/// fan-triangulated). Other extensions are refused by name.
pub fn read_mesh(path: &FsPath) -> Result<Mesh> {
    match format_of(path)? {
        Format::Stl | Format::Ply => read_mesh_from_bytes(&read_file(path)?, path),
        other => Err(wrong_kind(path, other, "a mesh")),
    }
}

/// [`read_mesh`] on bytes already in memory; `name` gives the format and is named in errors.
pub fn read_mesh_from_bytes(bytes: &[u8], name: &FsPath) -> Result<Mesh> {
    match format_of(name)? {
        Format::Stl => stl::parse(bytes, name),
        Format::Ply => ply::into_mesh(ply::parse(bytes, name)?, name),
        other => Err(wrong_kind(name, other, "a mesh")),
    }
}

/// Reads a trimming path from a path CSV (DESIGN.md "Path CSV").
///
/// The header names the columns `contour,x,y,z,u,v,w`, in any order; extra columns are ignored;
/// a missing one is an error naming it. One row per point, the rows of a contour contiguous and
/// in path order. Errors name the line (and the column for a bad cell): a non-numeric or
/// non-finite cell, a contour id that reappears after another contour (both lines named), a
/// contour of one point or of zero length.
pub fn read_path(path: &FsPath) -> Result<Path> {
    read_path_from_bytes(&read_file(path)?, path)
}

/// [`read_path`] on bytes already in memory; `name` is the file named in errors.
pub fn read_path_from_bytes(bytes: &[u8], name: &FsPath) -> Result<Path> {
    path_csv::parse(bytes, name)
}

/// Reads whatever the file holds, by extension: `.csv` → path, `.stl` → mesh, `.ply` → mesh if it
/// has at least one face, else points; `.pcd`, `.xyz`, `.txt` → points. A point cloud with no
/// points is refused as in [`read_points`].
pub fn read_geometry(path: &FsPath) -> Result<Geometry> {
    format_of(path)?;
    read_geometry_from_bytes(&read_file(path)?, path)
}

/// [`read_geometry`] on bytes already in memory; `name` gives the format and is named in errors.
pub fn read_geometry_from_bytes(bytes: &[u8], name: &FsPath) -> Result<Geometry> {
    match format_of(name)? {
        Format::PathCsv => path_csv::parse(bytes, name).map(Geometry::Path),
        Format::Stl => stl::parse(bytes, name).map(|m| Geometry::Mesh(Box::new(m))),
        Format::Ply => {
            let data = ply::parse(bytes, name)?;
            if data.faces.is_empty() {
                non_empty(data.cloud, name).map(Geometry::Points)
            } else {
                ply::into_mesh(data, name).map(|m| Geometry::Mesh(Box::new(m)))
            }
        }
        Format::Pcd => non_empty(pcd::parse(bytes, name)?, name).map(Geometry::Points),
        Format::Xyz => non_empty(xyz::parse(bytes, name)?, name).map(Geometry::Points),
    }
}

/// Writes a point cloud in the format its extension names, so that [`read_points`] reads it
/// back exactly: `.ply` binary little-endian PLY, `.pcd` binary PCD, `.xyz` or `.txt` XYZ text
/// (all double precision, normals when the cloud has them). A `.stl` or `.csv` (a mesh or a path,
/// not a cloud) and unknown extensions are refused by name, and so is a cloud with no points,
/// which [`read_points`] would refuse: nothing is written then.
pub fn write_points(path: &FsPath, cloud: &PointCloud) -> Result<()> {
    let format = format_of(path)?;
    if cloud.is_empty() {
        return Err(GeomError::invalid(
            "points",
            format!(
                "{}: no points to write (a cloud file with none cannot be read back)",
                path.display()
            ),
        ));
    }
    match format {
        Format::Ply => write_ply(path, cloud, PlyEncoding::BinaryLittleEndian),
        Format::Pcd => write_pcd(path, cloud, PcdEncoding::Binary),
        Format::Xyz => write_xyz(path, cloud),
        Format::Stl => Err(not_a_cloud(path, "stl", "a mesh")),
        Format::PathCsv => Err(not_a_cloud(path, "csv", "a trimming path")),
    }
}

/// The error for writing a cloud to a file whose extension holds another kind of data.
fn not_a_cloud(path: &FsPath, ext: &str, holds: &str) -> GeomError {
    GeomError::UnsupportedFormat {
        path: path.into(),
        message: format!(
            "a .{ext} file holds {holds}, not a point cloud: write a cloud as .ply, .pcd, .xyz \
             or .txt"
        ),
    }
}

/// Writes a point cloud as PLY with double-precision `x y z` (and `nx ny nz` when the cloud has
/// normals), so coordinates round-trip exactly.
pub fn write_ply(path: &FsPath, cloud: &PointCloud, encoding: PlyEncoding) -> Result<()> {
    write_file(path, &encode_ply(cloud, encoding, PlyScalar::Double))
}

/// The bytes of a PLY file of `cloud`, with coordinates (and normals) stored as `scalar`.
/// `PlyScalar::Float` rounds each value to the nearest `f32`.
#[must_use]
pub fn encode_ply(cloud: &PointCloud, encoding: PlyEncoding, scalar: PlyScalar) -> Vec<u8> {
    ply::encode(cloud, encoding, scalar)
}

/// Writes a point cloud as PCD v0.7 with double-precision (`SIZE 8`, `TYPE F`) fields `x y z`
/// and, when the cloud has normals, `normal_x normal_y normal_z`.
pub fn write_pcd(path: &FsPath, cloud: &PointCloud, encoding: PcdEncoding) -> Result<()> {
    write_file(path, &encode_pcd(cloud, encoding))
}

/// The bytes of a PCD file of `cloud` (see [`write_pcd`]).
#[must_use]
pub fn encode_pcd(cloud: &PointCloud, encoding: PcdEncoding) -> Vec<u8> {
    pcd::encode(cloud, encoding)
}

/// Writes a point cloud as XYZ text: `x y z` or `x y z nx ny nz` per line, shortest round-trip
/// decimal for each value.
pub fn write_xyz(path: &FsPath, cloud: &PointCloud) -> Result<()> {
    write_file(path, &encode_xyz(cloud))
}

/// The bytes of an XYZ file of `cloud` (see [`write_xyz`]).
#[must_use]
pub fn encode_xyz(cloud: &PointCloud) -> Vec<u8> {
    xyz::encode(cloud)
}

/// Writes a mesh as binary STL (via stl_io). STL stores `f32`: each coordinate is rounded to the
/// nearest `f32`. Facet normals are the right-hand-rule face normals (zero for degenerate
/// triangles).
pub fn write_stl(path: &FsPath, mesh: &Mesh) -> Result<()> {
    let bytes = encode_stl(mesh).map_err(|e| match e {
        GeomError::InvalidArgument { message, .. } => {
            GeomError::parse(path, Location::Header, message)
        }
        other => other,
    })?;
    write_file(path, &bytes)
}

/// The bytes of a binary STL file of `mesh` (see [`write_stl`]). Fails only for a mesh of more
/// than `u32::MAX` triangles, which binary STL cannot count.
pub fn encode_stl(mesh: &Mesh) -> Result<Vec<u8>> {
    stl::encode(mesh)
}

/// Writes a path as a path CSV: header `contour,x,y,z,u,v,w`, one row per point, contours in
/// order, each value in the shortest decimal that reads back to the same `f64`.
pub fn write_path(path: &FsPath, trim_path: &Path) -> Result<()> {
    write_file(path, &encode_path(trim_path))
}

/// The bytes of a path CSV of `trim_path` (see [`write_path`]).
#[must_use]
pub fn encode_path(trim_path: &Path) -> Vec<u8> {
    path_csv::encode(trim_path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::Vector3;

    /// What `f` logs through tracing, as plain text.
    fn logged(f: impl FnOnce()) -> String {
        use std::sync::{Arc, Mutex};
        #[derive(Clone, Default)]
        struct Buffer(Arc<Mutex<Vec<u8>>>);
        impl std::io::Write for Buffer {
            fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
                self.0
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .extend_from_slice(bytes);
                Ok(bytes.len())
            }
            fn flush(&mut self) -> std::io::Result<()> {
                Ok(())
            }
        }
        let buffer = Buffer::default();
        let writer = buffer.clone();
        let subscriber = tracing_subscriber::fmt()
            .with_ansi(false)
            .with_writer(move || writer.clone())
            .finish();
        tracing::subscriber::with_default(subscriber, f);
        let bytes = buffer.0.lock().unwrap_or_else(|e| e.into_inner()).clone();
        String::from_utf8_lossy(&bytes).into_owned()
    }

    #[test]
    fn a_text_file_without_a_last_line_end_reads_with_a_warning_naming_it() {
        let name = FsPath::new("cam/path.csv");
        let whole = "contour,x,y,z,u,v,w\n1,0,0,0,0,0,1\n1,1,0,0,0,0,1\n1,1,1,0,0,0,1\n";
        // Cut after the last row's last digit, its line end lost: a cut inside a number reads
        // the same way, with the number short.
        let cut = &whole[..whole.len() - 1];
        let log = logged(|| {
            read_path_from_bytes(cut.as_bytes(), name).expect("a cut file still reads");
        });
        assert!(
            log.contains("WARN")
                && log.contains("cam/path.csv: line 4, the last, has no line end")
                && log.contains("its last value may be short"),
            "{log}"
        );
        let log = logged(|| {
            read_path_from_bytes(whole.as_bytes(), name).expect("reads");
        });
        assert!(log.is_empty(), "{log}");
        let log = logged(|| {
            read_points_from_bytes(b"0 0 0\n1 0 0\n0 1 0\n2 2 2.5", FsPath::new("scan.xyz"))
                .expect("reads");
        });
        assert!(
            log.contains("scan.xyz: line 4, the last, has no line end"),
            "{log}"
        );
        // A last line that is only a comment or blank is no cut value.
        assert!(!warn_if_unterminated(b"0 0 0\n# end", FsPath::new("a.xyz")));
        assert!(!warn_if_unterminated(b"0 0 0\n  ", FsPath::new("a.xyz")));
        assert!(!warn_if_unterminated(b"", FsPath::new("a.xyz")));
    }

    #[test]
    fn unit_or_none_survives_huge_and_refuses_zero_or_tiny() {
        let huge = unit_or_none(&Vector3::new(0.0, 1e308, 1e308), 1e-12).unwrap();
        assert!((huge - Vector3::new(0.0, 1.0, 1.0).normalize()).norm() < 1e-15);
        assert!(unit_or_none(&Vector3::zeros(), 1e-12).is_none());
        assert!(unit_or_none(&Vector3::new(1e-13, 0.0, 0.0), 1e-12).is_none());
        assert!(unit_or_none(&Vector3::new(f64::NAN, 1.0, 0.0), 1e-12).is_none());
        assert_eq!(
            unit_or_none(&Vector3::new(0.0, -3.0, 0.0), 1e-12),
            Some(-Vector3::y())
        );
    }

    #[test]
    fn dispatch_refuses_unknown_and_stl_as_points() {
        let e = read_points_from_bytes(b"", FsPath::new("a.obj")).unwrap_err();
        assert!(
            e.to_string().contains("a.obj") && e.to_string().contains(".obj"),
            "{e}"
        );
        let e = read_points_from_bytes(b"", FsPath::new("noext")).unwrap_err();
        assert!(e.to_string().contains("no file extension"), "{e}");
        let e =
            read_points_from_bytes(b"solid x\nendsolid x\n", FsPath::new("part.STL")).unwrap_err();
        assert!(e.to_string().contains("read_mesh"), "{e}");
        let e = read_mesh_from_bytes(b"1 2 3\n", FsPath::new("a.xyz")).unwrap_err();
        assert!(e.to_string().contains("not a mesh"), "{e}");
    }
}
