//! The scanned edges as observations of the field (DESIGN.md, Registration step 4,
//! "Edge terms").
//!
//! The field is fitted to the faces. Where no face fixes a direction (a strip's slide along a
//! core's span, a corner's slide along the chord), its posterior is wide and its estimate is
//! whatever the smoothness prior makes of it. The scanned edge of each stretch
//! ([`super::scanned_edge`]) measures exactly the displacement the faces miss, across the edge:
//! the offset `o` is, to first order, the mean over the stretch's points of
//! `s·(Rᵀu)ᵀ·δ(xᵢ)`, with `δ = d_true − d` the field's error at the CAD point `xᵢ`, `u` the
//! stretch's outward direction (scan frame) and `s`, `R` the similarity's scale and rotation.
//! That is linear in the field's control displacements: a row `h`. The field's posterior
//! `N(c, Σ)` (given the faces) is conditioned on the readings `o ~ N(h·δ, r)`:
//!
//! ```text
//! K = Σ Hᵀ (H Σ Hᵀ + R)⁻¹,   c ← c + K o,   Σ ← Σ − K H Σ,
//! ```
//!
//! the Kalman update, with `r = σₑ² + floor²` per reading. The floor
//! ([`EDGE_TERM_FLOOR_MM`]) is the readings' scatter about the truth that their own `σₑ` does
//! not explain, measured on the outside generator's tune seeds; it is the same for a reading
//! from the wall and from the face's end. A reading the posterior finds implausible (`o² > 9·(hΣhᵀ + r)`) is left out: flash
//! standing off the edge reads as material far beyond it, and the laser is there to remove it,
//! not to follow it; so is a stretch whose face runs on beyond the contour
//! (`ScannedEdge::flash_share`), where a burr web in the face's plane would bias the reading
//! by a share of its height, and so is any reading of more material beyond the contour than
//! the `material_beyond` flag's threshold ([`ScannedEdge::shows_material_beyond`]), since a web
//! too low to count as flash reads the same (own burred core 305: a 53 µm web over 13 of 20 mm
//! read +41 µm and, taken, pulled the strip 40 µm off). The cap is that threshold, so every
//! reading of material beyond a strip either moves the field or flags the strip: until
//! 2026-11-28 the cap was 10 µm and the flag 15 µm, and strips reading 10–15 µm beyond were
//! neither corrected nor flagged (outside tune seeds 2001–2080: 12 of the 29 trusted contours
//! with a cross-edge P95 over 12 µm). An edge the registration put beyond the material is left
//! to the scanned-edge check, which puts the part in doubt. A reading left out for the material
//! beyond it (not flash) may still be the part lying out there: the move it would have made,
//! `k = Σhᵀ o / (hΣhᵀ + r)`, is added to the posterior as a possible one (`Σ ← Σ + k kᵀ`), so
//! the contours it would have carried have it in their bounds.

use nalgebra::{Cholesky, DMatrix, DVector, Dyn};
use trim_geom::{Path, Similarity3, Vector3};

use super::field_fit::{CheckPosterior, FieldPosterior};
use super::scanned_edge::{ScannedEdge, widest_gap_um};
use crate::deformation::{BSplineField, SUPPORT};

/// The scatter of a reading about the true edge that its own `σₑ` does not explain, mm:
/// `√(SD² − mean σₑ²)` of the readings before the update against the truth, on the outside
/// tune seeds 2001–2080 with the edge terms off. Re-measured 2026-11-29: 1.9 µm both for the
/// 1,398 readings located from the wall (residual SD 3.1 µm at an RMS σₑ of 2.5 µm; unbiased)
/// and for the 830 from the face's end (6.2 µm at 5.9 µm; bias −1.1 µm). Until then 3 µm for
/// the wall and 8 µm for the face (2026-11-27: SD 3.4 µm at a median σₑ of 2.4 µm, and 9.5 µm
/// at 5.8 µm, on that day's registration).
pub const EDGE_TERM_FLOOR_MM: f64 = 0.002;
/// A reading whose offset lies beyond this many predicted deviations is left out.
pub const EDGE_TERM_GATE_SIGMAS: f64 = 3.0;
/// Contour points per stretch whose field rows are averaged into the reading's row (evenly
/// spaced; the rest add nothing the spline does not already interpolate).
pub const EDGE_TERM_SAMPLES: usize = 16;

