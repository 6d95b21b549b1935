//! Round trips through every format, the real data files in tests/data, and the error for
//! each kind of bad input (the message must name the file and the line or element).
#![expect(
    clippy::unwrap_used,
    reason = "fixture helpers: a fixture that fails to build is a failed test"
)]

use std::path::{Path as FsPath, PathBuf};

use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_geom::formats::{
    self, Geometry, PcdEncoding, PlyEncoding, PlyScalar, encode_pcd, encode_ply, encode_stl,
    read_geometry, read_mesh, read_mesh_from_bytes, read_path, read_points, read_points_from_bytes,
};
use trim_geom::mesh::Mesh;
use trim_geom::{Contour, Path, Point3, PointCloud, Vector3};

/// Normals are renormalised when read: a unit normal comes back within a few ulps.
const NORMAL_TOL: f64 = 1e-15;

fn cloud(n: usize, normals: bool, seed: u64) -> PointCloud {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let points: Vec<Point3> = (0..n)
        .map(|_| {
            Point3::new(
                rng.random_range(-500.0..500.0),
                rng.random_range(-500.0..500.0),
                rng.random_range(-1e-3..1e-3),
            )
        })
        .collect();
    if normals {
        let ns = (0..n)
            .map(|_| {
                Vector3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(0.1..1.0),
                )
            })
            .collect();
        PointCloud::with_normals(points, ns).unwrap()
    } else {
        PointCloud::new(points).unwrap()
    }
}

/// The cloud with every value rounded to f32, as a float file stores it.
fn rounded_to_f32(c: &PointCloud) -> Vec<Point3> {
    c.points()
        .iter()
        .map(|p| p.map(|v| f64::from(v as f32)))
        .collect()
}

fn assert_same(read: &PointCloud, written: &PointCloud) {
    assert_eq!(read.points(), written.points());
    assert_eq!(read.has_normals(), written.has_normals());
    if let (Some(a), Some(b)) = (read.normals(), written.normals()) {
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).norm() < NORMAL_TOL, "{x} vs {y}");
        }
    }
}

fn data(rel: &str) -> PathBuf {
    FsPath::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data")
        .join(rel)
}

fn err_points(bytes: &[u8], name: &str) -> String {
    read_points_from_bytes(bytes, FsPath::new(name))
        .unwrap_err()
        .to_string()
}

fn err_mesh(bytes: &[u8], name: &str) -> String {
    read_mesh_from_bytes(bytes, FsPath::new(name))
        .unwrap_err()
        .to_string()
}

fn assert_starts(message: &str, prefix: &str) {
    assert!(
        message.starts_with(prefix),
        "expected a message starting {prefix:?}, got {message:?}"
    );
}

// ---------------------------------------------------------------------------------------------
// Round trips

#[test]
fn ply_round_trips_in_every_encoding_and_precision() {
    let dir = tempfile::tempdir().unwrap();
    for normals in [false, true] {
        let c = cloud(257, normals, 1);
        for encoding in [
            PlyEncoding::Ascii,
            PlyEncoding::BinaryLittleEndian,
            PlyEncoding::BinaryBigEndian,
        ] {
            // Double, through the file API.
            let file = dir.path().join(format!("c_{normals}_{encoding:?}.ply"));
            formats::write_ply(&file, &c, encoding).unwrap();
            assert_same(&read_points(&file).unwrap(), &c);
            // Float, through bytes: every value is the nearest f32.
            let bytes = encode_ply(&c, encoding, PlyScalar::Float);
            let back = read_points_from_bytes(&bytes, FsPath::new("f.ply")).unwrap();
            assert_eq!(back.points(), rounded_to_f32(&c).as_slice(), "{encoding:?}");
            if let (Some(a), Some(b)) = (back.normals(), c.normals()) {
                for (x, y) in a.iter().zip(b) {
                    assert!((x - y).norm() < 1e-6, "{encoding:?}: {x} vs {y}");
                }
            }
        }
    }
}

