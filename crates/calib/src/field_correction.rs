//! `trimctl calibrate field`: the galvo field correction from a marked and measured grid
//! (DESIGN.md "Frames and the calibration chain").
//!
//! Input rows (`marks.csv`: `x_cmd,y_cmd,h_mm,x_meas,y_meas`, mm, head frame): a command c was
//! marked on a flat coupon at height h (toward the lens) and the mark measured at m. The model:
//! `m = (L − h)/L · D(c)` with `D(c) = c + δ(c)`.
//!
//! - δ is a penalised tensor-product cubic B-spline (a P-spline, Eilers & Marx 1996) over the
//!   commanded range. The penalty weighs fourth differences of the coefficients along rows and
//!   columns (`penalty_order`), so every bicubic polynomial — offset, rotation, scale, keystone
//!   (trapezoid), barrel — is free of it: the similarity/affine part and the low-order
//!   polynomial are fitted as by least squares, and only the smooth residue a real f-theta head
//!   adds on top is shrunk. Its weight is chosen by leave-one-out cross-validation, exact from
//!   the hat matrix H: holding out the marks g of one command (all its heights) leaves
//!   residuals `(I − H_gg)⁻¹ r_g`; the weights are tried in parallel.
//! - L comes from the raised and lowered rows (h ≠ 0): for a trial L each row's focal-plane
//!   landing is `m·L/(L − h)`; L is the value whose fit leaves the least sum of squares
//!   (golden-section search over ½–2 × the focal length, alternated once with the weight), its
//!   standard deviation `√(2σ²/RSS''(L))`. Without such rows L is left to the job
//!   (`calibration.lens.pivot_to_focal_plane_mm` or the focal length).
//! - The fitted D is sampled onto a 65 × 65 grid as a [`FieldCorrection`] (field.json), which
//!   the planner inverts per point (Newton) and which converts to a controller's
//!   [`trim_cell::lens::CorrectionTable`].

use std::io::Write;
use std::path::Path;

use nalgebra::{DMatrix, DVector};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};
use trim_cell::lens::{FieldCorrection, LensDistortion, height_scale};

use crate::error::CalibError;

/// The header of marks.csv.
pub const MARKS_HEADER: &str = "x_cmd,y_cmd,h_mm,x_meas,y_meas";

/// Fewest marks a fit takes (a 5 × 5 grid).
pub const MIN_MARKS: usize = 25;

/// A mark whose leave-one-out residual exceeds this many robust standard deviations of the
/// others' is refused as a blunder (a mistyped or misread value): under Gaussian noise a
/// distance passes 8 σ with probability e^(−32), and a real head's smooth residue raises the
/// residuals of every mark together, which raises the scale with them.
pub const OUTLIER_SIGMAS: f64 = 8.0;

/// ... and it must also exceed this (mm): below it a mark is within what a measurement of a
/// coupon scatters, even on a grid of marks that agree to a fraction of a micrometre.
pub const OUTLIER_FLOOR_MM: f64 = 0.02;

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

/// Reads marks.csv; errors name the file and line, and a last row without a line end is warned
/// of (`trim_geom::formats::warn_if_unterminated`).
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
            Some((i, l)) => break (i + 1, l.trim_start_matches('\u{feff}').trim()),
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
    trim_geom::formats::warn_if_unterminated(text.as_bytes(), path);
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
    /// B-spline cells per side of the commanded range (fewer when the grid has fewer than two
    /// mark columns per cell).
    pub cells: usize,
    /// Order of the coefficient differences the penalty weighs (2–4): polynomials of degree
    /// below it in each axis are free of the penalty. 4 leaves every bicubic term — offset,
    /// rotation, scale, keystone, barrel — free, so only the smooth residue is shrunk.
    pub penalty_order: usize,
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
            penalty_order: 4,
            grid_nodes: 65,
            focal_length_mm: 254.0,
            smoothing: None,
        }
    }
}

