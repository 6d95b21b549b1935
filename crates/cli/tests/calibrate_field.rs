//! `trimctl calibrate field` end to end: synthetic marks of a seeded head in a tempdir, the
//! built binary, field.json checked against the truth on held-out commands (≤ 3 µm RMS) and L
//! (within 1 %); the table and the SVG written; bad inputs refused naming the file (and line).

use std::path::Path;
use std::process::{Command, Output};

use trim_calib::field_correction::{MarkGrid, synth_marks, write_marks};
use trim_cell::lens::{CorrectionTable, FieldCorrection, LensDistortion, LensModel};

fn trimctl(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_trimctl"))
        .args(args)
        .output()
        .expect("run trimctl")
}

fn calibrate(marks: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "calibrate",
        "field",
        "--marks",
        marks.to_str().expect("utf-8"),
        "--out",
        out.to_str().expect("utf-8"),
    ];
    args.extend_from_slice(extra);
    trimctl(&args)
}

const TRUTH: LensDistortion = LensDistortion {
    offset_mm: [0.31, -0.18],
    rotation_deg: 0.14,
    // −60 µm at 50 mm.
    barrel_per_mm2: -60e-3 / 125_000.0,
    trapezoid_per_mm: [25e-3 / 2500.0, -15e-3 / 2500.0],
};
const PIVOT_MM: f64 = 262.0;

fn grid(n: usize, heights_mm: &[f64], noise_um: f64, offset_fraction: f64) -> MarkGrid {
    MarkGrid {
        grid: n,
        half_field_mm: 50.0,
        heights_mm: heights_mm.to_vec(),
        noise_um,
        offset_fraction,
    }
}

#[test]
fn fits_a_seeded_head_and_writes_field_json_table_and_svg() {
    let dir = tempfile::tempdir().expect("dir");
    let marks_csv = dir.path().join("marks.csv");
    let field_json = dir.path().join("field.json");
    let table = dir.path().join("field.cor");
    let svg = dir.path().join("residuals.svg");
    // 11 × 11 in the focal plane; on coupons at ±2 mm the centre row and the top row.
    let mut marks = synth_marks(&TRUTH, PIVOT_MM, &grid(11, &[0.0], 2.0, 0.0), 1);
    marks.extend(
        synth_marks(&TRUTH, PIVOT_MM, &grid(11, &[2.0, -2.0], 2.0, 0.0), 2)
            .into_iter()
            .filter(|m| m.y_cmd.abs() < 1e-9 || (m.y_cmd - 50.0).abs() < 1e-9),
    );
    write_marks(&marks_csv, &marks).expect("write marks");
    let out = calibrate(
        &marks_csv,
        &field_json,
        &[
            "--focal-length-mm",
            "254",
            "--table-out",
            table.to_str().expect("utf-8"),
            "--svg",
            svg.to_str().expect("utf-8"),
        ],
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    println!("{stdout}");
    for word in [
        "before",
        "after",
        "leave-one-out",
        "rotation",
        "pivot height L",
    ] {
        assert!(stdout.contains(word), "{word}: {stdout}");
    }
    // field.json: the stable keys, L within 1 %.
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&field_json).expect("read")).expect("json");
    assert_eq!(json["version"], 1);
    let l = json["pivot_to_focal_plane_mm"].as_f64().expect("L");
    assert!((l - PIVOT_MM).abs() / PIVOT_MM < 0.01, "L {l}");
    for key in ["rms_before_um", "rms_after_um", "loo_rms_um", "loo_max_um"] {
        assert!(json["fit"][key].as_f64().is_some(), "fit.{key}");
    }
    // Held-out commands between the fit's marks, measured separately: within 3 µm RMS of the
    // truth (noise-free), and at heights through the lens model.
    let field = FieldCorrection::read(&field_json).expect("field.json");
    let held = synth_marks(&TRUTH, PIVOT_MM, &grid(10, &[0.0, 1.0], 0.0, 0.5), 3);
    let lens = LensModel {
        telecentric: false,
        pivot_to_focal_plane_mm: l,
        field: Some(field.clone()),
    };
    let sq: Vec<f64> = held
        .iter()
        .map(|m| {
            let p = lens.land([m.x_cmd, m.y_cmd], m.h_mm);
            ((p[0] - m.x_meas).powi(2) + (p[1] - m.y_meas).powi(2)) * 1e6
        })
        .collect();
    let rms = (sq.iter().sum::<f64>() / sq.len() as f64).sqrt();
    assert!(rms <= 3.0, "held-out {rms:.2} µm RMS");
    // The table is a .cor file of the integer layout and reads back.
    let t = CorrectionTable::read(&table).expect("table");
    assert_eq!(t.correction_bits.len(), 65 * 65);
    assert!((t.bits_per_mm - 65536.0 / 100.0).abs() < 1e-9);
    let svg_text = std::fs::read_to_string(&svg).expect("svg");
    assert!(svg_text.starts_with("<svg") && svg_text.contains("marker-end"));
}