#[test]
fn ply_binary_layouts_differ_by_endianness_only() {
    let c = cloud(3, false, 2);
    let le = encode_ply(&c, PlyEncoding::BinaryLittleEndian, PlyScalar::Double);
    let be = encode_ply(&c, PlyEncoding::BinaryBigEndian, PlyScalar::Double);
    let body = |b: &[u8]| {
        let at = b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        b[at..].to_vec()
    };
    let (le, be) = (body(&le), body(&be));
    assert_eq!(le.len(), 3 * 3 * 8);
    assert_eq!(le[..8], c.points()[0].x.to_le_bytes());
    assert_eq!(be[..8], c.points()[0].x.to_be_bytes());
}

#[test]
fn pcd_and_xyz_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    for normals in [false, true] {
        let c = cloud(300, normals, 3);
        for encoding in [PcdEncoding::Ascii, PcdEncoding::Binary] {
            let file = dir.path().join(format!("c_{normals}_{encoding:?}.pcd"));
            formats::write_pcd(&file, &c, encoding).unwrap();
            assert_same(&read_points(&file).unwrap(), &c);
        }
        for ext in ["xyz", "txt"] {
            let file = dir.path().join(format!("c_{normals}.{ext}"));
            formats::write_xyz(&file, &c).unwrap();
            assert_same(&read_points(&file).unwrap(), &c);
        }
    }
}

/// `write_points` writes the format its extension names, which `read_points` reads back exactly;
/// a mesh or path extension, an unknown one, or an empty cloud is refused and nothing is written.
#[test]
fn write_points_writes_the_format_its_extension_names_and_refuses_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let c = cloud(40, true, 4);
    for (ext, starts) in [
        ("ply", &b"ply\nformat binary_little_endian"[..]),
        ("PCD", &b"# .PCD"[..]),
        ("xyz", &b""[..]),
        ("txt", &b""[..]),
    ] {
        let file = dir.path().join(format!("c.{ext}"));
        formats::write_points(&file, &c).unwrap();
        let bytes = std::fs::read(&file).unwrap();
        assert!(bytes.starts_with(starts), ".{ext}: {:?}", &bytes[..20]);
        if starts.is_empty() {
            // Text: the first line is the first point's six numbers.
            let first = std::str::from_utf8(&bytes).unwrap().lines().next().unwrap();
            assert_eq!(first.split_whitespace().count(), 6, ".{ext}: {first}");
        }
        assert_same(&read_points(&file).unwrap(), &c);
    }
    for (ext, says) in [
        ("stl", "holds a mesh, not a point cloud"),
        ("csv", "holds a trimming path, not a point cloud"),
        ("obj", "unknown extension .obj"),
    ] {
        let file = dir.path().join(format!("c.{ext}"));
        let e = formats::write_points(&file, &c).unwrap_err().to_string();
        assert!(e.contains(says) && e.contains(&format!("c.{ext}")), "{e}");
        assert!(!file.exists(), ".{ext} was written");
    }
    let file = dir.path().join("empty.ply");
    let e = formats::write_points(&file, &PointCloud::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("empty.ply: no points to write"), "{e}");
    assert!(!file.exists());
}

/// An empty cloud can be written, but reading a file with no points is refused, naming it.
#[test]
fn empty_clouds_are_refused_when_read() {
    let empty = PointCloud::default();
    for (bytes, name) in [
        (
            encode_ply(&empty, PlyEncoding::Ascii, PlyScalar::Double),
            "e.ply",
        ),
        (
            encode_ply(&empty, PlyEncoding::BinaryBigEndian, PlyScalar::Float),
            "e.ply",
        ),
        (encode_pcd(&empty, PcdEncoding::Binary), "e.pcd"),
        (formats::encode_xyz(&empty), "e.xyz"),
    ] {
        let e = read_points_from_bytes(&bytes, FsPath::new(name)).unwrap_err();
        assert!(
            matches!(&e, trim_geom::GeomError::NoPoints { path } if path == FsPath::new(name)),
            "{name}: {e:?}"
        );
        assert_eq!(e.to_string(), format!("{name}: no points"));
        let e = formats::read_geometry_from_bytes(&bytes, FsPath::new(name)).unwrap_err();
        assert!(matches!(e, trim_geom::GeomError::NoPoints { .. }), "{name}");
    }
}