/// One reading as a row of the field's control displacements: `(sparse row, offset mm,
/// variance mm²)`.
type Row = (Vec<(usize, f64)>, f64, f64);

/// What the edge terms did.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EdgeTermSummary {
    /// Readings used.
    pub used: usize,
    /// Readings left out by the gate.
    pub gated: usize,
    /// Readings left out for the material beyond them ([`ScannedEdge::is_flash`],
    /// [`ScannedEdge::shows_material_beyond`]).
    pub flashed: usize,
    /// Of those, the readings showing material beyond (not flash) whose possible move widened
    /// the posterior.
    #[serde(default)]
    pub widened: usize,
    /// The largest change of the field along the path's points, mm (CAD frame).
    pub largest_shift_mm: f64,
}

impl EdgeTermSummary {
    /// Whether the update ran on every reading: none gated, none left out for the material
    /// beyond it.
    #[must_use]
    pub fn every_reading_used(&self) -> bool {
        self.used > 0 && self.gated == 0 && self.flashed == 0
    }

    /// The strips' widest gaps before the update (µm, one per contour of `readings`, the lists
    /// the update was given) that still count in `scan_edge_gap_um`: all of them when the terms
    /// left a reading out for the material beyond it (flash, or more than the cap), or when
    /// the update did not run, since a part corrected from one end only (the other end's
    /// readings left out as possible flash) shows its gap there before and no longer after,
    /// and the end left out cannot show a gap of its own; none otherwise. A reading the gate
    /// left out as implausible is no such end: it did not move the field, and the scanned-edge
    /// check reads it again after the update, where a gap over the tolerance flags its strip
    /// (outside fresh parts 8301, 8310 and 8311 at 500k: strips read 37–51 µm beyond the
    /// material before the update, 9–20 µm after, every contour within 30 µm, and the gap
    /// before put each good part in doubt because one or two readings elsewhere were gated).
    pub(crate) fn gaps_before(&self, readings: &[Vec<ScannedEdge>]) -> Vec<Option<f64>> {
        let count = self.used == 0 || self.flashed > 0;
        readings
            .iter()
            .map(|edges| widest_gap_um(edges).filter(|_| count))
            .collect()
    }
}

/// Conditions `field` and `posterior` on the scanned edges `readings` (one list per contour of
/// `path`, measured on the contours registered with `field`). `register` passes the strips'
/// readings only, a rim's list empty: rims check the registration but do not move the field
/// (the floors were measured on strips). Returns what the terms did and the readings they
/// took (one list per contour), for the model check ([`condition_check_on_edges`]).
pub(crate) fn condition_on_edges(
    field: &mut BSplineField,
    posterior: &mut FieldPosterior,
    path: &Path,
    readings: &[Vec<ScannedEdge>],
    scan_from_cad: &Similarity3,
) -> (EdgeTermSummary, Vec<Vec<ScannedEdge>>) {
    let Rows {
        rows,
        taken_from,
        beyond,
        flashed,
    } = rows(field, path, readings, scan_from_cad, None);
    let sigma = posterior.covariance();
    let (kept_at, columns, gated) = gate(&rows, sigma);
    let kept: Vec<Kept<'_>> = kept_at.iter().map(|&i| kept_row(&rows[i])).collect();
    let mut taken = vec![Vec::new(); readings.len()];
    for &i in &kept_at {
        let (contour, e) = taken_from[i];
        taken[contour].push(e);
    }
    let m = kept.len();
    let (mut used, mut largest_shift_mm) = (0, 0.0);
    if let Some((sht, chol)) = (m > 0).then(|| gain(columns, &kept)).flatten() {
        used = m;
        let o = DVector::from_iterator(m, kept.iter().map(|k| k.1));
        // Step: ΣHᵀ S⁻¹ o; covariance: Σ − ΣHᵀ S⁻¹ HΣ.
        let step = &sht * chol.solve(&o);
        posterior.subtract(&(&sht * chol.solve(&sht.transpose())));
        // The part's covariance takes the same readings (no step: the field moves once).
        let part = posterior.part_covariance().and_then(|c| {
            let columns = kept.iter().map(|(row, ..)| sigma_h(c, row)).collect();
            gain(columns, &kept)
        });
        if let Some((sht, chol)) = part {
            posterior.subtract_part(&(&sht * chol.solve(&sht.transpose())));
        }
        let before: Vec<_> = path
            .contours()
            .iter()
            .flat_map(|c| c.points().iter().map(|p| field.displacement(p)))
            .collect();
        field.add_step(step.as_slice());
        largest_shift_mm = path
            .contours()
            .iter()
            .flat_map(|c| c.points().iter().map(|p| field.displacement(p)))
            .zip(before)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
    }
    // A reading of material beyond the cap is a burr or the part lying out there; which, the
    // scan cannot tell. Had it been the part, the update would have moved the field by
    // `k = Σhᵀ o / (hΣhᵀ + r)` (under the posterior the kept readings left): that move is added
    // to the posterior as a possible one, `Σ ← Σ + k kᵀ`, so every contour it would have
    // carried along (a strip slid along the span by an end the scan shows out there) has it
    // in its bound.
    for (row, o, r) in &beyond {
        posterior.widen(&possible_move(posterior.covariance(), row, *o, *r));
        if let Some(c) = posterior.part_covariance() {
            let k = possible_move(c, row, *o, *r);
            posterior.widen_part(&k);
        }
    }
    let summary = EdgeTermSummary {
        used,
        gated,
        flashed,
        widened: beyond.len(),
        largest_shift_mm,
    };
    if used == 0 {
        // The update failed (S not positive definite): nothing was taken.
        taken.iter_mut().for_each(Vec::clear);
    }
    (summary, taken)
}

