//! The digital twin's demo cell: a seeded true cell that differs from the nominal one by the
//! errors a real cell has (thesis §3: axis tilts of hundredths of a degree, axis and scanner
//! offsets of tenths of a millimetre, f-theta barrel and keystone of tens of micrometres).

use nalgebra::{Rotation3, Unit};
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_cell::cell_model::TableModel;
use trim_cell::kinematics::MachineSettings;
use trim_cell::lens::LensDistortion;
use trim_cell::truth::TruthSettings;
use trim_geom::Vector3;

/// How far the demo's true cell is from the nominal one (each error is drawn in `[½, 1] ×`
/// its magnitude, in a random direction).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthMagnitudes {
    /// Tilt of each rotary axis direction (degrees).
    pub axis_tilt_deg: f64,
    /// Offset of each rotary axis line, perpendicular to it (mm).
    pub axis_offset_mm: f64,
    /// Rotation of the scanner on the head (degrees).
    pub scanner_rotation_deg: f64,
    /// Translation of the scanner on the head (mm).
    pub scanner_translation_mm: f64,
    /// Where the galvo's zero command lands (mm).
    pub head_offset_mm: f64,
    /// The galvo head's rotation about the beam (degrees).
    pub head_rotation_deg: f64,
    /// Barrel distortion at 50 mm from the field centre (µm).
    pub barrel_at_50_mm_um: f64,
    /// Keystone at the (50, 50) mm corner (µm).
    pub trapezoid_at_corner_um: f64,
    /// Relative error of the lens pivot height L.
    pub pivot_fraction: f64,
}

impl Default for TruthMagnitudes {
    fn default() -> Self {
        TruthMagnitudes {
            axis_tilt_deg: 0.03,
            axis_offset_mm: 0.15,
            scanner_rotation_deg: 0.15,
            scanner_translation_mm: 0.4,
            head_offset_mm: 0.2,
            head_rotation_deg: 0.1,
            barrel_at_50_mm_um: 60.0,
            trapezoid_at_corner_um: 30.0,
            pivot_fraction: 0.04,
        }
    }
}

fn magnitude(rng: &mut Xoshiro256PlusPlus, m: f64) -> f64 {
    let s = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    s * m * rng.random_range(0.5..=1.0)
}

fn random_unit(rng: &mut Xoshiro256PlusPlus) -> Vector3 {
    loop {
        let v = Vector3::new(
            rng.random_range(-1.0..=1.0),
            rng.random_range(-1.0..=1.0),
            rng.random_range(-1.0..=1.0),
        );
        let n = v.norm();
        if n > 0.1 && n <= 1.0 {
            return v / n;
        }
    }
}

/// A random unit vector perpendicular to `axis`.
fn perpendicular(rng: &mut Xoshiro256PlusPlus, axis: &Vector3) -> Vector3 {
    loop {
        let v = random_unit(rng);
        let p = v - axis * v.dot(axis);
        if p.norm() > 0.1 {
            return p.normalize();
        }
    }
}

/// The demo's true cell for seed `seed`, around the nominal cell of `machine` with the lens of
/// focal length `focal_length_mm`.
#[must_use]
pub fn demo_truth(
    seed: u64,
    machine: &MachineSettings,
    focal_length_mm: f64,
    m: &TruthMagnitudes,
) -> TruthSettings {
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0x7a1e_ce11);
    let nominal = TableModel::nominal(machine);
    let mut line = |point: Vector3, dir: Vector3| {
        let tilt_axis = perpendicular(&mut rng, &dir);
        let angle = magnitude(&mut rng, m.axis_tilt_deg).to_radians();
        let d = Rotation3::from_axis_angle(&Unit::new_normalize(tilt_axis), angle) * dir;
        let off = perpendicular(&mut rng, &d) * magnitude(&mut rng, m.axis_offset_mm).abs();
        let p = point + off;
        ([p.x, p.y, p.z], [d.x, d.y, d.z])
    };
    let (tp, td) = line(
        nominal.tilt.point_mm.coords,
        nominal.tilt.direction.into_inner(),
    );
    let (cp, cd) = line(
        nominal.rotary.point_mm.coords,
        nominal.rotary.direction.into_inner(),
    );
    let r = Rotation3::from_axis_angle(
        &Unit::new_normalize(random_unit(&mut rng)),
        magnitude(&mut rng, m.scanner_rotation_deg).to_radians(),
    );
    let rm = r.matrix();
    let t = random_unit(&mut rng) * magnitude(&mut rng, m.scanner_translation_mm).abs();
    let head_dir = perpendicular(&mut rng, &Vector3::z());
    let head_offset = head_dir * magnitude(&mut rng, m.head_offset_mm).abs();
    let barrel = magnitude(&mut rng, m.barrel_at_50_mm_um).abs() * 1e-3 / 50f64.powi(3);
    // Keystone: x gains x·tx·y, so tx = (corner shift) / (50 mm · 50 mm).
    let trapezoid = [
        magnitude(&mut rng, m.trapezoid_at_corner_um) * 1e-3 / 2500.0,
        magnitude(&mut rng, m.trapezoid_at_corner_um) * 1e-3 / 2500.0,
    ];
    let head = LensDistortion {
        offset_mm: [head_offset.x, head_offset.y],
        rotation_deg: magnitude(&mut rng, m.head_rotation_deg),
        barrel_per_mm2: barrel,
        trapezoid_per_mm: trapezoid,
    };
    let (a_point, a_dir, b_point, b_dir) = match machine.kinematics {
        trim_cell::KinematicsKind::XyzbcTrt => (None, None, Some(tp), Some(td)),
        _ => (Some(tp), Some(td), None, None),
    };
    let pivot_to_focal_plane_mm =
        Some(focal_length_mm * (1.0 + magnitude(&mut rng, m.pivot_fraction)));
    TruthSettings {
        calibration: trim_cell::cell_model::Calibration {
            a_axis_point_mm: a_point,
            a_axis_direction: a_dir,
            b_axis_point_mm: b_point,
            b_axis_direction: b_dir,
            c_axis_point_mm: Some(cp),
            c_axis_direction: Some(cd),
            scanner_rotation: Some([
                [rm[(0, 0)], rm[(0, 1)], rm[(0, 2)]],
                [rm[(1, 0)], rm[(1, 1)], rm[(1, 2)]],
                [rm[(2, 0)], rm[(2, 1)], rm[(2, 2)]],
            ]),
            scanner_translation_mm: Some([t.x, t.y, t.z]),
            field_correction: None,
            lens: trim_cell::cell_model::LensCalibration {
                pivot_to_focal_plane_mm,
            },
        },
        path: None,
        head,
    }
}
