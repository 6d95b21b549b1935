//! `trimctl calibrate field`: the galvo field correction from a marked and measured grid
//! (DESIGN.md "Frames and the calibration chain").
//!
//! Input rows (`marks.csv`: `x_cmd,y_cmd,h_mm,x_meas,y_meas`, mm, head frame): a command c was
//! marked on a flat coupon at height h (toward the lens) and the mark measured at m. The model:
//! `m = (L − h)/L · D(c)` with `D(c) = c + δ(c)`.
//!
//! - δ is a penalised tensor-product cubic B-spline (a P-spline, Eilers & Marx 1996) over the
//!   commanded range: it spans every polynomial up to bicubic — offset, rotation, scale,
//!   keystone (trapezoid), barrel — and whatever smooth residue a real f-theta head adds. The
//!   penalty is on second differences of the coefficients (linear motion is free); its weight
//!   is chosen by leave-one-out cross-validation, computed exactly from the hat matrix
//!   (`r_i / (1 − H_ii)`).
//! - L comes from the raised and lowered rows (h ≠ 0): for a trial L each row's focal-plane
//!   landing is `m·L/(L − h)`; L is the value that fits best (golden-section search). Without
//!   such rows L is left to the job (`calibration.lens.pivot_to_focal_plane_mm` or the focal
//!   length).
//! - The fitted D is sampled onto a 65 × 65 grid as a [`FieldCorrection`] (field.json), which
//!   the planner inverts per point.

use std::io::Write;
use std::path::Path;

use nalgebra::{DMatrix, DVector};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};
use trim_plan::lens::{FieldCorrection, LensDistortion, height_scale};

use crate::error::CalibError;

/// The header of marks.csv.
pub const MARKS_HEADER: &str = "x_cmd,y_cmd,h_mm,x_meas,y_meas";

/// Fewest marks a fit takes (a 5 × 5 grid).
pub const MIN_MARKS: usize = 25;

/// One measured mark (mm, head frame).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Mark {
    /// The commanded x.
    pub x_cmd: f64,
    /// The commanded y.
    pub y_cmd: f64,
    /// The coupon's height above the focal plane, toward the lens.
    pub h_mm: f64,
    /// Where the mark was measured, x.
    pub x_meas: f64,
    /// Where the mark was measured, y.
    pub y_meas: f64,
}

/// Reads marks.csv; errors name the file and line.
pub fn read_marks(path: &Path) -> Result<Vec<Mark>, CalibError> {
    let text = std::fs::read_to_string(path).map_err(|source| CalibError::Io {
        path: path.to_owned(),
        source,
    })?;
    let parse_err = |line: usize, message: String| CalibError::Parse {
        path: path.to_owned(),
        line,
        message,
    };
    let mut lines = text.lines().enumerate();
    let header = loop {
        match lines.next() {
            None => return Err(parse_err(1, "empty file: expected the header".into())),
            Some((_, l)) if l.trim().is_empty() => {}
            Some((i, l)) => break (i + 1, l.trim()),
        }
    };
    let cols: Vec<&str> = header.1.split(',').map(str::trim).collect();
    if cols != MARKS_HEADER.split(',').collect::<Vec<_>>() {
        return Err(parse_err(
            header.0,
            format!("expected the header `{MARKS_HEADER}`, got `{}`", header.1),
        ));
    }
    let mut marks = Vec::new();
    for (i, l) in lines {
        let l = l.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let f: Vec<&str> = l.split(',').map(str::trim).collect();
        if f.len() != 5 {
            return Err(parse_err(
                i + 1,
                format!("expected 5 columns ({MARKS_HEADER}), got {}", f.len()),
            ));
        }
        let mut v = [0.0; 5];
        for (k, s) in f.iter().enumerate() {
            v[k] = s.parse::<f64>().map_err(|_| {
                parse_err(i + 1, format!("column {}: `{s}` is not a number", k + 1))
            })?;
            if !v[k].is_finite() {
                return Err(parse_err(
                    i + 1,
                    format!("column {}: `{s}` is not finite", k + 1),
                ));
            }
        }
        marks.push(Mark {
            x_cmd: v[0],
            y_cmd: v[1],
            h_mm: v[2],
            x_meas: v[3],
            y_meas: v[4],
        });
    }
    if marks.len() < MIN_MARKS {
        return Err(CalibError::TooFew {
            what: format!("{}: marks", path.display()),
            needed: MIN_MARKS,
            got: marks.len(),
        });
    }
    Ok(marks)
}

