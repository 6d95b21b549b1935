//! The seeded accuracy cases: the range a core can come in (issue 11), shared by
//! `examples/accuracy.rs` and the accuracy and calibration tests (`#[path]`-included by both,
//! so the example reports on exactly what the tests assert).

use trim_synth::SynthParams;

/// Bend (mid-length rise), mm.
pub const SAG_RANGE_MM: (f64, f64) = (0.1, 0.5);
/// Twist end to end, degrees.
pub const TWIST_RANGE_DEG: (f64, f64) = (0.2, 1.0);
/// Per-axis scale range (each axis in `1 ± r`).
pub const SCALE_RANGE: (f64, f64) = (0.005, 0.02);
/// Scan noise (standard deviation per coordinate), mm.
pub const NOISE_RANGE_MM: (f64, f64) = (0.008, 0.015);
/// Fixture rotation error, degrees (the generator draws `[½, 1] ×` this): the whole capture
/// range (`coarse.capture_rotation_deg`).
pub const POSE_RANGE_DEG: (f64, f64) = (1.0, 20.0);
/// Fixture translation error, mm (drawn `[½, 1] ×` this): the whole capture range.
pub const POSE_RANGE_MM: (f64, f64) = (1.0, 20.0);
/// Tilt of the pressing axes (along which shrinkage acts) from the part's axes, degrees
/// (drawn `[½, 1] ×` this).
pub const PRESSING_TILT_RANGE_DEG: (f64, f64) = (0.0, 30.0);
/// The change of shrinkage along the span, end to end (a pressed core's density gradient;
/// `SynthParams::shrink_gradient`): an along-span displacement no affine map takes out, which
/// the field's prior on the span penalises.
pub const SHRINK_GRADIENT_RANGE: (f64, f64) = (-0.003, 0.003);
/// The share of contours whose edges carry burrs (flash webs 20–100 µm thick standing
/// 0.1–0.5 mm off the edge, in the scan): what the laser is there to remove, and what
/// registration must not be pulled by.
pub const BURR_FRACTION: f64 = 0.3;

/// A uniform number in `[0, 1)` from `(seed, k)` (SplitMix64; no generator state, so each
/// parameter of a case depends only on the seed and its position).
fn unit(seed: u64, k: u64) -> f64 {
    let mut z = seed
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(k.wrapping_mul(0xBF58_476D_1CE4_E5B9));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

fn pick(seed: u64, k: u64, (lo, hi): (f64, f64)) -> f64 {
    lo + (hi - lo) * unit(seed, k)
}

/// The case of `seed`: every parameter drawn uniformly in its range, except that seeds
/// divisible by 4 take the far end of every range at once (the hardest core).
#[must_use]
pub fn case_params(seed: u64, scan_points: usize, cad_points: usize) -> SynthParams {
    let far = seed.is_multiple_of(4);
    let p = |k, range: (f64, f64)| if far { range.1 } else { pick(seed, k, range) };
    SynthParams {
        seed,
        sag_mm: p(1, SAG_RANGE_MM),
        twist_deg: p(2, TWIST_RANGE_DEG),
        scale_range: p(3, SCALE_RANGE),
        noise_mm: p(4, NOISE_RANGE_MM),
        pose_deg: p(5, POSE_RANGE_DEG),
        pose_mm: p(6, POSE_RANGE_MM),
        scan_points,
        cad_points,
        pressing_tilt_deg: p(7, PRESSING_TILT_RANGE_DEG),
        shrink_gradient: p(8, SHRINK_GRADIENT_RANGE),
        burr_fraction: BURR_FRACTION,
        // A scanner fixed to the machine, looking from three directions (issue 21).
        scanner_views: 3,
        ..SynthParams::default()
    }
}

/// Contour groups of the synthetic core, by id.
#[cfg_attr(
    test,
    expect(
        dead_code,
        reason = "the example prints per group; the tests score all contours"
    )
)]
pub const GROUPS: [(&str, std::ops::RangeInclusive<i64>); 3] =
    [("slots", 1..=4), ("holes", 5..=46), ("edges", 47..=52)];
