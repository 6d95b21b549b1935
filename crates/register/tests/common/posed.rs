//! Synthetic cores at an exact fixture error (angle, axis, shift, direction), for the capture
//! range's test and example (`#[path]`-included by both). `trim_synth::generate` draws its
//! fixture error in `[½, 1] ×` the asked size about a random axis; these cases take a case
//! generated without one and place the whole scene (scan, ground truth, scanner) by the exact
//! error `E`, so `scan_from_cad_true = E` while the fixture's nominal pose stays the identity.

use trim_geom::{Path, Point3, PointCloud, Similarity3, Vector3};
use trim_synth::{SynthParams, generate};

/// A case placed at an exact fixture error.
pub struct PosedCase {
    /// CAD points with outward normals, CAD frame.
    pub cad: PointCloud,
    /// The template path, CAD frame.
    pub path: Path,
    /// The scan, scan frame.
    pub scan: PointCloud,
    /// The true registered path, scan frame.
    pub truth: Path,
    /// The scanner, scan frame, mm.
    pub scanner_mm: Point3,
    /// The true placement `scan_from_cad` (the fixture error; the nominal pose is the identity).
    pub scan_from_cad_true: Similarity3,
}

/// Eight directions spread over the sphere (axes, diagonals; not normalised: [`fixture_error`]
/// normalises), for rotation axes and shift directions.
pub const DIRECTIONS: [[f64; 3]; 8] = [
    [1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
    [-1.0, 1.0, 1.0],
    [1.0, -1.0, 0.0],
    [0.0, -1.0, -1.0],
    [-1.0, 0.0, 1.0],
    [1.0, 1.0, -1.0],
];

/// The fixture error: a rotation of `angle_deg` about `axis` (through the CAD origin, near the
/// part's centre), then a shift of `shift_mm` along `direction`.
#[must_use]
pub fn fixture_error(
    angle_deg: f64,
    axis: [f64; 3],
    shift_mm: f64,
    direction: [f64; 3],
) -> Similarity3 {
    Similarity3::new(
        Vector3::from(direction).normalize() * shift_mm,
        Vector3::from(axis).normalize() * angle_deg.to_radians(),
        1.0,
    )
}

/// The case of `seed` (the default deformation and scanner, `scan_points` scan points), placed
/// by `error`.
///
/// # Panics
/// When the generator fails (a test or example setup error).
#[must_use]
#[expect(
    clippy::unwrap_used,
    reason = "test setup: a generator failure must fail the caller"
)]
pub fn posed_case(seed: u64, scan_points: usize, error: &Similarity3) -> PosedCase {
    let case = generate(&SynthParams {
        seed,
        pose_deg: 0.0,
        pose_mm: 0.0,
        scan_points,
        ..SynthParams::default()
    })
    .unwrap();
    assert_eq!(case.scan_from_cad_true, Similarity3::identity());
    PosedCase {
        cad: case.cad_points,
        path: case.path,
        scan: case.scan.transformed(error).unwrap(),
        truth: case.truth.transformed(error).unwrap(),
        scanner_mm: error * case.scanner_in_scan,
        scan_from_cad_true: *error,
    }
}