/// The model check's field `check` conditioned on the readings `taken` by the fit's field
/// ([`condition_on_edges`]), which they were measured on (`measured_on`), under the check's own
/// posterior: its step only (the check's posterior is not used after). A reading taken on
/// another field is what it would have read on this one: `o + h'·c' − h·c`, with `h'`, `c'` the
/// other field's row and control displacements and `h`, `c` this one's. The check takes exactly
/// the fit's readings, with no gate of its own: a reading the fit left out as implausible
/// would otherwise move the check alone, and the two would part by the reading the fit refused.
/// So the two fields are compared given the same data, faces and scanned edges alike, and where
/// a strip's readings fix what the prior left open, both follow them. Returns the readings
/// used.
pub(crate) fn condition_check_on_edges(
    check: &mut BSplineField,
    posterior: &CheckPosterior,
    path: &Path,
    taken: &[Vec<ScannedEdge>],
    scan_from_cad: &Similarity3,
    measured_on: &BSplineField,
) -> usize {
    let Rows { rows, .. } = rows(check, path, taken, scan_from_cad, Some(measured_on));
    let mut kept: Vec<Kept<'_>> = Vec::with_capacity(rows.len());
    let mut columns = Vec::with_capacity(rows.len());
    for row in &rows {
        if let Some(sh) = posterior.sigma_h(&row.0) {
            kept.push(kept_row(row));
            columns.push(sh);
        }
    }
    let m = kept.len();
    let Some((sht, chol)) = (m > 0).then(|| gain(columns, &kept)).flatten() else {
        return 0;
    };
    let o = DVector::from_iterator(m, kept.iter().map(|k| k.1));
    check.add_step((&sht * chol.solve(&o)).as_slice());
    m
}

/// The readings as rows of a field ([`rows`]).
struct Rows {
    /// The readings that may move the field.
    rows: Vec<Row>,
    /// For each of `rows`, its contour and reading.
    taken_from: Vec<(usize, ScannedEdge)>,
    /// The readings of more material beyond the strip than the cap.
    beyond: Vec<Row>,
    /// Readings left out for the material beyond them.
    flashed: usize,
}