/// What the fit found (µm unless named; residuals are distances in the coupon's plane, head
/// frame).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FieldFitReport {
    /// Marks used.
    pub marks: usize,
    /// Of which on raised or lowered coupons (h ≠ 0).
    pub marks_off_plane: usize,
    /// Distinct commands among them (the leave-one-out holds out all marks of one command).
    pub commands: usize,
    /// RMS distance between measured and nominal (D = identity, L = focal length).
    pub rms_before_um: f64,
    /// Largest such distance.
    pub max_before_um: f64,
    /// RMS residual of the fit.
    pub rms_after_um: f64,
    /// Largest residual of the fit.
    pub max_after_um: f64,
    /// Leave-one-out: RMS of each mark's residual when the fit sees no mark of its command
    /// (exact, from the hat matrix, at the chosen penalty and L).
    pub loo_rms_um: f64,
    /// Leave-one-out: the largest.
    pub loo_max_um: f64,
    /// L fitted from the off-plane rows (mm), if there are any.
    pub pivot_to_focal_plane_mm: Option<f64>,
    /// Its standard deviation (mm), from the curvature of the residual sum of squares.
    pub pivot_std_mm: Option<f64>,
    /// Where the zero command lands (mm, head frame).
    pub offset_mm: [f64; 2],
    /// The field's rotation at the centre (degrees, counter-clockwise).
    pub rotation_deg: f64,
    /// The field's scale at the centre (1 = nominal).
    pub scale: f64,
    /// The penalty weight used.
    pub smoothing: f64,
    /// The penalty's difference order.
    pub penalty_order: usize,
    /// B-spline cells per side used.
    pub cells: usize,
    /// Effective parameters per coordinate (trace of the hat matrix).
    pub effective_parameters: f64,
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
    fn side(&self) -> usize {
        self.cells + 3
    }

    fn size(&self) -> usize {
        self.side() * self.side()
    }

    /// (index, value) of the 16 functions non-zero at c.
    fn row(&self, c: [f64; 2]) -> [(usize, f64); 16] {
        let side = self.side();
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

    /// The difference penalty DᵀD of the given order along both directions (Eilers & Marx
    /// 1996, Eq. 9, applied to rows and columns of the coefficient grid).
    fn penalty(&self, order: usize) -> DMatrix<f64> {
        let side = self.side();
        let n = self.size();
        // Binomial weights with alternating signs: the order-th difference.
        let mut w = vec![1.0];
        for _ in 0..order {
            let mut next = vec![0.0; w.len() + 1];
            for (k, v) in w.iter().enumerate() {
                next[k] += v;
                next[k + 1] -= v;
            }
            w = next;
        }
        let mut p = DMatrix::zeros(n, n);
        let mut add = |idx: &[usize]| {
            for (a, &ia) in idx.iter().enumerate() {
                for (b, &ib) in idx.iter().enumerate() {
                    p[(ia, ib)] += w[a] * w[b];
                }
            }
        };
        for j in 0..side {
            for i in 0..side.saturating_sub(order) {
                let along_x: Vec<usize> = (0..=order).map(|k| j * side + i + k).collect();
                let along_y: Vec<usize> = (0..=order).map(|k| (i + k) * side + j).collect();
                add(&along_x);
                add(&along_y);
            }
        }
        p
    }
}

/// What does not change while L and the penalty weight are searched: the design matrix over
/// the commands, its Gram matrix, the penalty and the marks grouped by command.
struct Design {
    b: DMatrix<f64>,
    btb: DMatrix<f64>,
    penalty: DMatrix<f64>,
    groups: Vec<Vec<usize>>,
}

impl Design {
    fn new(basis: &Basis, marks: &[Mark], order: usize) -> Design {
        let mut b = DMatrix::zeros(marks.len(), basis.size());
        for (r, m) in marks.iter().enumerate() {
            for (k, v) in basis.row([m.x_cmd, m.y_cmd]) {
                b[(r, k)] = v;
            }
        }
        let btb = b.transpose() * &b;
        let mut by_command: std::collections::BTreeMap<(i64, i64), Vec<usize>> =
            std::collections::BTreeMap::new();
        for (r, m) in marks.iter().enumerate() {
            let key = (
                (m.x_cmd * COMMAND_KEY_PER_MM).round() as i64,
                (m.y_cmd * COMMAND_KEY_PER_MM).round() as i64,
            );
            by_command.entry(key).or_default().push(r);
        }
        Design {
            b,
            btb,
            penalty: basis.penalty(order),
            groups: by_command.into_values().collect(),
        }
    }

    /// The linear smoother at penalty weight λ: `(BᵀB + λP)⁻¹` and `B·(BᵀB + λP)⁻¹`.
    fn smoother(&self, lambda: f64) -> Option<Smoother> {
        let normal = &self.btb + &self.penalty * lambda;
        let inv = normal.cholesky()?.inverse();
        let bi = &self.b * &inv;
        let trace = (0..self.b.nrows())
            .map(|r| bi.row(r).dot(&self.b.row(r)))
            .sum();
        Some(Smoother {
            lambda,
            inv,
            bi,
            trace,
        })
    }
}