/// Writes marks.csv.
pub fn write_marks(path: &Path, marks: &[Mark]) -> Result<(), CalibError> {
    let io = |source| CalibError::Io {
        path: path.to_owned(),
        source,
    };
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).map_err(io)?);
    writeln!(f, "{MARKS_HEADER}").map_err(io)?;
    for m in marks {
        writeln!(
            f,
            "{},{},{},{},{}",
            m.x_cmd, m.y_cmd, m.h_mm, m.x_meas, m.y_meas
        )
        .map_err(io)?;
    }
    f.flush().map_err(io)
}

/// A marked grid: `grid × grid` commands over `[−half_field, half_field]²` on a coupon at each
/// of `heights_mm`, measured with Gaussian noise `noise_um` per coordinate; `offset_fraction`
/// shifts the grid by that fraction of a cell (a held-out grid between another's marks).
#[derive(Debug, Clone, PartialEq)]
pub struct MarkGrid {
    /// Marks per side.
    pub grid: usize,
    /// Half the side of the marked square (mm).
    pub half_field_mm: f64,
    /// Coupon heights above the focal plane, toward the lens (mm).
    pub heights_mm: Vec<f64>,
    /// Measurement noise per coordinate (µm).
    pub noise_um: f64,
    /// Grid shift, in cells.
    pub offset_fraction: f64,
}

/// The marks a head with field `truth` and pivot height `pivot_mm` gives on `grid` (seeded).
#[must_use]
pub fn synth_marks(truth: &LensDistortion, pivot_mm: f64, grid: &MarkGrid, seed: u64) -> Vec<Mark> {
    let (half_field_mm, heights_mm, noise_um, offset_fraction) = (
        grid.half_field_mm,
        &grid.heights_mm,
        grid.noise_um,
        grid.offset_fraction,
    );
    let grid = grid.grid;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let noise = Normal::new(0.0, noise_um.max(0.0) * 1e-3).unwrap_or_else(|_| {
        // σ = 0 is valid for Normal; only a NaN gets here.
        Normal::new(0.0, 0.0).unwrap_or_else(|_| unreachable!("σ = 0 is a valid normal"))
    });
    let n = grid.max(2);
    let step = 2.0 * half_field_mm / (n - 1) as f64;
    let mut out = Vec::with_capacity(n * n * heights_mm.len());
    for &h in heights_mm.iter() {
        for j in 0..n {
            for i in 0..n {
                let c = [
                    (-half_field_mm + (i as f64 + offset_fraction) * step).min(half_field_mm),
                    (-half_field_mm + (j as f64 + offset_fraction) * step).min(half_field_mm),
                ];
                let d = truth.land(c);
                let s = height_scale(pivot_mm, h);
                out.push(Mark {
                    x_cmd: c[0],
                    y_cmd: c[1],
                    h_mm: h,
                    x_meas: d[0] * s + noise.sample(&mut rng),
                    y_meas: d[1] * s + noise.sample(&mut rng),
                });
            }
        }
    }
    out
}

/// Options of the fit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FieldFitSettings {
    /// B-spline cells per side of the commanded range.
    pub cells: usize,
    /// Nodes per side of the field.json grid.
    pub grid_nodes: usize,
    /// The nominal L (the focal length, mm): the "before" model and the centre of L's search.
    pub focal_length_mm: f64,
    /// The penalty weight; unset: chosen by leave-one-out cross-validation.
    pub smoothing: Option<f64>,
}

impl Default for FieldFitSettings {
    fn default() -> Self {
        FieldFitSettings {
            cells: 8,
            grid_nodes: 65,
            focal_length_mm: 254.0,
            smoothing: None,
        }
    }
}

/// What the fit found (µm unless named).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FieldFitReport {
    /// Marks used.
    pub marks: usize,
    /// Of which on raised or lowered coupons (h ≠ 0).
    pub marks_off_plane: usize,
    /// RMS distance between measured and nominal (D = identity, L = focal length).
    pub rms_before_um: f64,
    /// Largest such distance.
    pub max_before_um: f64,
    /// RMS residual of the fit.
    pub rms_after_um: f64,
    /// Largest residual of the fit.
    pub max_after_um: f64,
    /// Leave-one-out: RMS of each mark's residual when the fit does not see it.
    pub loo_rms_um: f64,
    /// Leave-one-out: the largest.
    pub loo_max_um: f64,
    /// L fitted from the off-plane rows (mm), if there are any.
    pub pivot_to_focal_plane_mm: Option<f64>,
    /// Where the zero command lands (mm).
    pub offset_mm: [f64; 2],
    /// The field's rotation at the centre (degrees).
    pub rotation_deg: f64,
    /// The penalty weight used.
    pub smoothing: f64,
    /// Half the side of the commanded range the field covers (mm).
    pub half_field_mm: f64,
}