#[test]
fn bad_inputs_exit_non_zero_naming_the_file() {
    let dir = tempfile::tempdir().expect("dir");
    let marks_csv = dir.path().join("marks.csv");
    let out = dir.path().join("field.json");
    let header = "x_cmd,y_cmd,h_mm,x_meas,y_meas";
    for (text, want) in [
        (String::new(), "marks.csv:1"),
        ("x,y,h,xm,ym\n1,2,0,1,2\n".to_owned(), "marks.csv:1"),
        (format!("{header}\n1,2,0,1,2\n1,2,0,NaN,2\n"), "marks.csv:3"),
        (format!("{header}\n1,2,0,1,2\n1,2,0,x,2\n"), "marks.csv:3"),
        (format!("{header}\n1,2,0,1\n"), "marks.csv:2"),
        (format!("{header}\n1,2,0,1,2\n"), "marks.csv"),
    ] {
        std::fs::write(&marks_csv, &text).expect("write");
        let o = calibrate(&marks_csv, &out, &[]);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{text:?} accepted");
        assert!(stderr.contains(want), "{text:?}: {stderr}");
        assert!(!out.exists(), "{text:?}: field.json written");
    }
    let missing = dir.path().join("nowhere.csv");
    let o = calibrate(&missing, &out, &[]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("nowhere.csv"));
}

/// Numeric flags out of range are refused naming the flag, nothing written: `--focal-length-mm
/// 1e9` exited 0 with `± inf` in the report.
#[test]
fn out_of_range_numeric_flags_are_refused_naming_the_flag() {
    let dir = tempfile::tempdir().expect("dir");
    let marks_csv = dir.path().join("marks.csv");
    let out = dir.path().join("field.json");
    write_marks(
        &marks_csv,
        &synth_marks(&TRUTH, PIVOT_MM, &grid(5, &[0.0], 0.0, 0.0), 1),
    )
    .expect("marks");
    for (flags, want) in [
        (&["--focal-length-mm", "1e9"][..], "--focal-length-mm"),
        (&["--focal-length-mm", "NaN"][..], "--focal-length-mm"),
        (&["--focal-length-mm", "0"][..], "--focal-length-mm"),
        (&["--smoothing=-1"][..], "--smoothing"),
        (&["--smoothing", "inf"][..], "--smoothing"),
        // 1e300 made the fit singular, which blamed the marks; the values are shown as typed,
        // not as 300 digits.
        (
            &["--smoothing", "1e300"][..],
            "--smoothing: must be within (0, 1e12]",
        ),
        (&["--focal-length-mm", "1e300"][..], "mm, got 1e300"),
        (
            &["--table-out", "t.cor", "--table-field-mm", "1e9"][..],
            "--table-field-mm",
        ),
    ] {
        let o = calibrate(&marks_csv, &out, flags);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{flags:?}: {stderr}");
        assert!(stderr.contains(want), "{flags:?}: {stderr}");
        assert!(!out.exists(), "{flags:?}: field.json written");
    }
    // An output folder that does not exist is named with the system's reason once (it was
    // printed twice: the message showed its source and the chain showed it again).
    let o = calibrate(
        &marks_csv,
        &dir.path().join("nowhere").join("field.json"),
        &[],
    );
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("nowhere"), "{stderr}");
    assert_eq!(stderr.matches("os error 2").count(), 1, "{stderr}");
}