/// One sparse row of `field` per reading: the mean of the stretch's sampled rows. A reading of
/// more material beyond the strip than the cap (not flash: its face does not run on) is kept
/// apart: it does not move the field, but widens the posterior by the move it would make.
/// Readings taken on the contours registered with `measured_on` are carried over to `field`
/// ([`condition_check_on_edges`]).
fn rows(
    field: &BSplineField,
    path: &Path,
    readings: &[Vec<ScannedEdge>],
    scan_from_cad: &Similarity3,
    measured_on: Option<&BSplineField>,
) -> Rows {
    let scale = scan_from_cad.scaling();
    let mut out = Rows {
        rows: Vec::new(),
        taken_from: Vec::new(),
        beyond: Vec::new(),
        flashed: 0,
    };
    for (index, (contour, edges)) in path.contours().iter().zip(readings).enumerate() {
        for e in edges {
            if e.is_flash() {
                out.flashed += 1;
                continue;
            }
            let outward = e.shows_material_beyond();
            out.flashed += usize::from(outward);
            let Some(row) = reading_row(field, contour, e, scale) else {
                continue;
            };
            let offset_mm = match measured_on {
                None => e.offset_mm,
                Some(other) => {
                    let Some(other_row) = reading_row(other, contour, e, scale) else {
                        continue;
                    };
                    e.offset_mm + row_value(&other_row, other) - row_value(&row, field)
                }
            };
            let reading = (
                row,
                offset_mm,
                e.sigma_mm.powi(2) + EDGE_TERM_FLOOR_MM * EDGE_TERM_FLOOR_MM,
            );
            if outward {
                out.beyond.push(reading);
            } else {
                out.rows.push(reading);
                out.taken_from.push((index, *e));
            }
        }
    }
    out
}

/// Gates each reading on its own predicted spread under the covariance `sigma`
/// (`o² > g²·(hΣhᵀ + r)` leaves it out): the indices of the readings kept, their columns of
/// `ΣHᵀ`, and how many were gated.
fn gate(rows: &[Row], sigma: &DMatrix<f64>) -> (Vec<usize>, Vec<DVector<f64>>, usize) {
    let mut kept = Vec::new();
    let mut columns = Vec::new();
    let mut gated = 0;
    for (i, (row, o, r)) in rows.iter().enumerate() {
        let sh = sigma_h(sigma, row);
        let hsh: f64 = row.iter().map(|&(j, v)| v * sh[j]).sum();
        if o * o > EDGE_TERM_GATE_SIGMAS.powi(2) * (hsh + r) {
            gated += 1;
            continue;
        }
        kept.push(i);
        columns.push(sh);
    }
    (kept, columns, gated)
}

/// A row as the update takes it.
fn kept_row(row: &Row) -> Kept<'_> {
    (&row.0, row.1, row.2)
}

/// The move `Σhᵀ o / (hΣhᵀ + r)` a reading `o` (variance `r`, sparse row `row`) would make
/// under the covariance `sigma`.
fn possible_move(sigma: &DMatrix<f64>, row: &[(usize, f64)], o: f64, r: f64) -> DVector<f64> {
    let sh = sigma_h(sigma, row);
    let hsh: f64 = row.iter().map(|&(j, v)| v * sh[j]).sum();
    sh * (o / (hsh + r))
}

/// The reading `e` of `contour` (CAD frame) as a sparse row of `field`'s control
/// displacements: the mean over the stretch's sampled points of `s·uᵀ·B(x)`, `u` the outward
/// direction; `None` for a stretch with no usable point.
fn reading_row(
    field: &BSplineField,
    contour: &trim_geom::Contour,
    e: &ScannedEdge,
    scale: f64,
) -> Option<Vec<(usize, f64)>> {
    let p = contour.points();
    let f = contour.features();
    if e.last <= e.first || e.last >= p.len() {
        return None;
    }
    let span = e.last - e.first;
    let samples = EDGE_TERM_SAMPLES.min(span + 1);
    let mut entries: Vec<(usize, f64)> = Vec::with_capacity(samples * SUPPORT * 3);
    for k in 0..samples {
        let i = e.first + (k * span) / (samples - 1).max(1);
        let (a, b) = (p[i.saturating_sub(1)], p[(i + 1).min(p.len() - 1)]);
        let Some(t) = (b - a).try_normalize(1e-12) else {
            continue;
        };
        let Some(across) = t.cross(&f[i]).try_normalize(1e-12) else {
            continue;
        };
        // The outward direction, from the CAD contour's own frame: the similarity turns
        // `t × f` as a whole, so the reading's sign carries over.
        let u: Vector3 = across * e.outward;
        let (index, value) = field.values(&p[i]);
        for m in 0..SUPPORT {
            if value[m] == 0.0 {
                continue;
            }
            for c in 0..3 {
                entries.push((3 * index[m] + c, scale * value[m] * u[c]));
            }
        }
    }
    if entries.is_empty() {
        return None;
    }
    let w = 1.0 / samples as f64;
    entries.sort_unstable_by_key(|x| x.0);
    let mut row: Vec<(usize, f64)> = Vec::new();
    for (j, v) in entries {
        match row.last_mut() {
            Some((last, acc)) if *last == j => *acc += w * v,
            _ => row.push((j, w * v)),
        }
    }
    Some(row)
}