/// Cubic B-spline basis values at t ∈ [0, 1] of the four functions on a cell.
fn bspline(t: f64) -> [f64; 4] {
    let u = 1.0 - t;
    [
        u * u * u / 6.0,
        (3.0 * t * t * t - 6.0 * t * t + 4.0) / 6.0,
        (-3.0 * t * t * t + 3.0 * t * t + 3.0 * t + 1.0) / 6.0,
        t * t * t / 6.0,
    ]
}

/// The tensor B-spline basis over `[−half, half]²` with `cells` cells per side.
struct Basis {
    half: f64,
    cells: usize,
}

impl Basis {
    fn size(&self) -> usize {
        (self.cells + 3) * (self.cells + 3)
    }

    /// (index, value) of the 16 functions non-zero at c.
    fn row(&self, c: [f64; 2]) -> [(usize, f64); 16] {
        let side = self.cells + 3;
        let step = 2.0 * self.half / self.cells as f64;
        let locate = |x: f64| {
            let u = ((x + self.half) / step).clamp(0.0, self.cells as f64);
            let i = (u.floor() as usize).min(self.cells - 1);
            (i, u - i as f64)
        };
        let (i, tx) = locate(c[0]);
        let (j, ty) = locate(c[1]);
        let (bx, by) = (bspline(tx), bspline(ty));
        let mut out = [(0, 0.0); 16];
        for b in 0..4 {
            for a in 0..4 {
                out[b * 4 + a] = ((j + b) * side + i + a, bx[a] * by[b]);
            }
        }
        out
    }

    /// The second-difference penalty DᵀD along both directions.
    fn penalty(&self) -> DMatrix<f64> {
        let side = self.cells + 3;
        let n = self.size();
        let mut p = DMatrix::zeros(n, n);
        let mut add = |idx: [usize; 3]| {
            let w = [1.0, -2.0, 1.0];
            for (a, &ia) in idx.iter().enumerate() {
                for (b, &ib) in idx.iter().enumerate() {
                    p[(ia, ib)] += w[a] * w[b];
                }
            }
        };
        for j in 0..side {
            for i in 0..side - 2 {
                add([j * side + i, j * side + i + 1, j * side + i + 2]);
                add([i * side + j, (i + 1) * side + j, (i + 2) * side + j]);
            }
        }
        p
    }
}

/// One penalised least-squares fit of δ at a given L and weight: the coefficients (x and y),
/// the residuals and the hat matrix's diagonal.
struct Solved {
    coef: [DVector<f64>; 2],
    residual: Vec<[f64; 2]>,
    leverage: Vec<f64>,
}

fn solve(
    basis: &Basis,
    marks: &[Mark],
    pivot_mm: f64,
    lambda: f64,
    penalty: &DMatrix<f64>,
) -> Option<Solved> {
    let n = basis.size();
    let mut b = DMatrix::zeros(marks.len(), n);
    let mut y = [DVector::zeros(marks.len()), DVector::zeros(marks.len())];
    for (r, m) in marks.iter().enumerate() {
        for (k, v) in basis.row([m.x_cmd, m.y_cmd]) {
            b[(r, k)] = v;
        }
        let s = height_scale(pivot_mm, m.h_mm);
        y[0][r] = m.x_meas / s - m.x_cmd;
        y[1][r] = m.y_meas / s - m.y_cmd;
    }
    let normal = b.transpose() * &b + penalty * lambda;
    let chol = normal.cholesky()?;
    let inv = chol.inverse();
    let coef = [
        &inv * (b.transpose() * &y[0]),
        &inv * (b.transpose() * &y[1]),
    ];
    let bi = &b * &inv;
    let leverage = (0..marks.len()).map(|r| bi.row(r).dot(&b.row(r))).collect();
    let fit = [&b * &coef[0], &b * &coef[1]];
    let residual = marks
        .iter()
        .enumerate()
        .map(|(r, m)| {
            // In measured units: the residual on the coupon at its height.
            let s = height_scale(pivot_mm, m.h_mm);
            [(y[0][r] - fit[0][r]) * s, (y[1][r] - fit[1][r]) * s]
        })
        .collect();
    Some(Solved {
        coef,
        residual,
        leverage,
    })
}