/// Marks whose commands agree to 0.1 µm are one command.
const COMMAND_KEY_PER_MM: f64 = 1e4;

struct Smoother {
    lambda: f64,
    inv: DMatrix<f64>,
    bi: DMatrix<f64>,
    /// tr(H): effective parameters per coordinate.
    trace: f64,
}

/// One fit at a given L: coefficients (x, y), and each mark's residual in the focal plane
/// (`y − ŷ`, mm) and its height scale.
struct Solved {
    coef: [DVector<f64>; 2],
    residual: Vec<[f64; 2]>,
    scale: Vec<f64>,
}

impl Solved {
    /// The residuals on the coupons, where they were measured (mm).
    fn measured(&self) -> impl Iterator<Item = f64> + '_ {
        self.residual
            .iter()
            .zip(&self.scale)
            .map(|(r, s)| r[0].hypot(r[1]) * s)
    }

    fn rss(&self) -> f64 {
        self.measured().map(|d| d * d).sum()
    }
}

fn solve(design: &Design, sm: &Smoother, marks: &[Mark], pivot_mm: f64) -> Solved {
    let n = marks.len();
    let mut y = [DVector::zeros(n), DVector::zeros(n)];
    let mut scale = Vec::with_capacity(n);
    for (r, m) in marks.iter().enumerate() {
        let s = height_scale(pivot_mm, m.h_mm);
        y[0][r] = m.x_meas / s - m.x_cmd;
        y[1][r] = m.y_meas / s - m.y_cmd;
        scale.push(s);
    }
    let coef = [
        &sm.inv * (design.b.tr_mul(&y[0])),
        &sm.inv * (design.b.tr_mul(&y[1])),
    ];
    let fit = [&design.b * &coef[0], &design.b * &coef[1]];
    let residual = (0..n)
        .map(|r| [y[0][r] - fit[0][r], y[1][r] - fit[1][r]])
        .collect();
    Solved {
        coef,
        residual,
        scale,
    }
}

/// Leave-one-command-out residuals (mm, on the coupon), exact for the linear smoother:
/// `e_g = (I − H_gg)⁻¹ r_g` for the marks g of one command (Hastie & Tibshirani, the
/// leave-one-out lemma generalised to a block).
fn loo_residuals(design: &Design, sm: &Smoother, solved: &Solved) -> Vec<f64> {
    let mut out = vec![0.0; solved.residual.len()];
    for g in &design.groups {
        let k = g.len();
        let mut a = DMatrix::<f64>::identity(k, k);
        for (p, &rp) in g.iter().enumerate() {
            for (q, &rq) in g.iter().enumerate() {
                a[(p, q)] -= sm.bi.row(rp).dot(&design.b.row(rq));
            }
        }
        let inv = a.clone().try_inverse().unwrap_or_else(|| {
            // A command the fit reproduces exactly whatever it measured: no held-out
            // prediction. Regularise so the penalty weight that caused it is not chosen.
            (a + DMatrix::<f64>::identity(k, k) * 1e-9)
                .try_inverse()
                .unwrap_or_else(|| DMatrix::identity(k, k) * 1e9)
        });
        for c in 0..2 {
            let r = DVector::from_iterator(k, g.iter().map(|&i| solved.residual[i][c]));
            let e = &inv * r;
            for (p, &i) in g.iter().enumerate() {
                out[i] += (e[p] * solved.scale[i]).powi(2);
            }
        }
    }
    out.iter_mut().for_each(|v| *v = v.sqrt());
    out
}