/// A closed tetrahedron with f32-representable coordinates (so STL's f32 keeps them exactly).
fn tetrahedron() -> Mesh {
    Mesh::new(
        vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(10.5, 0.0, 0.0),
            Point3::new(0.0, 8.25, 0.0),
            Point3::new(0.0, 0.0, 3.125),
        ],
        vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
    )
    .unwrap()
}

/// Each triangle as its corner coordinates, in order (vertex numbering may differ).
fn corners(m: &Mesh) -> Vec<[Point3; 3]> {
    m.triangles()
        .iter()
        .map(|t| t.map(|i| m.vertices()[i as usize]))
        .collect()
}

#[test]
fn stl_binary_round_trip_and_ascii_read() {
    let dir = tempfile::tempdir().unwrap();
    let m = tetrahedron();
    let file = dir.path().join("t.stl");
    formats::write_stl(&file, &m).unwrap();
    let bytes = std::fs::read(&file).unwrap();
    assert_eq!(bytes.len(), 84 + 50 * 4);
    let back = read_mesh(&file).unwrap();
    assert_eq!(corners(&back), corners(&m));
    assert!((back.area() - m.area()).abs() < 1e-12);

    // A binary header that starts with "solid", as many exporters write it.
    let mut solid_header = bytes.clone();
    solid_header[..12].copy_from_slice(b"solid part 1");
    let solid = read_mesh_from_bytes(&solid_header, FsPath::new("s.stl")).unwrap();
    assert_eq!(corners(&solid), corners(&m));

    // The same tetrahedron in ascii, with f64 digits that f32 could not hold.
    let ascii = "solid t\n\
        facet normal 0 0 -1\n outer loop\n  vertex 0 0 0\n  vertex 0 8.25 0\n  vertex 10.5 0 0\n endloop\nendfacet\n\
        facet normal 0 -1 0\n outer loop\n  vertex 0 0 0\n  vertex 10.5 0 0\n  vertex 0 0 3.125\n endloop\nendfacet\n\
        facet normal -1 0 0\n outer loop\n  vertex 0 0 0\n  vertex 0 0 3.125\n  vertex 0 8.25 0\n endloop\nendfacet\n\
        facet normal 1 1 1\n outer loop\n  vertex 10.5 0 0\n  vertex 0 8.25 0\n  vertex 0 0 3.125000000000001\n endloop\nendfacet\n\
        endsolid t\n";
    let a = read_mesh_from_bytes(ascii.as_bytes(), FsPath::new("a.stl")).unwrap();
    assert_eq!(a.triangles().len(), 4);
    assert_eq!(
        a.vertices().len(),
        5,
        "3.125000000000001 is a distinct f64 vertex"
    );
    assert_eq!(a.vertices()[4].z, 3.125_000_000_000_001);
}

#[test]
fn ply_mesh_reads_faces_and_fan_triangulates() {
    let text = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
                property float z\nproperty uchar red\nelement face 1\n\
                property list uchar int vertex_indices\nproperty float quality\nend_header\n\
                0 0 0 9\n1 0 0 9\n1 1 0 9\n0 1 0 9\n4 0 1 2 3 0.5\n";
    let m = read_mesh_from_bytes(text.as_bytes(), FsPath::new("quad.ply")).unwrap();
    assert_eq!(m.triangles(), &[[0, 1, 2], [0, 2, 3]]);
    assert!((m.area() - 1.0).abs() < 1e-12);
    // As points, the faces are ignored.
    let c = read_points_from_bytes(text.as_bytes(), FsPath::new("quad.ply")).unwrap();
    assert_eq!(c.len(), 4);
    // read_geometry tells mesh from points by the faces.
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("quad.ply");
    std::fs::write(&file, text).unwrap();
    assert!(matches!(read_geometry(&file).unwrap(), Geometry::Mesh(_)));
    let pts = dir.path().join("pts.ply");
    formats::write_ply(&pts, &c, PlyEncoding::BinaryLittleEndian).unwrap();
    assert!(matches!(read_geometry(&pts).unwrap(), Geometry::Points(_)));
}

