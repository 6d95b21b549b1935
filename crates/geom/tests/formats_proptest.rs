//! Property tests of the formats: random clouds and paths round-trip; arbitrary bytes and
//! mutated valid files (byte flips, truncation, insertion) never make a parser panic, and every
//! error names the file.
#![expect(
    clippy::unwrap_used,
    reason = "fixture helpers: a fixture that fails to build is a failed test"
)]

use std::path::Path as FsPath;

use proptest::prelude::*;
use trim_geom::formats::{
    PcdEncoding, PlyEncoding, PlyScalar, encode_path, encode_pcd, encode_ply, encode_stl,
    encode_xyz, read_geometry_from_bytes, read_mesh_from_bytes, read_path_from_bytes,
    read_points_from_bytes,
};
use trim_geom::mesh::Mesh;
use trim_geom::{Contour, Path, Point3, PointCloud, Vector3};

/// Normals are renormalised on reading: a unit normal comes back within a few ulps.
const NORMAL_TOL: f64 = 1e-15;

/// Round-trip cases per property.
const ROUND_TRIP_CASES: u32 = 64;
/// Garbage and mutation cases per property.
const ABUSE_CASES: u32 = 256;

fn finite() -> impl Strategy<Value = f64> {
    prop_oneof![
        -1e4..1e4f64,
        proptest::num::f64::NORMAL | proptest::num::f64::SUBNORMAL | proptest::num::f64::ZERO,
    ]
}

fn point() -> impl Strategy<Value = Point3> {
    (finite(), finite(), finite()).prop_map(|(x, y, z)| Point3::new(x, y, z))
}

fn direction() -> impl Strategy<Value = Vector3> {
    (-1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64)
        .prop_map(|(x, y, z)| Vector3::new(x, y, z))
        .prop_filter("not too short to normalise", |v| v.norm() > 0.1)
}

fn cloud() -> impl Strategy<Value = PointCloud> {
    (
        proptest::collection::vec((point(), direction()), 0..64),
        any::<bool>(),
    )
        .prop_map(|(rows, with_normals)| {
            let (points, normals): (Vec<_>, Vec<_>) = rows.into_iter().unzip();
            if with_normals {
                PointCloud::with_normals(points, normals).unwrap()
            } else {
                PointCloud::new(points).unwrap()
            }
        })
}

fn path() -> impl Strategy<Value = Path> {
    proptest::collection::vec(
        (
            proptest::collection::vec((-1e3..1e3f64, -1e3..1e3f64, -1e3..1e3f64), 2..8),
            direction(),
        ),
        1..6,
    )
    .prop_map(|contours| {
        let contours = contours
            .into_iter()
            .enumerate()
            .map(|(k, (coords, feature))| {
                // Offsetting each point along x keeps the contour of non-zero length.
                let points = coords
                    .iter()
                    .enumerate()
                    .map(|(i, &(x, y, z))| Point3::new(x + i as f64, y, z))
                    .collect();
                let id = i64::try_from(k).unwrap() * 7 - 10;
                Contour::new(id, points, feature).unwrap()
            })
            .collect();
        Path::new(contours).unwrap()
    })
}

fn assert_same(read: &PointCloud, written: &PointCloud) -> Result<(), TestCaseError> {
    prop_assert_eq!(read.points(), written.points());
    prop_assert_eq!(read.has_normals(), written.has_normals());
    if let (Some(a), Some(b)) = (read.normals(), written.normals()) {
        for (x, y) in a.iter().zip(b) {
            prop_assert!((x - y).norm() < NORMAL_TOL, "{} vs {}", x, y);
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(ROUND_TRIP_CASES))]

    #[test]
    fn clouds_round_trip_through_every_point_format(c in cloud()) {
        // A file with no points is refused on reading (tested in formats.rs): `read` checks that
        // the error names the file, else the cloud comes back as written.
        let read = |bytes: &[u8], name: &str| -> Result<Option<PointCloud>, TestCaseError> {
            match read_points_from_bytes(bytes, FsPath::new(name)) {
                Ok(back) => Ok(Some(back)),
                Err(e) => {
                    prop_assert!(c.is_empty(), "{}: {}", name, e);
                    prop_assert_eq!(e.to_string(), format!("{name}: no points"));
                    Ok(None)
                }
            }
        };
        for encoding in [
            PlyEncoding::Ascii,
            PlyEncoding::BinaryLittleEndian,
            PlyEncoding::BinaryBigEndian,
        ] {
            if let Some(back) = read(&encode_ply(&c, encoding, PlyScalar::Double), "c.ply")? {
                assert_same(&back, &c)?;
            }
        }
        for encoding in [PcdEncoding::Ascii, PcdEncoding::Binary] {
            if let Some(back) = read(&encode_pcd(&c, encoding), "c.pcd")? {
                assert_same(&back, &c)?;
            }
        }
        if let Some(back) = read(&encode_xyz(&c), "c.xyz")? {
            assert_same(&back, &c)?;
        }
    }

    #[test]
    fn paths_round_trip(p in path()) {
        let back = read_path_from_bytes(&encode_path(&p), FsPath::new("p.csv")).unwrap();
        prop_assert_eq!(back.len(), p.len());
        for (a, b) in back.contours().iter().zip(p.contours()) {
            prop_assert_eq!(a.id(), b.id());
            prop_assert_eq!(a.points(), b.points());
            for (x, y) in a.features().iter().zip(b.features()) {
                prop_assert!((x - y).norm() < NORMAL_TOL);
            }
        }
    }
}