/// The sparse row `row` applied to `field`'s control displacements, mm.
fn row_value(row: &[(usize, f64)], field: &BSplineField) -> f64 {
    let c = field.coefficients();
    row.iter().map(|&(j, v)| v * c[j / 3][j % 3]).sum()
}

/// A reading kept: its sparse row, offset (mm) and variance (mm²).
type Kept<'a> = (&'a Vec<(usize, f64)>, f64, f64);

/// The column `Σhᵀ` of the sparse row `row` under the covariance `sigma`.
fn sigma_h(sigma: &DMatrix<f64>, row: &[(usize, f64)]) -> DVector<f64> {
    let mut out = DVector::zeros(sigma.nrows());
    for &(j, v) in row {
        out.axpy(v, &sigma.column(j), 1.0);
    }
    out
}

/// `ΣHᵀ` (dim × m, from the kept readings' `columns`, [`sigma_h`]) and the Cholesky factor of
/// `S = HΣHᵀ + R` (m × m) for the readings `kept`; `None` when `S` is not positive definite.
fn gain(
    columns: Vec<DVector<f64>>,
    kept: &[Kept<'_>],
) -> Option<(DMatrix<f64>, Cholesky<f64, Dyn>)> {
    let m = kept.len();
    let sht = DMatrix::from_columns(&columns);
    let mut s = DMatrix::zeros(m, m);
    for (a, (row, _, r)) in kept.iter().enumerate() {
        for b in 0..m {
            s[(a, b)] = row.iter().map(|&(j, v)| v * sht[(j, b)]).sum::<f64>();
        }
        s[(a, a)] += r;
    }
    let s = (&s + s.transpose()) * 0.5;
    Some((sht, s.cholesky()?))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::regional::scanned_edge::EdgeFrom;
    use trim_geom::{Contour, Point3};

    /// A field over a 40 × 20 × 10 mm box with control points every 5 mm, each displacement
    /// component independent, scaled so that the displacement at the strip's middle has
    /// deviation `sd_mm` (a posterior the faces left wide), and a strip along x at y = 10 on
    /// the face z = 5 (feature +z), so across it is ±y.
    fn case(sd_mm: f64) -> (BSplineField, FieldPosterior, Path) {
        let field = BSplineField::zero(
            &Point3::new(0.0, 0.0, 0.0),
            &Point3::new(40.0, 20.0, 10.0),
            5.0,
        );
        let dim = 3 * field.len();
        let (_, value) = field.values(&MID);
        let sum: f64 = value.iter().map(|v| v * v).sum();
        let posterior =
            FieldPosterior::from_covariance(DMatrix::identity(dim, dim) * (sd_mm * sd_mm / sum));
        let strip: Vec<Point3> = (0..=200)
            .map(|i| Point3::new(10.0 + 0.1 * i as f64, 10.0, 5.0))
            .collect();
        let path = Path::new(vec![Contour::new(3, strip, Vector3::z()).unwrap()]).unwrap();
        (field, posterior, path)
    }

    fn reading(offset_mm: f64, from: EdgeFrom) -> ScannedEdge {
        ScannedEdge {
            at_mm: 10.0,
            offset_mm,
            sigma_mm: 0.002,
            points: 200,
            from,
            first: 0,
            last: 200,
            flash_share: 0.0,
            gap_sigmas: crate::regional::EDGE_GAP_SIGMAS,
            // t × f = x × z = −y: outward is +y.
            outward: -1.0,
            size_mm: 0.0,
            slide_sigma_mm: 0.002,
        }
    }

    /// [`case`] conditioned on the one reading `e`: the field after, and what the terms did.
    fn conditioned(sd_mm: f64, e: ScannedEdge) -> (BSplineField, EdgeTermSummary) {
        let (mut field, mut posterior, path) = case(sd_mm);
        let (summary, _) = condition_on_edges(
            &mut field,
            &mut posterior,
            &path,
            &[vec![e]],
            &Similarity3::identity(),
        );
        (field, summary)
    }

    /// The strip's middle.
    const MID: Point3 = Point3::new(20.0, 10.0, 5.0);

    /// The variance of the displacement along `u` at `x`.
    fn variance(field: &BSplineField, posterior: &FieldPosterior, x: &Point3, u: &Vector3) -> f64 {
        (u.transpose() * posterior.displacement_covariance(field, x) * u)[(0, 0)]
    }

    #[test]
    fn a_reading_moves_the_edge_toward_the_scan_and_narrows_the_posterior_across_it() {
        let (mut field, mut posterior, path) = case(0.025);
        let mid = MID;
        let before = variance(&field, &posterior, &mid, &Vector3::y());
        // The scan shows the edge 40 µm short of the registered one (the contour lies beyond
        // the material, −y).
        let (summary, _) = condition_on_edges(
            &mut field,
            &mut posterior,
            &path,
            &[vec![reading(-0.04, EdgeFrom::Wall)]],
            &Similarity3::identity(),
        );
        assert_eq!((summary.used, summary.gated), (1, 0));
        assert!(summary.every_reading_used());
        // The reading is the stretch's mean offset. A prior of about 25 µm against a reading
        // good to 2.8 µm: most of the 40 µm is taken.
        let points = path.contours()[0].points();
        let mean =
            -points.iter().map(|p| field.displacement(p).y).sum::<f64>() / points.len() as f64;
        assert!(
            mean > 0.03 && mean < 0.04,
            "moved {mean:.4} mm inward on average"
        );
        let d = field.displacement(&mid);
        assert!(
            d.x.abs() < 1e-9 && d.z.abs() < 1e-9,
            "moved along or off the face: {d:?}"
        );
        let after = variance(&field, &posterior, &mid, &Vector3::y());
        // One mean over 20 mm of independent control points: the middle's variance about halves.
        assert!(
            after < 0.6 * before,
            "variance across {before:.2e} -> {after:.2e}"
        );
        // Along the strip and off the face the reading says nothing.
        let along = variance(&field, &posterior, &mid, &Vector3::x());
        assert!((along - before).abs() < 1e-12 * before.max(1.0) + 1e-15);
    }

    /// The check's posterior with the information of `posterior` (no band: diagonal).
    fn check_posterior_of(posterior: &FieldPosterior) -> CheckPosterior {
        let information = posterior
            .covariance()
            .clone()
            .try_inverse()
            .expect("a diagonal covariance");
        CheckPosterior::new(&information, 0, 1.0).expect("positive definite")
    }

    /// The fit conditioned on `readings`, then the check on the readings the fit took, as
    /// `register` does: what the fit did, what it took, and how many the check used.
    fn condition_both(
        fit: &mut BSplineField,
        posterior: &mut FieldPosterior,
        check: &mut BSplineField,
        check_posterior: &CheckPosterior,
        path: &Path,
        readings: &[Vec<ScannedEdge>],
    ) -> (EdgeTermSummary, Vec<Vec<ScannedEdge>>, usize) {
        let measured_on = fit.clone();
        let identity = Similarity3::identity();
        let (summary, taken) = condition_on_edges(fit, posterior, path, readings, &identity);
        let used = condition_check_on_edges(
            check,
            check_posterior,
            path,
            &taken,
            &identity,
            &measured_on,
        );
        (summary, taken, used)
    }

    #[test]
    fn the_model_check_takes_the_fits_readings_as_they_would_read_on_it() {
        // The fit's field 30 µm along +y (outward) everywhere, the check's at zero, both with
        // the same wide posterior. The scan shows the edge 40 µm inside the contour as the fit
        // registered it: 10 µm inside the CAD's, which is what the check must read.
        let (mut fit, mut posterior, path) = case(0.025);
        let mut check = fit.clone();
        let dim = 3 * fit.len();
        let mut step = vec![0.0; dim];
        for k in 0..fit.len() {
            step[3 * k + 1] = 0.03;
        }
        fit.add_step(&step);
        let check_posterior = check_posterior_of(&posterior);
        let readings = [vec![reading(-0.04, EdgeFrom::Wall)]];
        let points = path.contours()[0].points();
        let mean_y = |f: &BSplineField| {
            points.iter().map(|p| f.displacement(p).y).sum::<f64>() / points.len() as f64
        };
        let apart_before = mean_y(&fit) - mean_y(&check);
        let (summary, taken, used) = condition_both(
            &mut fit,
            &mut posterior,
            &mut check,
            &check_posterior,
            &path,
            &readings,
        );
        assert_eq!((summary.used, taken.as_slice()), (1, readings.as_slice()));
        assert_eq!(used, 1);
        // On its own the check moves toward −10 µm, not toward the −40 µm the fit read.
        let moved = mean_y(&check);
        assert!(
            moved < -0.007 && moved > -0.0105,
            "the check moved {moved:.4} mm along y"
        );
        // Given the same reading, the two fields now nearly agree on the strip.
        let apart_after = (mean_y(&fit) - mean_y(&check)).abs();
        assert!(
            (apart_before - 0.03).abs() < 1e-9 && apart_after < 0.2 * apart_before,
            "{apart_before:.4} -> {apart_after:.4} mm apart"
        );
    }

    #[test]
    fn the_model_check_takes_no_reading_the_fit_left_out() {
        // The fit's posterior narrow (10 µm), the check's wide (100 µm): the scan shows the edge
        // 200 µm inside, which the fit's gate leaves out as implausible and the check's own
        // gate would have kept. The check must not move by it, or the two would part by the
        // reading the fit refused.
        let (mut fit, mut posterior, path) = case(0.01);
        let (mut check, wide, _) = case(0.1);
        let check_posterior = check_posterior_of(&wide);
        let readings = [vec![reading(-0.2, EdgeFrom::Face)]];
        let (summary, taken, used) = condition_both(
            &mut fit,
            &mut posterior,
            &mut check,
            &check_posterior,
            &path,
            &readings,
        );
        assert_eq!((summary.used, summary.gated), (0, 1));
        assert!(taken.iter().all(Vec::is_empty));
        assert_eq!(used, 0);
        assert_eq!(check.displacement(&MID), Vector3::zeros());
    }

    #[test]
    fn an_implausible_reading_is_left_out() {
        // The contour 200 µm beyond the material where the posterior allows 10 µm: left to
        // the scanned-edge check.
        let (field, summary) = conditioned(0.01, reading(-0.2, EdgeFrom::Face));
        assert_eq!((summary.used, summary.gated), (0, 1));
        assert!(!summary.every_reading_used());
        assert_eq!(field.displacement(&MID), Vector3::zeros());
    }

    #[test]
    fn material_beyond_the_edge_is_left_out() {
        // 25 µm more material than the contour: a low web reads the same, and the strip is
        // flagged `material_beyond` instead.
        let (field, summary) = conditioned(0.025, reading(0.025, EdgeFrom::Wall));
        assert_eq!((summary.used, summary.flashed), (0, 1));
        assert_eq!(field.displacement(&MID), Vector3::zeros());
    }

    #[test]
    fn material_beyond_the_cap_widens_the_posterior_by_the_move_it_would_make() {
        // 25 µm beyond, over the cap: the field stays, but the strip's deviation across its
        // edge grows, in quadrature, by exactly the move the reading would have made had it
        // been taken: 25/15 of what a 15 µm reading (under the cap, taken) moves the middle.
        let (mut field, mut posterior, path) = case(0.025);
        let before = variance(&field, &posterior, &MID, &Vector3::y());
        let (summary, _) = condition_on_edges(
            &mut field,
            &mut posterior,
            &path,
            &[vec![reading(0.025, EdgeFrom::Wall)]],
            &Similarity3::identity(),
        );
        assert_eq!((summary.used, summary.flashed, summary.widened), (0, 1, 1));
        assert!(!summary.every_reading_used());
        assert_eq!(field.displacement(&MID), Vector3::zeros());
        let grown = (variance(&field, &posterior, &MID, &Vector3::y()) - before).sqrt();
        let taken = conditioned(0.025, reading(0.015, EdgeFrom::Wall)).0;
        let would = taken.displacement(&MID).y * 0.025 / 0.015;
        assert!(
            (grown - would).abs() < 1e-9 && would > 0.02,
            "grew by {grown:.6} mm in quadrature, the reading would have moved it {would:.6} mm"
        );
        // Flash widens nothing: its face shows the burr.
        let (mut field, mut posterior, path) = case(0.025);
        let flash = ScannedEdge {
            flash_share: 0.1,
            ..reading(0.025, EdgeFrom::Wall)
        };
        let (summary, _) = condition_on_edges(
            &mut field,
            &mut posterior,
            &path,
            &[vec![flash]],
            &Similarity3::identity(),
        );
        assert_eq!((summary.flashed, summary.widened), (1, 0));
        let after = variance(&field, &posterior, &MID, &Vector3::y());
        assert!((after - before).abs() < 1e-15, "{before} -> {after}");
    }

    #[test]
    fn material_beyond_the_edge_within_the_flags_threshold_moves_the_field() {
        // 15 µm more material than the contour, under `MATERIAL_BEYOND_MM`: no flag would
        // follow, so the reading moves the strip outward (+y). The reading is the stretch's
        // mean offset; a prior of about 25 µm against a wall reading good to 3.6 µm takes most
        // of it.
        let (field, summary) = conditioned(0.025, reading(0.015, EdgeFrom::Wall));
        assert_eq!((summary.used, summary.flashed), (1, 0));
        let points = [10.0, 15.0, 20.0, 25.0, 30.0].map(|x| Point3::new(x, 10.0, 5.0));
        let mean = points.iter().map(|p| field.displacement(p).y).sum::<f64>() / 5.0;
        assert!(
            (0.011..0.015).contains(&mean),
            "moved {mean:.4} mm outward on average"
        );
    }

    #[test]
    fn a_gap_before_the_update_counts_only_when_a_reading_was_left_out_for_the_material_beyond() {
        // A strip 50 µm beyond the material before the update (gap 50 − 2 × 2 = 46 µm) and a
        // strip with no reading.
        let readings = vec![vec![reading(-0.05, EdgeFrom::Wall)], Vec::new()];
        let all_used = EdgeTermSummary {
            used: 3,
            ..EdgeTermSummary::default()
        };
        assert_eq!(all_used.gaps_before(&readings), [None, None]);
        // A reading gated as implausible: it is read again after the update, and the gap
        // before does not count.
        let gated = EdgeTermSummary {
            gated: 2,
            ..all_used
        };
        assert_eq!(gated.gaps_before(&readings), [None, None]);
        // One reading left out for the material beyond it, with or without one gated: the
        // gap before counts.
        for left_out in [
            EdgeTermSummary {
                gated: 1,
                flashed: 1,
                ..all_used
            },
            EdgeTermSummary {
                flashed: 1,
                widened: 1,
                ..all_used
            },
            // The update did not run.
            EdgeTermSummary::default(),
        ] {
            let gaps = left_out.gaps_before(&readings);
            assert!(
                gaps[0].is_some_and(|g| (g - 46.0).abs() < 1e-9) && gaps[1].is_none(),
                "{left_out:?}: {gaps:?}"
            );
        }
    }

    #[test]
    fn a_stretch_whose_face_runs_on_beyond_the_edge_is_left_out() {
        // 5 µm read where 10 % of the face stands beyond 60 µm: a web biased it.
        let flashed = ScannedEdge {
            flash_share: 0.1,
            ..reading(0.005, EdgeFrom::Face)
        };
        let (field, summary) = conditioned(0.025, flashed);
        assert_eq!((summary.used, summary.flashed), (0, 1));
        assert!(!summary.every_reading_used());
        assert_eq!(field.displacement(&MID), Vector3::zeros());
    }

    #[test]
    fn a_reading_counts_by_its_own_deviation_wherever_it_was_located() {
        // One floor for the wall and the face (measured the same, 2 µm): what weighs a
        // reading is its own σₑ, which a face's end (few points at the edge) makes wider.
        let moved = |from, sigma_mm| {
            let mut e = reading(-0.02, from);
            e.sigma_mm = sigma_mm;
            -conditioned(0.015, e).0.displacement(&MID).y
        };
        let (wall, face) = (moved(EdgeFrom::Wall, 0.002), moved(EdgeFrom::Face, 0.002));
        assert!(
            wall > 0.0 && (face - wall).abs() < 1e-12,
            "face {face:.4}, wall {wall:.4}"
        );
        let wider = moved(EdgeFrom::Face, 0.006);
        assert!(
            wider > 0.0 && wider < 0.9 * face,
            "σₑ 6 µm moved {wider:.4}, 2 µm {face:.4}"
        );
    }
}