/// Refuses the mark whose leave-one-out residual `loo` (mm) is furthest beyond
/// [`OUTLIER_SIGMAS`] robust standard deviations and [`OUTLIER_FLOOR_MM`], naming it by its
/// place among the marks and by its command. The scale is the residuals' median over the
/// Rayleigh median √(2 ln 2) (a distance of two Gaussian coordinates), which a few blunders
/// do not move.
fn refuse_blunders(marks: &[Mark], loo: &[f64]) -> Result<(), CalibError> {
    let mut sorted = loo.to_vec();
    sorted.sort_by(f64::total_cmp);
    let sigma = sorted[sorted.len() / 2] / (2.0 * std::f64::consts::LN_2).sqrt();
    let limit = (OUTLIER_SIGMAS * sigma).max(OUTLIER_FLOOR_MM);
    let far = loo.iter().filter(|&&d| d > limit).count();
    let Some((i, d)) = loo
        .iter()
        .copied()
        .enumerate()
        .filter(|&(_, d)| d > limit)
        .max_by(|a, b| a.1.total_cmp(&b.1))
    else {
        return Ok(());
    };
    let m = &marks[i];
    let others = if far > 1 {
        format!(" ({far} marks are beyond it; this is the furthest)")
    } else {
        String::new()
    };
    Err(CalibError::Invalid {
        key: format!("mark {}", i + 1),
        message: format!(
            "measured at ({:.4}, {:.4}) mm for the command ({:.4}, {:.4}) at h {:.3} mm, \
             {:.1} µm from where the other marks put it; they scatter by {:.1} µm, and a mark \
             beyond {:.1} µm is taken for a mistyped or misread value{others}: correct or \
             delete its row",
            m.x_meas,
            m.y_meas,
            m.x_cmd,
            m.y_cmd,
            m.h_mm,
            d * 1e3,
            sigma * 1e3,
            limit * 1e3
        ),
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

/// The penalty weights searched when none is given: half decades over 14 decades.
fn lambda_grid() -> Vec<f64> {
    (-16..=12).map(|e| 10f64.powf(f64::from(e) / 2.0)).collect()
}

/// The smoother whose leave-one-command-out RMS at L is least (weights in parallel).
fn choose_smoother(
    design: &Design,
    marks: &[Mark],
    lambdas: &[f64],
    pivot_mm: f64,
) -> Option<Smoother> {
    use rayon::prelude::*;
    let scored: Vec<(f64, Smoother)> = lambdas
        .par_iter()
        .filter_map(|&l| {
            let sm = design.smoother(l)?;
            let solved = solve(design, &sm, marks, pivot_mm);
            let (rms, _) = rms_max_um(loo_residuals(design, &sm, &solved).into_iter());
            Some((rms, sm))
        })
        .collect();
    // Ties (within 0.1 %) go to the smoother fit: fewer effective parameters.
    let best = scored.iter().map(|s| s.0).fold(f64::INFINITY, f64::min);
    scored
        .into_iter()
        .filter(|s| s.0 <= best * 1.001)
        .max_by(|a, b| a.1.lambda.total_cmp(&b.1.lambda))
        .map(|s| s.1)
}

/// L minimising the residual sum of squares at a fixed smoother: golden-section search over
/// `[½, 2] ×` the focal length (the sum is near-quadratic in 1/L there).
fn search_pivot(design: &Design, sm: &Smoother, marks: &[Mark], focal_length_mm: f64) -> f64 {
    let rss = |l: f64| solve(design, sm, marks, l).rss();
    trim_geom::stats::golden_section_min(
        rss,
        0.5 * focal_length_mm,
        2.0 * focal_length_mm,
        PIVOT_SEARCH_STEPS,
    )
}

/// Golden-section steps of L's search: the bracket shrinks to 0.618⁶⁰ ≈ 3·10⁻¹³ of itself.
const PIVOT_SEARCH_STEPS: usize = 60;

/// The largest |h| (as a fraction of the focal length) a coupon may be raised or lowered.
const MAX_HEIGHT_FRACTION: f64 = 0.25;

/// The largest `smoothing` a fit takes: six decades beyond the largest that leave-one-out
/// tries, where the penalty has long swamped the marks.
pub const MAX_SMOOTHING: f64 = 1e12;

/// What is wrong with a `smoothing` outside (0, [`MAX_SMOOTHING`]] (1e300 made the fit
/// singular, which blamed the marks); the caller names the key.
pub fn check_smoothing(l: f64) -> Result<(), String> {
    if l.is_finite() && l > 0.0 && l <= MAX_SMOOTHING {
        Ok(())
    } else {
        Err(format!(
            "must be within (0, {MAX_SMOOTHING:e}] (leave-one-out chooses from 1e-8 to 1e6), got {}",
            trim_geom::Num(l)
        ))
    }
}

/// The farthest a mark's command or measurement may lie from the field centre (mm): no galvo
/// field is a metre across.
pub const MAX_MARK_OFFSET_MM: f64 = 500.0;

/// Refuses a mark with a value that is not finite, a position beyond ±[`MAX_MARK_OFFSET_MM`]
/// or a height beyond ±`max_height_mm`, naming the mark (1-based, as a marks file's data row)
/// and the value. A mark at 1e300 made the fit singular, which blamed the whole set.
fn check_marks(marks: &[Mark], max_height_mm: f64) -> Result<(), CalibError> {
    for (i, m) in marks.iter().enumerate() {
        let values = [
            ("x_cmd", m.x_cmd),
            ("y_cmd", m.y_cmd),
            ("h_mm", m.h_mm),
            ("x_meas", m.x_meas),
            ("y_meas", m.y_meas),
        ];
        for (name, v) in values {
            let limit = if name == "h_mm" {
                max_height_mm
            } else {
                MAX_MARK_OFFSET_MM
            };
            let message = if !v.is_finite() {
                format!("{name} = {v} is not finite")
            } else if v.abs() > limit {
                let why = if name == "h_mm" {
                    format!("a quarter of the focal length, {limit:.1} mm")
                } else {
                    format!("{limit} mm from the field centre: no galvo field is a metre across")
                };
                format!("{name} = {} mm is beyond ±{why}", trim_geom::Num(v))
            } else {
                continue;
            };
            return Err(CalibError::Invalid {
                key: format!("mark {}", i + 1),
                message,
            });
        }
    }
    Ok(())
}

/// Fits the head field (and L from off-plane rows) to the marks.
///
/// Steps: the design over the commands; the penalty weight with the least leave-one-command-out
/// RMS at the nominal L; with off-plane rows, L by golden-section search at that weight, the
/// weight again at the new L, and L again; the final fit sampled onto a `grid_nodes²` grid.
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
    let f = settings.focal_length_mm;
    if !(f.is_finite() && f > 0.0) {
        return Err(CalibError::Invalid {
            key: "focal_length_mm".into(),
            message: format!("must be > 0, got {f}"),
        });
    }
    if settings.cells < 1 || settings.grid_nodes < 4 || !(2..=4).contains(&settings.penalty_order) {
        return Err(CalibError::Invalid {
            key: "cells/grid_nodes/penalty_order".into(),
            message: format!(
                "need at least 1 cell, 4 grid nodes and a penalty order of 2 to 4, got {}, {}, {}",
                settings.cells, settings.grid_nodes, settings.penalty_order
            ),
        });
    }
    if let Some(l) = settings.smoothing {
        check_smoothing(l).map_err(|message| CalibError::Invalid {
            key: "smoothing".into(),
            message,
        })?;
    }
    check_marks(marks, MAX_HEIGHT_FRACTION * f)?;
    let half = marks
        .iter()
        .map(|m| m.x_cmd.abs().max(m.y_cmd.abs()))
        .fold(0.0, f64::max);
    if half <= 0.0 {
        return Err(CalibError::Degenerate(
            "every mark was commanded at the field centre".into(),
        ));
    }
    // Enough marks per cell: at most one cell per two mark columns (and rows).
    let distinct = |key: fn(&Mark) -> f64| {
        let mut v: Vec<i64> = marks
            .iter()
            .map(|m| (key(m) * COMMAND_KEY_PER_MM).round() as i64)
            .collect();
        v.sort_unstable();
        v.dedup();
        v.len()
    };
    let columns = distinct(|m| m.x_cmd).min(distinct(|m| m.y_cmd));
    if columns < 4 {
        return Err(CalibError::Degenerate(format!(
            "the marks span {columns} distinct commanded x or y values; a field needs a grid of \
             at least 4 × 4"
        )));
    }
    let cells = settings.cells.min(columns / 2).max(1);
    let basis = Basis { half, cells };
    let design = Design::new(&basis, marks, settings.penalty_order);
    let off_plane = marks.iter().filter(|m| m.h_mm != 0.0).count();
    let lambdas = settings.smoothing.map_or_else(lambda_grid, |l| vec![l]);
    let singular =
        || CalibError::Degenerate("the marks do not determine the field (singular fit)".into());
    let mut sm = choose_smoother(&design, marks, &lambdas, f).ok_or_else(singular)?;
    let pivot = if off_plane > 0 {
        let mut l = search_pivot(&design, &sm, marks, f);
        sm = choose_smoother(&design, marks, &lambdas, l).ok_or_else(singular)?;
        l = search_pivot(&design, &sm, marks, f);
        Some(l)
    } else {
        None
    };
    let l = pivot.unwrap_or(f);
    let solved = solve(&design, &sm, marks, l);
    let pivot_std_mm = pivot.map(|l| {
        // var(L) = 2σ²/RSS''(L), σ² the per-coordinate noise from the residual.
        let dof = (2.0 * marks.len() as f64 - 2.0 * sm.trace - 1.0).max(1.0);
        let sigma2 = solved.rss() / dof;
        let dl = 1e-3 * l;
        let rss = |x: f64| solve(&design, &sm, marks, x).rss();
        let curvature = (rss(l + dl) - 2.0 * rss(l) + rss(l - dl)) / (dl * dl);
        if curvature > 0.0 {
            (2.0 * sigma2 / curvature).sqrt()
        } else {
            f64::INFINITY
        }
    });
    let before = rms_max_um(marks.iter().map(|m| {
        let s = height_scale(f, m.h_mm);
        (m.x_meas - m.x_cmd * s).hypot(m.y_meas - m.y_cmd * s)
    }));
    let after = rms_max_um(solved.measured());
    let loo = loo_residuals(&design, &sm, &solved);
    refuse_blunders(marks, &loo)?;
    let (loo_rms_um, loo_max_um) = rms_max_um(loo.into_iter());
    let land = |c: [f64; 2]| {
        let mut d = c;
        for (k, v) in basis.row(c) {
            d[0] += v * solved.coef[0][k];
            d[1] += v * solved.coef[1][k];
        }
        d
    };
    let mut field = FieldCorrection::sample(half, settings.grid_nodes, land);
    field.pivot_to_focal_plane_mm = pivot;
    // The similarity part at the centre: offset, rotation and scale of the Jacobian.
    let offset = land([0.0, 0.0]);
    let e = 0.5;
    let (xp, xm, yp, ym) = (
        land([e, 0.0]),
        land([-e, 0.0]),
        land([0.0, e]),
        land([0.0, -e]),
    );
    let j = [
        [(xp[0] - xm[0]) / (2.0 * e), (yp[0] - ym[0]) / (2.0 * e)],
        [(xp[1] - xm[1]) / (2.0 * e), (yp[1] - ym[1]) / (2.0 * e)],
    ];
    let (cos_part, sin_part) = (0.5 * (j[0][0] + j[1][1]), 0.5 * (j[1][0] - j[0][1]));
    let report = FieldFitReport {
        marks: marks.len(),
        marks_off_plane: off_plane,
        commands: design.groups.len(),
        rms_before_um: before.0,
        max_before_um: before.1,
        rms_after_um: after.0,
        max_after_um: after.1,
        loo_rms_um,
        loo_max_um,
        pivot_to_focal_plane_mm: pivot,
        pivot_std_mm,
        offset_mm: offset,
        rotation_deg: sin_part.atan2(cos_part).to_degrees(),
        scale: cos_part.hypot(sin_part),
        smoothing: sm.lambda,
        penalty_order: settings.penalty_order,
        cells,
        effective_parameters: sm.trace,
        half_field_mm: half,
    };
    field.fit = serde_json::to_value(&report).map_err(|e| CalibError::Invalid {
        key: "fit report".into(),
        message: e.to_string(),
    })?;
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
    fn a_mistyped_mark_is_refused_naming_it_and_its_command() {
        let grid = MarkGrid {
            grid: 15,
            half_field_mm: 50.0,
            heights_mm: vec![0.0, 2.0],
            noise_um: 2.0,
            offset_fraction: 0.0,
        };
        let clean = synth_marks(&truth(), 262.0, &grid, 7);
        fit_field(&clean, &FieldFitSettings::default()).expect("clean marks fit");
        // Two digits swapped in one measured y: 21.43 typed for 12.43 is 9 mm; a misread of the
        // last digit shown, 0.05 mm, is still far beyond 2 µm noise.
        for (k, shift_mm) in [(37_usize, 9.0), (100, 0.05)] {
            let mut marks = clean.clone();
            marks[k].y_meas += shift_mm;
            let e = fit_field(&marks, &FieldFitSettings::default())
                .expect_err("a blunder is refused")
                .to_string();
            let m = &clean[k];
            let command = format!("the command ({:.4}, {:.4}) at h", m.x_cmd, m.y_cmd);
            assert!(
                e.starts_with(&format!("mark {}: measured at", k + 1))
                    && e.contains(&command)
                    && e.contains("correct or delete its row"),
                "{shift_mm} mm: {e}"
            );
        }
        // A shift within the measurement scatter is not a blunder.
        let mut marks = clean.clone();
        marks[37].y_meas += 0.004;
        fit_field(&marks, &FieldFitSettings::default()).expect("4 µm is measurement scatter");
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
            trim_geom::fs::write_atomic(&p, text).expect("write");
            let e = read_marks(&p).expect_err(text).to_string();
            assert!(e.contains("marks.csv") && e.contains(want), "{text:?}: {e}");
        }
    }
}