/// Feeds `bytes` to every reader under every name; each must return (not panic), and each error
/// must name the file.
fn feed_everything(bytes: &[u8]) -> Result<(), TestCaseError> {
    for name in ["f.ply", "f.pcd", "f.xyz", "f.stl", "f.csv"] {
        let name = FsPath::new(name);
        let results = [
            read_points_from_bytes(bytes, name).err(),
            read_mesh_from_bytes(bytes, name).err(),
            read_path_from_bytes(bytes, name).err(),
            read_geometry_from_bytes(bytes, name).err(),
        ];
        for e in results.into_iter().flatten() {
            let message = e.to_string();
            prop_assert!(
                message.starts_with(&name.display().to_string()),
                "an error that does not name the file: {}",
                message
            );
        }
    }
    Ok(())
}

/// Valid files of every format, to mutate.
fn seeds() -> Vec<Vec<u8>> {
    let c = PointCloud::with_normals(
        vec![
            Point3::new(1.0, 2.0, 3.0),
            Point3::new(-4.5, 0.25, 1e-3),
            Point3::new(7.0, -8.0, 9.5),
        ],
        vec![Vector3::z(), Vector3::x(), Vector3::new(0.6, 0.8, 0.0)],
    )
    .unwrap();
    let mesh = Mesh::new(c.points().to_vec(), vec![[0, 1, 2], [2, 1, 0]]).unwrap();
    let path = Path::new(vec![
        Contour::new(1, c.points()[..2].to_vec(), Vector3::z()).unwrap(),
        Contour::new(2, c.points()[1..].to_vec(), Vector3::x()).unwrap(),
    ])
    .unwrap();
    let ply_mesh = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n\
        property float y\nproperty float z\nelement face 1\n\
        property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
        .to_vec();
    let stl_ascii = b"solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n\
        vertex 0 1 0\nendloop\nendfacet\nendsolid s\n"
        .to_vec();
    vec![
        encode_ply(&c, PlyEncoding::Ascii, PlyScalar::Float),
        encode_ply(&c, PlyEncoding::BinaryLittleEndian, PlyScalar::Float),
        encode_ply(&c, PlyEncoding::BinaryBigEndian, PlyScalar::Double),
        ply_mesh,
        encode_pcd(&c, PcdEncoding::Ascii),
        encode_pcd(&c, PcdEncoding::Binary),
        encode_xyz(&c),
        encode_stl(&mesh).unwrap(),
        stl_ascii,
        encode_path(&path),
    ]
}

/// One edit of a file.
#[derive(Debug, Clone)]
enum Mutation {
    /// Replace the byte at (position mod length).
    Set(usize, u8),
    /// XOR a bit into the byte at (position mod length).
    Flip(usize, u8),
    /// Insert bytes at (position mod length + 1).
    Insert(usize, Vec<u8>),
    /// Keep only the first (position mod length + 1) bytes.
    Truncate(usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        (any::<usize>(), any::<u8>()).prop_map(|(i, b)| Mutation::Set(i, b)),
        (any::<usize>(), 0..8u8).prop_map(|(i, bit)| Mutation::Flip(i, 1 << bit)),
        (
            any::<usize>(),
            proptest::collection::vec(any::<u8>(), 1..16)
        )
            .prop_map(|(i, b)| Mutation::Insert(i, b)),
        any::<usize>().prop_map(Mutation::Truncate),
        // Digits and separators, to turn numbers into other (or huge) numbers.
        (
            any::<usize>(),
            proptest::sample::select(b"0123456789-.e \n,#".to_vec())
        )
            .prop_map(|(i, b)| Mutation::Set(i, b)),
    ]
}

fn apply(bytes: &mut Vec<u8>, m: &Mutation) {
    let len = bytes.len().max(1);
    match m {
        Mutation::Set(i, b) => {
            if let Some(x) = bytes.get_mut(i % len) {
                *x = *b;
            }
        }
        Mutation::Flip(i, bit) => {
            if let Some(x) = bytes.get_mut(i % len) {
                *x ^= *bit;
            }
        }
        Mutation::Insert(i, extra) => {
            let at = (i % len + 1).min(bytes.len());
            bytes.splice(at..at, extra.iter().copied());
        }
        Mutation::Truncate(i) => bytes.truncate(i % len + 1),
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(ABUSE_CASES))]

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        feed_everything(&bytes)?;
    }

    #[test]
    fn arbitrary_bytes_after_a_valid_header_never_panic(
        which in 0usize..3,
        body in proptest::collection::vec(any::<u8>(), 0..512),
    ) {
        let heads: [&[u8]; 3] = [
            b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n\
              property double y\nproperty uchar z\nelement face 2\n\
              property list uchar uint vertex_indices\nend_header\n",
            b"VERSION 0.7\nFIELDS x y z n\nSIZE 4 8 1 2\nTYPE F F U I\nCOUNT 1 1 1 3\nWIDTH 4\n\
              HEIGHT 1\nPOINTS 4\nDATA binary\n",
            b"solid\n",
        ];
        let mut bytes = heads[which].to_vec();
        bytes.extend_from_slice(&body);
        feed_everything(&bytes)?;
    }

    #[test]
    fn mutated_valid_files_never_panic(
        seed in 0usize..10,
        mutations in proptest::collection::vec(mutation(), 1..6),
    ) {
        let mut bytes = seeds().swap_remove(seed);
        for m in &mutations {
            apply(&mut bytes, m);
        }
        feed_everything(&bytes)?;
    }
}

#[test]
fn every_seed_file_reads_before_mutation() {
    let names = [
        "s.ply", "s.ply", "s.ply", "s.ply", "s.pcd", "s.pcd", "s.xyz", "s.stl", "s.stl", "s.csv",
    ];
    for (bytes, name) in seeds().iter().zip(names) {
        let read = read_geometry_from_bytes(bytes, FsPath::new(name));
        assert!(read.is_ok(), "{name}: {:?}", read.err());
    }
}