#[test]
fn ply_skips_extra_properties_and_elements_of_any_type_in_binary() {
    // vertex: uchar flag, double x, float y, short s, double z, list uchar int extra;
    // then an element "edge" with two ints; big-endian.
    let mut b = b"ply\nformat binary_big_endian 1.0\ncomment test\nobj_info x\n\
        element vertex 2\nproperty uchar flag\nproperty double x\nproperty float y\n\
        property short s\nproperty double z\nproperty list uchar int extra\n\
        element edge 1\nproperty int v1\nproperty int v2\nend_header\n"
        .to_vec();
    for (i, (x, y, z)) in [(1.5f64, 2.25f32, -3.0f64), (4.0, 5.5, 6.125)]
        .iter()
        .enumerate()
    {
        b.push(7);
        b.extend_from_slice(&x.to_be_bytes());
        b.extend_from_slice(&y.to_be_bytes());
        b.extend_from_slice(&(-2i16).to_be_bytes());
        b.extend_from_slice(&z.to_be_bytes());
        b.push(u8::try_from(i).unwrap() + 1);
        for k in 0..=i {
            b.extend_from_slice(&i32::try_from(k).unwrap().to_be_bytes());
        }
    }
    b.extend_from_slice(&0i32.to_be_bytes());
    b.extend_from_slice(&1i32.to_be_bytes());
    let c = read_points_from_bytes(&b, FsPath::new("mixed.ply")).unwrap();
    assert_eq!(
        c.points(),
        &[Point3::new(1.5, 2.25, -3.0), Point3::new(4.0, 5.5, 6.125)]
    );
}

/// A vertex of scalars only takes the reader's fixed-stride path: mixed types, little-endian,
/// integer coordinates and an element after it.
#[test]
fn ply_fixed_layout_vertices_with_mixed_scalar_types() {
    let mut b = b"ply
format binary_little_endian 1.0
element vertex 3
        property short x
property uchar pad
property double y
property int z
        property float nz
property char nx
property ushort ny
        element edge 1
property uint a
property uint b
end_header
"
    .to_vec();
    let rows: [(i16, f64, i32, f32, i8, u16); 3] = [
        (-7, 0.125, 70_000, 1.0, 0, 0),
        (300, -1e10, -3, 0.0, -2, 0),
        (0, 5.5, 0, 0.0, 0, 9),
    ];
    for (x, y, z, nz, nx, ny) in rows {
        b.extend_from_slice(&x.to_le_bytes());
        b.push(0xAB);
        b.extend_from_slice(&y.to_le_bytes());
        b.extend_from_slice(&z.to_le_bytes());
        b.extend_from_slice(&nz.to_le_bytes());
        b.extend_from_slice(&nx.to_le_bytes());
        b.extend_from_slice(&ny.to_le_bytes());
    }
    b.extend_from_slice(&[1, 0, 0, 0, 2, 0, 0, 0]);
    let c = read_points_from_bytes(&b, FsPath::new("fixed.ply")).unwrap();
    assert_eq!(
        c.points(),
        &[
            Point3::new(-7.0, 0.125, 70_000.0),
            Point3::new(300.0, -1e10, -3.0),
            Point3::new(0.0, 5.5, 0.0)
        ]
    );
    assert_eq!(
        c.normals().unwrap(),
        &[Vector3::z(), -Vector3::x(), Vector3::y()]
    );
    // The edge element is read past; cutting into it is a truncation of "edge".
    let e = err_points(&b[..b.len() - 3], "fixed.ply");
    assert_starts(
        &e,
        "fixed.ply: element 0: truncated: the header declares 1 edge elements",
    );
}