fn rms_max_um(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut s, mut n, mut m) = (0.0, 0usize, 0.0_f64);
    for x in v {
        s += x * x;
        n += 1;
        m = m.max(x);
    }
    if n == 0 {
        (0.0, 0.0)
    } else {
        ((s / n as f64).sqrt() * 1e3, m * 1e3)
    }
}

fn loo(s: &Solved) -> (f64, f64) {
    rms_max_um(
        s.residual
            .iter()
            .zip(&s.leverage)
            .map(|(r, h)| r[0].hypot(r[1]) / (1.0 - h).max(1e-9)),
    )
}

/// Fits the head field (and L from off-plane rows) to the marks.
pub fn fit_field(
    marks: &[Mark],
    settings: &FieldFitSettings,
) -> Result<(FieldCorrection, FieldFitReport), CalibError> {
    if marks.len() < MIN_MARKS {
        return Err(CalibError::TooFew {
            what: "marks".into(),
            needed: MIN_MARKS,
            got: marks.len(),
        });
    }
    if !(settings.focal_length_mm.is_finite() && settings.focal_length_mm > 0.0) {
        return Err(CalibError::Invalid {
            key: "focal_length_mm".into(),
            message: format!("must be > 0, got {}", settings.focal_length_mm),
        });
    }
    if settings.cells < 1 || settings.grid_nodes < 4 {
        return Err(CalibError::Invalid {
            key: "cells/grid_nodes".into(),
            message: "need at least 1 cell and 4 grid nodes".into(),
        });
    }
    let half = marks
        .iter()
        .map(|m| m.x_cmd.abs().max(m.y_cmd.abs()))
        .fold(0.0, f64::max);
    if half <= 0.0 {
        return Err(CalibError::Degenerate(
            "every mark was commanded at the field centre".into(),
        ));
    }
    // Enough marks per cell: at most one cell per two mark columns.
    let distinct_x = {
        let mut xs: Vec<i64> = marks
            .iter()
            .map(|m| (m.x_cmd * 1e3).round() as i64)
            .collect();
        xs.sort_unstable();
        xs.dedup();
        xs.len()
    };
    let cells = settings.cells.min((distinct_x / 2).max(1));
    let basis = Basis { half, cells };
    let penalty = basis.penalty();
    let off_plane = marks.iter().filter(|m| m.h_mm != 0.0).count();
    let lambdas: Vec<f64> = match settings.smoothing {
        Some(l) => vec![l],
        None => (-8..=2).map(|e| 10f64.powi(e)).collect(),
    };
    let best_lambda = |pivot: f64| -> Option<(f64, Solved)> {
        let mut best: Option<(f64, f64, Solved)> = None;
        for &l in &lambdas {
            let s = solve(&basis, marks, pivot, l, &penalty)?;
            let (loo_rms, _) = loo(&s);
            if best.as_ref().is_none_or(|b| loo_rms < b.0) {
                best = Some((loo_rms, l, s));
            }
        }
        best.map(|(_, l, s)| (l, s))
    };
    let fit_rms = |pivot: f64| -> f64 {
        solve(
            &basis,
            marks,
            pivot,
            lambdas[lambdas.len() / 2].min(1e-3),
            &penalty,
        )
        .map_or(f64::INFINITY, |s| {
            rms_max_um(s.residual.iter().map(|r| r[0].hypot(r[1]))).0
        })
    };
    let pivot = if off_plane > 0 {
        // Golden-section search of L over [½, 2] × the focal length.
        let (mut a, mut b) = (
            0.5 * settings.focal_length_mm,
            2.0 * settings.focal_length_mm,
        );
        let g = (5f64.sqrt() - 1.0) / 2.0;
        let (mut c, mut d) = (b - g * (b - a), a + g * (b - a));
        let (mut fc, mut fd) = (fit_rms(c), fit_rms(d));
        for _ in 0..80 {
            if fc < fd {
                b = d;
                d = c;
                fd = fc;
                c = b - g * (b - a);
                fc = fit_rms(c);
            } else {
                a = c;
                c = d;
                fc = fd;
                d = a + g * (b - a);
                fd = fit_rms(d);
            }
        }
        Some(0.5 * (a + b))
    } else {
        None
    };
    let l = pivot.unwrap_or(settings.focal_length_mm);
    let (lambda, solved) = best_lambda(l).ok_or_else(|| {
        CalibError::Degenerate("the marks do not determine the field (singular fit)".into())
    })?;
    let before = rms_max_um(marks.iter().map(|m| {
        let s = height_scale(settings.focal_length_mm, m.h_mm);
        (m.x_meas - m.x_cmd * s).hypot(m.y_meas - m.y_cmd * s)
    }));
    let after = rms_max_um(solved.residual.iter().map(|r| r[0].hypot(r[1])));
    let (loo_rms_um, loo_max_um) = loo(&solved);
    let delta = |c: [f64; 2]| -> [f64; 2] {
        let mut d = [0.0; 2];
        for (k, v) in basis.row(c) {
            d[0] += v * solved.coef[0][k];
            d[1] += v * solved.coef[1][k];
        }
        d
    };
    let land = |c: [f64; 2]| {
        let d = delta(c);
        [c[0] + d[0], c[1] + d[1]]
    };
    let mut field = FieldCorrection::sample(half, settings.grid_nodes, land);
    field.pivot_to_focal_plane_mm = pivot;
    let offset = land([0.0, 0.0]);
    let e = 1.0;
    let (lx, ly) = (land([e, 0.0]), land([0.0, e]));
    let rotation_deg = ((lx[1] - offset[1]) - (ly[0] - offset[0]))
        .atan2((lx[0] - offset[0]) + (ly[1] - offset[1]))
        .to_degrees();
    let report = FieldFitReport {
        marks: marks.len(),
        marks_off_plane: off_plane,
        rms_before_um: before.0,
        max_before_um: before.1,
        rms_after_um: after.0,
        max_after_um: after.1,
        loo_rms_um,
        loo_max_um,
        pivot_to_focal_plane_mm: pivot,
        offset_mm: offset,
        rotation_deg,
        smoothing: lambda,
        half_field_mm: half,
    };
    field.fit = serde_json::to_value(&report).unwrap_or(serde_json::Value::Null);
    Ok((field, report))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth() -> LensDistortion {
        LensDistortion {
            offset_mm: [0.21, -0.14],
            rotation_deg: 0.12,
            barrel_per_mm2: 4.8e-7,
            trapezoid_per_mm: [1.1e-5, -9.0e-6],
        }
    }

    #[test]
    fn recovers_a_barrel_keystone_head_and_its_pivot_to_micrometres() {
        for seed in 1..=3 {
            let t = truth();
            let pivot = 262.0;
            let fit_grid = MarkGrid {
                grid: 21,
                half_field_mm: 50.0,
                heights_mm: vec![0.0, 2.0, -2.0],
                noise_um: 2.0,
                offset_fraction: 0.0,
            };
            let marks = synth_marks(&t, pivot, &fit_grid, seed);
            let (field, report) = fit_field(&marks, &FieldFitSettings::default()).expect("fit");
            // Held out: a grid between the fit's marks, in the focal plane, without noise.
            let held_grid = MarkGrid {
                grid: 20,
                heights_mm: vec![0.0],
                noise_um: 0.0,
                offset_fraction: 0.5,
                ..fit_grid
            };
            let held = synth_marks(&t, pivot, &held_grid, seed + 100);
            let errs: Vec<f64> = held
                .iter()
                .map(|m| {
                    let l = field.land([m.x_cmd, m.y_cmd]);
                    (l[0] - m.x_meas).hypot(l[1] - m.y_meas)
                })
                .collect();
            let rms = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len() as f64).sqrt() * 1e3;
            let l = report.pivot_to_focal_plane_mm.expect("L from raised rows");
            assert!(
                rms <= 3.0,
                "seed {seed}: held-out RMS {rms:.2} µm; {report:?}"
            );
            assert!((l - pivot).abs() / pivot < 0.01, "seed {seed}: L {l}");
            assert!(report.loo_rms_um <= 3.0, "{report:?}");
            assert!(report.rms_before_um > 50.0, "{report:?}");
        }
    }

    #[test]
    fn bad_files_name_file_and_line() {
        let dir = tempfile::tempdir().expect("dir");
        let p = dir.path().join("marks.csv");
        for (text, want) in [
            ("", "empty"),
            ("x,y\n", "header"),
            (&format!("{MARKS_HEADER}\n1,2,0,1,nan\n") as &str, ":2:"),
            (&format!("{MARKS_HEADER}\n1,2,0,1\n"), "5 columns"),
            (&format!("{MARKS_HEADER}\n1,2,0,1,2\n"), "at least 25"),
        ] {
            std::fs::write(&p, text).expect("write");
            let e = read_marks(&p).expect_err(text).to_string();
            assert!(e.contains("marks.csv") && e.contains(want), "{text:?}: {e}");
        }
    }
}
