//! `calibrate field` recovers seeded f-theta heads (barrel 40–72 µm at the edge of a 100 mm
//! field, keystone, 0.1–0.5 mm offset, 0.05–0.2° rotation, 2 µm measurement noise per
//! coordinate) from an 11 × 11 grid plus two rows on coupons at ±2 mm: the fitted field lands
//! held-out commands (a grid between the fit's marks, measured separately) within 3 µm RMS, and
//! L within 1 %. Also: a ripple no polynomial holds, the Newton inverse, the 65 × 65 table.

use trim_calib::field_correction::{FieldFitSettings, Mark, MarkGrid, fit_field, synth_marks};
use trim_cell::lens::{CorrectionTable, FieldCorrection, LensDistortion, LensModel, height_scale};

const HALF_FIELD_MM: f64 = 50.0;
const NOISE_UM: f64 = 2.0;

fn grid(n: usize, heights_mm: &[f64], noise_um: f64, offset_fraction: f64) -> MarkGrid {
    MarkGrid {
        grid: n,
        half_field_mm: HALF_FIELD_MM,
        heights_mm: heights_mm.to_vec(),
        noise_um,
        offset_fraction,
    }
}

/// A seeded head within the ranges.
fn truth(seed: u64) -> LensDistortion {
    let s = seed as f64;
    LensDistortion {
        offset_mm: [0.1 + 0.07 * s, -(0.08 + 0.06 * s)],
        rotation_deg: if seed.is_multiple_of(2) { 1.0 } else { -1.0 } * (0.05 + 0.03 * s),
        // Barrel: k·50³ = −(40 … 72) µm at the field edge.
        barrel_per_mm2: -(40.0 + 8.0 * s) * 1e-3 / HALF_FIELD_MM.powi(3),
        // Keystone: 10 … 35 µm at the corners.
        trapezoid_per_mm: [
            (10.0 + 5.0 * s) * 1e-3 / (HALF_FIELD_MM * HALF_FIELD_MM),
            -(30.0 - 4.0 * s) * 1e-3 / (HALF_FIELD_MM * HALF_FIELD_MM),
        ],
    }
}

/// The fit's marks: the 11 × 11 grid in the focal plane and, on coupons at +2 and −2 mm, the
/// grid's centre row and its top row.
fn fit_marks(t: &LensDistortion, pivot_mm: f64, seed: u64) -> Vec<Mark> {
    let mut marks = synth_marks(t, pivot_mm, &grid(11, &[0.0], NOISE_UM, 0.0), seed);
    let raised = synth_marks(
        t,
        pivot_mm,
        &grid(11, &[2.0, -2.0], NOISE_UM, 0.0),
        seed + 1000,
    );
    marks.extend(
        raised
            .into_iter()
            .filter(|m| m.y_cmd.abs() < 1e-9 || (m.y_cmd - HALF_FIELD_MM).abs() < 1e-9),
    );
    marks
}