fn path_of(seed: u64) -> Path {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let contours = [3i64, -1, 40]
        .iter()
        .map(|&id| {
            let n = rng.random_range(2..9);
            let points = (0..n)
                .map(|_| {
                    Point3::new(
                        rng.random(),
                        rng.random::<f64>() * 1e3,
                        -rng.random::<f64>(),
                    )
                })
                .collect();
            let f = Vector3::new(rng.random(), rng.random(), 1.0).normalize();
            Contour::new(id, points, f).unwrap()
        })
        .collect();
    Path::new(contours).unwrap()
}

#[test]
fn path_csv_round_trips_points_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let p = path_of(4);
    let file = dir.path().join("p.csv");
    formats::write_path(&file, &p).unwrap();
    let text = std::fs::read_to_string(&file).unwrap();
    assert!(text.starts_with("contour,x,y,z,u,v,w\n"));
    assert_eq!(text.lines().count(), 1 + p.num_points());
    let back = read_path(&file).unwrap();
    assert_eq!(back.len(), p.len());
    for (a, b) in back.contours().iter().zip(p.contours()) {
        assert_eq!(a.id(), b.id());
        assert_eq!(a.points(), b.points());
        for (x, y) in a.features().iter().zip(b.features()) {
            assert!((x - y).norm() < NORMAL_TOL);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Real files

#[test]
fn reads_the_bunny_pcds() {
    let bun0 = read_points(&data("bunny/bun0.pcd")).unwrap();
    assert_eq!(bun0.len(), 397);
    assert!(bun0.has_normals(), "bun0 has normal_x normal_y normal_z");
    // TYPE F SIZE 4: each value is the f32 PCL holds, widened.
    let f = |text: &str| f64::from(text.parse::<f32>().unwrap());
    assert_eq!(
        bun0.points()[0],
        Point3::new(f("0.0054215998"), f("0.11349"), f("0.040748999"))
    );
    let n0 = bun0.normals().unwrap()[0];
    let expected = Vector3::new(f("-0.16884723"), f("-0.45159745"), f("-0.87609947")).normalize();
    assert!((n0 - expected).norm() < 1e-12);
    let bun4 = read_points(&data("bunny/bun4.pcd")).unwrap();
    assert_eq!(bun4.len(), 361);
    assert!(!bun4.has_normals());
    assert_eq!(
        bun4.points()[1],
        Point3::new(f("0.051684"), f("0.12201"), f("0.066413"))
    );
    let b = bun4.bounds().unwrap();
    assert!(b.diagonal() > 0.05 && b.diagonal() < 0.5, "metres: {b:?}");
}

#[test]
fn reads_the_lidar_plys() {
    let file = data("lidar-pair/source.ply");
    let source = read_points(&file).unwrap();
    assert_eq!(source.len(), 69_792);
    assert!(!source.has_normals());
    // The first vertex decoded independently: float x y z after the header.
    let raw = std::fs::read(&file).unwrap();
    let body = raw.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let f = |k: usize| {
        let at = body + 4 * k;
        f64::from(f32::from_le_bytes(raw[at..at + 4].try_into().unwrap()))
    };
    assert_eq!(source.points()[0], Point3::new(f(0), f(1), f(2)));
    // The last vertex: 16 bytes per vertex (x y z intensity).
    let last = 69_791 * 4;
    assert_eq!(
        source.points()[69_791],
        Point3::new(f(last), f(last + 1), f(last + 2))
    );
    let target = read_points(&data("lidar-pair/target.ply")).unwrap();
    assert_eq!(target.len(), 69_088);
}

// ---------------------------------------------------------------------------------------------
// Bad input

const PLY_ASCII: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n\
                         property float y\nproperty float z\nend_header\n";

#[test]
fn ply_errors_name_the_line_or_element() {
    assert_starts(
        &err_points(b"plx\n", "a.ply"),
        "a.ply: line 1: not a PLY file",
    );
    assert_starts(
        &err_points(b"ply\nformat binary_middle_endian 1.0\n", "a.ply"),
        "a.ply: line 2: unknown format",
    );
    assert_starts(
        &err_points(
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\n",
            "a.ply",
        ),
        "a.ply: line 4: unknown property type \"float128\"",
    );
    assert_starts(
        &err_points(
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n",
            "a.ply",
        ),
        "a.ply: line 3: element vertex has no property z",
    );
    assert_starts(
        &err_points(b"ply\nformat ascii 1.0\nelement vertex 1\n", "a.ply"),
        "a.ply: end of file: the header has no end_header",
    );
    let text = |body: &str| format!("{PLY_ASCII}{body}");
    assert_eq!(
        err_points(text("1 2 3\n4 five 6\n7 8 9\n").as_bytes(), "a.ply"),
        "a.ply: line 9: vertex 1: \"five\" is not a number"
    );
    assert_starts(
        &err_points(text("1 2 3\n4 5\n7 8 9\n").as_bytes(), "a.ply"),
        "a.ply: line 9: vertex 1: fewer values",
    );
    assert_starts(
        &err_points(text("1 2 3\n4 5 6 7\n7 8 9\n").as_bytes(), "a.ply"),
        "a.ply: line 9: vertex 1: more values",
    );
    assert_eq!(
        err_points(text("1 2 3\n4 5 6\n7 nan 9\n").as_bytes(), "a.ply"),
        "a.ply: line 10: vertex 2: (7, NaN, 9) is not finite"
    );
    assert_eq!(
        err_points(text("1 2 3\n4 5 6\n").as_bytes(), "a.ply"),
        "a.ply: end of file: truncated: the header declares 3 vertex elements, found 2"
    );
    assert_starts(
        &err_points(text("1 2 3\n4 5 6\n7 8 9\n1 1 1\n").as_bytes(), "a.ply"),
        "a.ply: line 11: data after the last element",
    );
}

#[test]
fn ply_binary_errors_say_expected_and_found() {
    let c = cloud(3, true, 5);
    let full = encode_ply(&c, PlyEncoding::BinaryLittleEndian, PlyScalar::Float);
    // Cut inside the third vertex (each is 6 floats = 24 bytes).
    let cut = &full[..full.len() - 10];
    assert_starts(
        &err_points(cut, "b.ply"),
        "b.ply: element 2: truncated: the header declares 3 vertex elements",
    );
    assert!(err_points(cut, "b.ply").ends_with("so 2 were found"));
    // A NaN in vertex 1's y.
    let mut nan = full.clone();
    let at = nan.len() - 2 * 24 + 4;
    nan[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    assert_starts(&err_points(&nan, "b.ply"), "b.ply: element 1: vertex 1: (");
    // A zero normal.
    let mut zero = full.clone();
    let at = zero.len() - 24 + 12;
    zero[at..at + 12].fill(0);
    assert_starts(
        &err_points(&zero, "b.ply"),
        "b.ply: element 2: vertex 2: the normal (0, 0, 0) is zero",
    );
    // A header that claims a trillion vertices over a few bytes: an error, not an allocation.
    let huge = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000\n\
                 property double x\nproperty double y\nproperty double z\nend_header\n\
                 0123456789abcdef0123456789abcdef"
        .to_vec();
    assert_starts(
        &err_points(&huge, "h.ply"),
        "h.ply: element 1: truncated: the header declares 1000000000000 vertex elements",
    );
    // Bytes beyond the declared elements.
    let mut extra = full.clone();
    extra.extend_from_slice(&[1, 2, 3]);
    assert!(err_points(&extra, "b.ply").contains("3 bytes follow the last element"));
}

#[test]
fn ply_face_errors_name_the_face() {
    let head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                property float z\nelement face 1\nproperty list uchar uint vertex_indices\n\
                end_header\n0 0 0\n1 0 0\n0 1 0\n";
    assert_eq!(
        err_mesh(format!("{head}3 0 1 7\n").as_bytes(), "f.ply"),
        "f.ply: line 13: face 0: vertex index 7 is not one of the 3 vertices"
    );
    assert_eq!(
        err_mesh(format!("{head}2 0 1\n").as_bytes(), "f.ply"),
        "f.ply: line 13: face 0: 2 vertices: a face needs at least 3"
    );
    assert_starts(
        &err_mesh(format!("{head}3 0 1 1\n").as_bytes(), "f.ply"),
        "f.ply: end of file: triangles: all 1 triangles are degenerate",
    );
    let no_faces = encode_ply(&cloud(3, false, 6), PlyEncoding::Ascii, PlyScalar::Double);
    assert_starts(&err_mesh(&no_faces, "p.ply"), "p.ply: header: no faces");
}

const PCD_HEAD: &str = "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\n\
                        COUNT 1 1 1 1\nWIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\n";

#[test]
fn pcd_errors_name_the_line_or_element() {
    let ascii = |body: &str| format!("{PCD_HEAD}DATA ascii\n{body}");
    assert_eq!(
        err_points(ascii("1 2 3 4\n1 2 x 4\n1 2 3 4\n").as_bytes(), "c.pcd"),
        "c.pcd: line 13: z: \"x\" is not a number"
    );
    assert_eq!(
        err_points(ascii("1 2 3 4\nnan 2 3 4\n1 2 3 4\n").as_bytes(), "c.pcd"),
        "c.pcd: line 13: point 1: (NaN, 2, 3) is not finite"
    );
    assert_eq!(
        err_points(ascii("1 2 3 4\n1 2 3\n").as_bytes(), "c.pcd"),
        "c.pcd: line 13: expected 4 values (one per FIELDS × COUNT), found 3"
    );
    assert_eq!(
        err_points(ascii("1 2 3 4\n1 2 3 4\n").as_bytes(), "c.pcd"),
        "c.pcd: end of file: truncated: POINTS declares 3 points, found 2"
    );
    assert_eq!(
        err_points(
            ascii("1 2 3 4\n1 2 3 4\n1 2 3 4\n1 2 3 4\n").as_bytes(),
            "c.pcd"
        ),
        "c.pcd: line 15: more points than POINTS declares (3)"
    );
    let mut binary = format!("{PCD_HEAD}DATA binary\n").into_bytes();
    for k in 0..2u8 {
        for v in [1.0f32, 2.0, f32::from(k)] {
            binary.extend_from_slice(&v.to_le_bytes());
        }
        binary.extend_from_slice(&[0, 0, 0, 0]);
    }
    assert_eq!(
        err_points(&binary, "c.pcd"),
        "c.pcd: element 2: truncated: POINTS declares 3 points of 16 bytes, the body (32 bytes) \
         holds 2"
    );
    assert_starts(
        &err_points(
            b"VERSION 0.7\nFIELDS x y\nSIZE 4 4\nTYPE F F\nPOINTS 0\nDATA ascii\n",
            "c.pcd",
        ),
        "c.pcd: line 2: FIELDS has no z",
    );
    assert_starts(
        &err_points(
            b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4\nTYPE F F F\nPOINTS 0\nDATA ascii\n",
            "c.pcd",
        ),
        "c.pcd: line 3: SIZE has 2 entries for 3 FIELDS",
    );
    assert_starts(
        &err_points(
            b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA binary_compressed\n",
            "c.pcd",
        ),
        "c.pcd: unsupported format: line 6: DATA binary_compressed",
    );
    assert_starts(
        &err_points(b"hello\n", "c.pcd"),
        "c.pcd: line 1: unknown header key \"hello\"",
    );
}

#[test]
fn stl_errors_name_the_line_or_facet() {
    let facet = "facet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\n";
    assert_eq!(
        err_mesh(format!("solid s\n{facet}").as_bytes(), "s.stl"),
        "s.stl: end of file: the file ends inside a solid after 1 complete facets (no endsolid: \
         truncated?)"
    );
    assert_eq!(
        err_mesh(
            "solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 zero 0\n".as_bytes(),
            "s.stl"
        ),
        "s.stl: line 5: y: \"zero\" is not a number"
    );
    assert_eq!(
        err_mesh(
            "solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nendloop\n".as_bytes(),
            "s.stl"
        ),
        "s.stl: line 5: the facet of line 2 has 1 vertices, needs 3"
    );
    assert_eq!(
        err_mesh(
            format!("solid s\n{facet}endsolid s\nbanana\n").as_bytes(),
            "s.stl"
        ),
        "s.stl: line 10: expected nothing or another solid, found \"banana\""
    );
    let full = encode_stl(&tetrahedron()).unwrap();
    assert_eq!(
        err_mesh(&full[..full.len() - 1], "b.stl"),
        "b.stl: element 3: truncated: the header declares 4 facets, the file holds 3 (283 bytes, \
         284 needed)"
    );
    let mut nan = full.clone();
    // Facet 1's first vertex x: after the 84-byte header, facet 0 (50 bytes), the normal (12).
    nan[84 + 50 + 12..84 + 50 + 16].copy_from_slice(&f32::NAN.to_le_bytes());
    assert_eq!(
        err_mesh(&nan, "b.stl"),
        "b.stl: element 1: facet 1: vertex (NaN, 0, 0) is not finite"
    );
    assert_starts(
        &err_mesh(b"short", "b.stl"),
        "b.stl: header: a binary STL needs an 84-byte header",
    );
}

#[test]
fn file_errors_name_the_path_on_disk() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nope.ply");
    let e = read_points(&missing).unwrap_err().to_string();
    assert!(e.starts_with(&missing.display().to_string()), "{e}");
    let csv = dir.path().join("p.csv");
    std::fs::write(&csv, "contour,x,y,z,u,v\n").unwrap();
    let e = read_path(&csv).unwrap_err().to_string();
    assert_eq!(
        e,
        format!(
            "{}: line 1: missing column w (the header must name contour, x, y, z, u, v, w)",
            csv.display()
        )
    );
    let stl = dir.path().join("part.stl");
    let e = read_points(&stl).unwrap_err().to_string();
    assert!(e.contains("read_mesh"), "{e}");
    let obj = dir.path().join("part.obj");
    let e = read_points(&obj).unwrap_err().to_string();
    assert!(e.contains("unknown extension .obj"), "{e}");
}

/// Found by fuzzing (xyz and ply targets, 60 s each): a normal with components near `f64::MAX`
/// has an infinite length, and dividing by it gave a zero "unit" normal that no writer could
/// write back. Readers now scale by the largest component before normalising.
#[test]
fn huge_normals_and_features_normalise_instead_of_vanishing() {
    let c = read_points_from_bytes(b"1 2 3 0 1e308 -1e308\n", FsPath::new("h.xyz")).unwrap();
    let expected = Vector3::new(0.0, 1.0, -1.0).normalize();
    assert!((c.normals().unwrap()[0] - expected).norm() < NORMAL_TOL);
    let back = read_points_from_bytes(
        &encode_ply(&c, PlyEncoding::BinaryBigEndian, PlyScalar::Double),
        FsPath::new("h.ply"),
    )
    .unwrap();
    assert!((back.normals().unwrap()[0] - expected).norm() < NORMAL_TOL);
    let p = formats::read_path_from_bytes(
        b"contour,x,y,z,u,v,w\n1,0,0,0,1e308,1e308,0\n1,1,0,0,1e308,1e308,0\n",
        FsPath::new("h.csv"),
    )
    .unwrap();
    let f = Vector3::new(1.0, 1.0, 0.0).normalize();
    assert!((p.contours()[0].features()[0] - f).norm() < NORMAL_TOL);
    assert_starts(
        &formats::read_path_from_bytes(
            b"contour,x,y,z,u,v,w\n1,0,0,0,0,0,0\n1,1,0,0,0,0,1\n",
            FsPath::new("z.csv"),
        )
        .unwrap_err()
        .to_string(),
        "z.csv: line 2: contour 1: the feature vector (u, v, w) is zero",
    );
}