/// RMS and max (µm) of the distance between where the field says each mark lands and where it
/// was measured.
fn held_out_um(field: &FieldCorrection, pivot_mm: f64, marks: &[Mark]) -> (f64, f64) {
    let d: Vec<f64> = marks
        .iter()
        .map(|m| {
            let l = field.land([m.x_cmd, m.y_cmd]);
            let s = height_scale(pivot_mm, m.h_mm);
            (l[0] * s - m.x_meas).hypot(l[1] * s - m.y_meas) * 1e3
        })
        .collect();
    let rms = (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt();
    (rms, d.iter().copied().fold(0.0, f64::max))
}

#[test]
fn recovers_seeded_heads_on_held_out_marks_and_the_pivot() {
    for seed in 1..=5 {
        let t = truth(seed);
        let pivot = 240.0 + 7.0 * seed as f64;
        let marks = fit_marks(&t, pivot, seed);
        let settings = FieldFitSettings {
            focal_length_mm: 254.0,
            ..FieldFitSettings::default()
        };
        let (field, report) = fit_field(&marks, &settings).expect("fit");
        let l = report
            .pivot_to_focal_plane_mm
            .expect("L from the raised rows");
        let l_std = report.pivot_std_mm.expect("its standard deviation");
        // Held out: a 10 × 10 grid between the fit's marks, measured separately (own noise).
        let held = synth_marks(&t, pivot, &grid(10, &[0.0], NOISE_UM, 0.5), seed + 2000);
        let (noisy_rms, noisy_max) = held_out_um(&field, l, &held);
        // The same commands without measurement noise: the field's own error.
        let exact = synth_marks(&t, pivot, &grid(10, &[0.0], 0.0, 0.5), seed + 2000);
        let (true_rms, true_max) = held_out_um(&field, l, &exact);
        println!(
            "seed {seed}: before {:.1}/{:.1} µm, after {:.2}/{:.2} µm, LOO {:.2}/{:.2} µm, \
             held-out {noisy_rms:.2}/{noisy_max:.2} µm (noise-free {true_rms:.2}/{true_max:.2} \
             µm), L {l:.2} ± {l_std:.2} mm vs {pivot} mm ({:+.3} %), λ {:.0e}, {:.1} parameters",
            report.rms_before_um,
            report.max_before_um,
            report.rms_after_um,
            report.max_after_um,
            report.loo_rms_um,
            report.loo_max_um,
            (l - pivot) / pivot * 100.0,
            report.smoothing,
            report.effective_parameters,
        );
        assert!(report.max_before_um > 100.0, "{report:?}");
        assert!(
            true_rms <= 1.5,
            "seed {seed}: field error {true_rms:.2} µm RMS"
        );
        // 2 µm per coordinate alone gives 2.83 µm RMS of the distance.
        assert!(
            noisy_rms <= 3.3,
            "seed {seed}: held-out {noisy_rms:.2} µm RMS"
        );
        assert!(report.loo_rms_um <= 3.5, "{report:?}");
        assert!(
            (l - pivot).abs() / pivot < 0.01,
            "seed {seed}: L {l} vs {pivot}"
        );
        assert!(
            (l - pivot).abs() < 4.0 * l_std + 0.05,
            "L {l} ± {l_std} vs {pivot}"
        );
        // The similarity part found: offset to the noise, rotation to a few thousandths.
        let dx = report.offset_mm[0] - t.offset_mm[0];
        let dy = report.offset_mm[1] - t.offset_mm[1];
        assert!(
            dx.hypot(dy) < 3e-3,
            "offset {:?} vs {:?}",
            report.offset_mm,
            t.offset_mm
        );
        assert!(
            (report.rotation_deg - t.rotation_deg).abs() < 5e-3,
            "rotation {} vs {}",
            report.rotation_deg,
            t.rotation_deg
        );
        // field.json carries L and the report.
        assert_eq!(field.pivot_to_focal_plane_mm, Some(l));
        assert!(field.fit["loo_rms_um"].as_f64().is_some());
    }
}

#[test]
fn follows_a_smooth_residue_no_low_order_polynomial_holds() {
    // A head with a 5 µm ripple on top of barrel and keystone (the kind of residue a real
    // f-theta lens leaves), marked on a 21 × 21 grid in the focal plane only.
    let t = truth(3);
    let ripple = |c: [f64; 2]| {
        let (sx, sy) = ((c[0] / 8.0).sin(), (c[1] / 10.0).cos());
        [5e-3 * sx * sy, 4e-3 * sy * (c[0] / 9.0).cos()]
    };
    let land = |c: [f64; 2]| {
        let (d, r) = (t.land(c), ripple(c));
        [d[0] + r[0], d[1] + r[1]]
    };
    let make = |n: usize, shift: f64, noise: f64, seed: u64| -> Vec<Mark> {
        // Noise from the library's own generator: the same commands with the truth's noise.
        let base = synth_marks(&t, 254.0, &grid(n, &[0.0], noise, shift), seed);
        base.iter()
            .map(|m| {
                let exact = t.land([m.x_cmd, m.y_cmd]);
                let l = land([m.x_cmd, m.y_cmd]);
                Mark {
                    x_meas: m.x_meas - exact[0] + l[0],
                    y_meas: m.y_meas - exact[1] + l[1],
                    ..*m
                }
            })
            .collect()
    };
    let marks = make(21, 0.0, NOISE_UM, 7);
    let (field, report) = fit_field(&marks, &FieldFitSettings::default()).expect("fit");
    assert!(report.pivot_to_focal_plane_mm.is_none());
    let (true_rms, _) = held_out_um(&field, 254.0, &make(20, 0.5, 0.0, 8));
    // A bicubic polynomial alone (the penalty at its strongest) misses the ripple.
    let poly = FieldFitSettings {
        smoothing: Some(1e8),
        ..FieldFitSettings::default()
    };
    let (stiff, _) = fit_field(&marks, &poly).expect("fit");
    let (stiff_rms, _) = held_out_um(&stiff, 254.0, &make(20, 0.5, 0.0, 8));
    println!(
        "ripple: spline {true_rms:.2} µm RMS (λ {:.0e}, {:.1} parameters), bicubic only \
         {stiff_rms:.2} µm RMS",
        report.smoothing, report.effective_parameters
    );
    assert!(true_rms <= 1.5, "{true_rms}");
    assert!(stiff_rms > 2.0 * true_rms, "{stiff_rms} vs {true_rms}");
}

#[test]
fn the_fitted_field_inverts_to_a_micrometre_fraction_with_the_height_term() {
    let t = truth(2);
    let marks = fit_marks(&t, 254.0, 11);
    let (field, report) = fit_field(&marks, &FieldFitSettings::default()).expect("fit");
    let lens = LensModel {
        telecentric: false,
        pivot_to_focal_plane_mm: report.pivot_to_focal_plane_mm.expect("L"),
        field: Some(field),
    };
    let mut worst: f64 = 0.0;
    for h in [-1.5, 0.0, 0.8] {
        for i in -12..=12 {
            for j in -12..=12 {
                let p = [f64::from(i) * 3.9, f64::from(j) * 3.9];
                let c = lens.command_for(p, h).expect("inside");
                let back = lens.land(c, h);
                worst = worst.max((back[0] - p[0]).hypot(back[1] - p[1]));
            }
        }
    }
    assert!(worst <= 1e-6, "inverse error {worst} mm");
    let field = lens.field.as_ref().expect("field");
    assert!(
        field.command_for([70.0, 0.0]).is_none(),
        "outside the range"
    );
}

#[test]
fn the_65_by_65_table_round_trips() {
    let t = truth(4);
    let (field, _) =
        fit_field(&fit_marks(&t, 254.0, 4), &FieldFitSettings::default()).expect("fit");
    let dir = tempfile::tempdir().expect("dir");
    for name in ["field.cor", "field.txt"] {
        let path = dir.path().join(name);
        let table = CorrectionTable::from_field(&field, 2.0 * HALF_FIELD_MM).expect("table");
        table.write(&path).expect("write");
        let read = CorrectionTable::read(&path).expect("read");
        assert_eq!(read, table, "{name}");
        let back = read.to_field().expect("back");
        let mut worst: f64 = 0.0;
        for i in -10..=10 {
            for j in -10..=10 {
                let c = [f64::from(i) * 4.8, f64::from(j) * 4.8];
                let (a, b) = (back.land(c), field.land(c));
                worst = worst.max((a[0] - b[0]).hypot(a[1] - b[1]));
            }
        }
        // Half a controller bit per axis at 655 bits/mm: ≤ 1.1 µm.
        assert!(worst <= 1.2e-3, "{name}: {worst} mm");
    }
    // A file that is neither layout is refused, naming it.
    let bad = dir.path().join("bad.cor");
    std::fs::write(&bad, "i,j\n").expect("write");
    let e = CorrectionTable::read(&bad).expect_err("bad").to_string();
    assert!(e.contains("bad.cor"), "{e}");
}

#[test]
fn too_few_or_degenerate_marks_are_refused() {
    let t = truth(1);
    let marks = synth_marks(&t, 254.0, &grid(11, &[0.0], NOISE_UM, 0.0), 1);
    assert!(fit_field(&marks[..10], &FieldFitSettings::default()).is_err());
    let one_row: Vec<Mark> = marks
        .iter()
        .filter(|m| m.y_cmd.abs() < 1e-9)
        .copied()
        .collect();
    let mut row3 = one_row.clone();
    row3.extend(one_row.iter().map(|m| Mark { h_mm: 1.0, ..*m }));
    row3.extend(one_row.iter().map(|m| Mark { h_mm: -1.0, ..*m }));
    assert!(fit_field(&row3, &FieldFitSettings::default()).is_err());
    let far = vec![
        Mark {
            h_mm: 100.0,
            ..marks[0]
        };
        1
    ];
    let mut with_far = marks.clone();
    with_far.extend(far);
    let e = fit_field(&with_far, &FieldFitSettings::default()).expect_err("|h| too large");
    assert!(e.to_string().contains("mark 122"), "{e}");
    assert!(
        e.to_string()
            .contains("h_mm = 100 mm is beyond ±a quarter of the focal length"),
        "{e}"
    );
    // A mark far beyond any field is refused by its value, not as a singular fit of the set.
    let mut stray = marks.clone();
    stray[5].x_cmd = 1e300;
    let e = fit_field(&stray, &FieldFitSettings::default()).expect_err("a stray mark");
    assert!(
        e.to_string().contains("mark 6")
            && e.to_string().contains("x_cmd = 1e300 mm is beyond ±500 mm"),
        "{e}"
    );
    stray[5].x_cmd = marks[5].x_cmd;
    stray[5].y_meas = f64::NAN;
    let e = fit_field(&stray, &FieldFitSettings::default()).expect_err("a NaN");
    assert!(
        e.to_string().contains("mark 6") && e.to_string().contains("y_meas = NaN is not finite"),
        "{e}"
    );
    // A smoothing far beyond the penalties leave-one-out tries is refused by its name.
    let e = fit_field(
        &marks,
        &FieldFitSettings {
            smoothing: Some(1e300),
            ..FieldFitSettings::default()
        },
    )
    .expect_err("smoothing 1e300");
    assert!(
        e.to_string().contains("smoothing") && e.to_string().contains("1e300"),
        "{e}"
    );
}
