//! What the landed lines remove from the films over blocked openings (DESIGN.md "Ablation and
//! the twin's part"; issue 23: "a blockage is cleared where hatch tracks remove its thickness").
//!
//! A film ([`Film`]) keeps, on a grid of [`trim_synth::FILM_GRID_MM`] over its opening (domain
//! plane), the depth removed from its top. Every landed mark vector ([`LandedCut`]) sweeps a
//! kerf `w` wide along it: a grid cell whose centre lies within `w/2` of the landed segment
//! (measured on the part, through the map from the domain plane to the work-piece frame), and
//! whose segment runs on the film's top (within [`ON_FILM_MM`] along the face normal), loses one
//! pass's depth ([`ProcessSettings::depth_per_pass_um`]). Where the depths add up to the film's
//! thickness the film is cleared; elsewhere it stands, thinner. So tracks a pitch `p` apart
//! clear a film only where their kerfs meet (`p ≤ w`): with `p > w` a strip `p − w` wide stands
//! between every two tracks, whatever the passes.
//!
//! One sweep of the beam counts once: the vectors of one marking of a polyline join end to end,
//! and a cell within reach of two of them (at a joint) is swept once. Consecutive vectors whose
//! ends meet form one sweep ("chain"); a chain ends where the beam jumps, and where a closed
//! polyline's next pass begins (its first vector again).
//!
//! The segment is carried into the domain plane by inverting the map at its two ends
//! (Gauss–Newton from the nearest of a coarse set of mapped points) and is straight there
//! between them; distances are measured through the map's Jacobian at the segment's middle, so
//! they are in millimetres on the part. Over a mark vector (≤ a few mm) the map of the
//! synthetic core is affine to well under a micrometre.

use trim_cell::ProcessSettings;
use trim_geom::kdtree::KdTree;
use trim_geom::{Point3, Vector3};
use trim_synth::{FILM_GRID_MM, Film};

use crate::ablation::LandedCut;

/// How far off the film's top (mm, along the face normal) a landed cut still counts as on it:
/// as for the edges' cuts ([`crate::ablation`]).
pub const ON_FILM_MM: f64 = 0.3;

/// The step (domain mm) of the mapped points a cut's end starts its inversion from.
const COARSE_MM: f64 = 0.25;

/// Gauss–Newton steps inverting the map at a cut's end (each gains several digits: the map is
/// nearly affine).
const INVERSE_STEPS: usize = 6;

/// The domain step of the map's finite-difference Jacobian, mm.
const JACOBIAN_MM: f64 = 1e-3;

/// Cut ends closer than this (mm) meet: the vectors belong to one sweep of the beam.
const JOIN_MM: f64 = 1e-9;

/// What the cuts did to one film.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct FilmOutcome {
    /// The contour that rims the film's opening.
    pub contour: i64,
    /// The film's grid cells (by their centres) the cuts of this call reached (each once however
    /// many passes).
    pub cells_cut: usize,
    /// The share of the film as drawn still standing after them.
    pub standing_share: f64,
    /// The share of the opening still covered.
    pub covered_share: f64,
}

/// The map from a film's domain plane to the part (work-piece frame, mm): the top face, which
/// the film is flush with, over the domain point `(u, v)`.
pub type TopFace<'a> = &'a dyn Fn(f64, f64) -> Point3;

/// The Jacobian of `top` at `(u, v)`: its columns ∂/∂u and ∂/∂v, mm per mm.
fn jacobian(top: TopFace<'_>, u: f64, v: f64) -> (Vector3, Vector3) {
    let h = JACOBIAN_MM;
    (
        (top(u + h, v) - top(u - h, v)) / (2.0 * h),
        (top(u, v + h) - top(u, v - h)) / (2.0 * h),
    )
}

/// A film's map and its inverse.
struct FilmMap<'a> {
    top: TopFace<'a>,
    coarse: Vec<[f64; 2]>,
    tree: KdTree,
    /// A sphere holding the film's top, work-piece frame: its centre and radius, mm.
    centre: Point3,
    radius: f64,
}

impl<'a> FilmMap<'a> {
    fn new(film: &Film, top: TopFace<'a>) -> Self {
        let (cols, rows) = film.grid();
        let [u0, v0] = film.cell_centre(0, 0);
        let [u1, v1] = film.cell_centre(cols.saturating_sub(1), rows.saturating_sub(1));
        let steps = |a: f64, b: f64| ((b - a) / COARSE_MM).ceil().max(1.0) as usize;
        let (nu, nv) = (steps(u0, u1), steps(v0, v1));
        let mut coarse = Vec::with_capacity((nu + 1) * (nv + 1));
        for i in 0..=nu {
            for j in 0..=nv {
                coarse.push([
                    u0 + (u1 - u0) * i as f64 / nu as f64,
                    v0 + (v1 - v0) * j as f64 / nv as f64,
                ]);
            }
        }
        let mapped: Vec<Point3> = coarse.iter().map(|[u, v]| top(*u, *v)).collect();
        let centre = top((u0 + u1) / 2.0, (v0 + v1) / 2.0);
        let radius = mapped
            .iter()
            .map(|p| (p - centre).norm())
            .fold(0.0, f64::max)
            + COARSE_MM;
        FilmMap {
            top,
            coarse,
            tree: KdTree::build(&mapped),
            centre,
            radius,
        }
    }

    /// Whether a cut's kerf may reach the film: the segment passes within `reach` of the
    /// sphere holding it.
    fn near(&self, cut: &LandedCut, reach: f64) -> bool {
        let d = cut.to - cut.from;
        let len2 = d.norm_squared();
        let t = if len2 > 0.0 {
            ((self.centre - cut.from).dot(&d) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (cut.from + d * t - self.centre).norm() <= self.radius + reach
    }

    /// The domain point under `p` and `p`'s height above the top face there (mm, along its
    /// normal), or none when the inversion does not settle (a point far off the part).
    fn invert(&self, p: &Point3) -> Option<([f64; 2], f64)> {
        let near = self.tree.nearest(p)?;
        let [mut u, mut v] = self.coarse[near.index];
        for _ in 0..INVERSE_STEPS {
            let (ju, jv) = jacobian(self.top, u, v);
            let r = p - (self.top)(u, v);
            // Least squares in the tangent plane: [ju jv]ᵀ[ju jv] δ = [ju jv]ᵀ r.
            let (a, b, c) = (ju.dot(&ju), ju.dot(&jv), jv.dot(&jv));
            let det = a * c - b * b;
            if det.is_nan() || det.abs() <= 1e-12 {
                return None;
            }
            let (ru, rv) = (ju.dot(&r), jv.dot(&r));
            u += (c * ru - b * rv) / det;
            v += (a * rv - b * ru) / det;
        }
        let (ju, jv) = jacobian(self.top, u, v);
        let n = ju.cross(&jv).try_normalize(1e-12)?;
        let height = (p - (self.top)(u, v)).dot(&n);
        (u.is_finite() && v.is_finite() && height.is_finite()).then_some(([u, v], height))
    }
}

/// Removes from `films` what `cuts` take (kerf `kerf_mm` wide, `process`'s depth per pass),
/// each film's top face placed by `top(film, u, v)` (work-piece frame, mm). Returns each film's
/// outcome, in `films`' order.
pub fn clear_films(
    films: &mut [Film],
    top: &dyn Fn(&Film, f64, f64) -> Point3,
    cuts: &[LandedCut],
    process: &ProcessSettings,
    kerf_mm: f64,
) -> Vec<FilmOutcome> {
    let chains = chains(cuts);
    let depth = process.depth_per_pass_mm();
    let half = kerf_mm / 2.0;
    films
        .iter_mut()
        .map(|film| {
            let snapshot = film.clone();
            let face = |u: f64, v: f64| top(&snapshot, u, v);
            let map = FilmMap::new(&snapshot, &face);
            let (cols, rows) = film.grid();
            let mut stamp = vec![u32::MAX; cols * rows];
            let mut cells_cut = 0usize;
            for (cut, chain) in cuts.iter().zip(&chains) {
                if !map.near(cut, half + ON_FILM_MM) {
                    continue;
                }
                let (Some((a, ha)), Some((b, hb))) = (map.invert(&cut.from), map.invert(&cut.to))
                else {
                    continue;
                };
                if ha.abs() > ON_FILM_MM && hb.abs() > ON_FILM_MM && ha * hb > 0.0 {
                    continue;
                }
                let mid = [(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0];
                let (ju, jv) = jacobian(&face, mid[0], mid[1]);
                // The domain reach of half a kerf: through the Jacobian's smallest stretch.
                let stretch = ju.norm().min(jv.norm()).max(1e-6);
                let reach = half / stretch * 1.5 + FILM_GRID_MM;
                let (is, js) = snapshot.cells_in(
                    [a[0].min(b[0]) - reach, a[0].max(b[0]) + reach],
                    [a[1].min(b[1]) - reach, a[1].max(b[1]) + reach],
                );
                let seg = ju * (b[0] - a[0]) + jv * (b[1] - a[1]);
                let len2 = seg.norm_squared();
                for j in js {
                    for i in is.clone() {
                        let k = j * cols + i;
                        // Every cell the kerf reaches loses the depth, the film's or not at
                        // its centre: a cell on the free edge whose centre lies just past it
                        // still holds film on its inner part, and the film there is read by
                        // that cell (`Film::remaining_at`). Skipping it left a 10 µm strip
                        // along the whole free edge standing under any hatch, which the
                        // rescan sampled as an uncut free edge (a cleared opening read 10 %
                        // covered, and its rim a 162 µm "web").
                        if stamp[k] == *chain {
                            continue;
                        }
                        let [u, v] = snapshot.cell_centre(i, j);
                        let x = ju * (u - a[0]) + jv * (v - a[1]);
                        let t = if len2 > 0.0 {
                            (x.dot(&seg) / len2).clamp(0.0, 1.0)
                        } else {
                            0.0
                        };
                        let height = ha + t * (hb - ha);
                        if (x - seg * t).norm() <= half && height.abs() <= ON_FILM_MM {
                            if stamp[k] == u32::MAX && snapshot.covers_cell(i, j) {
                                cells_cut += 1;
                            }
                            stamp[k] = *chain;
                            film.remove(i, j, depth);
                        }
                    }
                }
            }
            FilmOutcome {
                contour: film.contour(),
                cells_cut,
                standing_share: film.standing_share(),
                covered_share: film.covered_share(),
            }
        })
        .collect()
}

/// Each cut's sweep: consecutive cuts whose ends meet share one, until the beam jumps or a
/// closed polyline's next pass begins (its first vector comes round again).
fn chains(cuts: &[LandedCut]) -> Vec<u32> {
    let mut out = Vec::with_capacity(cuts.len());
    let mut chain = 0u32;
    let mut first: Option<&LandedCut> = None;
    let mut prev: Option<&LandedCut> = None;
    for c in cuts {
        let joined = prev.is_some_and(|p| (c.from - p.to).norm() <= JOIN_MM);
        let round_again = first.is_some_and(|f| {
            (c.from - f.from).norm() <= JOIN_MM && (c.to - f.to).norm() <= JOIN_MM
        });
        if prev.is_some() && (!joined || round_again) {
            chain = chain.wrapping_add(1) % (u32::MAX - 1);
            first = Some(c);
        } else if first.is_none() {
            first = Some(c);
        }
        out.push(chain);
        prev = Some(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use trim_synth::{Blockage, Film};

    /// A film over all of the round hole of contour 7 (domain centre (−16, −30), radius 1.5,
    /// see `trim_synth::part::cutouts`), `thickness_mm` thick.
    fn film(thickness_mm: f64) -> Film {
        Film::new(&Blockage {
            contour: 7,
            covered_share: 1.0,
            thickness_mm,
            direction: [1.0, 0.0],
            offset_mm: 10.0,
        })
        .unwrap()
    }

    /// The top face: the domain plane itself, lifted to z = 1 (an isometry, so distances on
    /// the part are domain distances).
    fn flat(_: &Film, u: f64, v: f64) -> Point3 {
        Point3::new(u, v, 1.0)
    }

    /// Tracks along u across the hole, `pitch` apart (v from the centre), each in vectors of
    /// 0.5 mm, the whole set marked `passes` times; at height `z`.
    fn hatch(pitch: f64, passes: usize, z: f64) -> Vec<LandedCut> {
        let (cu, cv) = (-16.0, -30.0);
        let n = (1.6 / pitch).ceil() as i32;
        let mut cuts = Vec::new();
        for _ in 0..passes {
            for k in -n..=n {
                let v = cv + f64::from(k) * pitch;
                for s in 0..8 {
                    let u0 = cu - 2.0 + 0.5 * f64::from(s);
                    cuts.push(LandedCut {
                        from: Point3::new(u0, v, z),
                        to: Point3::new(u0 + 0.5, v, z),
                    });
                }
            }
        }
        cuts
    }

    fn process(depth_um: f64) -> ProcessSettings {
        ProcessSettings {
            depth_per_pass_um: depth_um,
            kerf_width_um: None,
        }
    }

    /// [`clear_films`] on the flat face, 40 µm a pass, a 41 µm kerf.
    fn clear(films: &mut [Film], cuts: &[LandedCut]) -> Vec<FilmOutcome> {
        clear_films(films, &flat, cuts, &process(40.0), 0.041)
    }

    fn cleared(f: &Film) -> f64 {
        1.0 - f.standing_share()
    }

    #[test]
    fn tracks_whose_kerfs_meet_with_enough_passes_clear_the_film() {
        // 100 µm thick, 40 µm a pass: three passes; pitch 30 µm under a 41 µm kerf.
        let mut films = vec![film(0.1)];
        let out = clear(&mut films, &hatch(0.03, 3, 1.0));
        assert!(out[0].standing_share < 1e-9, "{out:?}");
        assert!(out[0].covered_share < 1e-9, "{out:?}");
        assert!(out[0].cells_cut > 60_000, "{out:?}");
    }

    /// A film over part of the hole, its free edge slanted across the cells: a hatch that
    /// clears the film leaves no strip standing along the free edge. The cells the edge cuts
    /// through whose centres lie just past it hold film on their inner part; they must lose
    /// the depth too, or the rescan samples the whole free edge as standing (it did: a cleared
    /// opening read 10 % covered).
    #[test]
    fn a_cleared_film_leaves_nothing_along_its_free_edge() {
        let direction = [0.6, 0.8];
        let offset_mm = 0.3;
        let mut films = vec![
            Film::new(&Blockage {
                contour: 7,
                covered_share: 0.6,
                thickness_mm: 0.1,
                direction,
                offset_mm,
            })
            .unwrap(),
        ];
        let out = clear(&mut films, &hatch(0.03, 3, 1.0));
        assert!(out[0].standing_share < 1e-9, "{out:?}");
        // Points a hair inside the free edge, all along the chord it makes across the hole
        // (radius 1.5 mm about (−16, −30); the chord's half-length is √(1.5² − 0.3²)).
        let (cu, cv) = (-16.0, -30.0);
        let half = (1.5f64.powi(2) - offset_mm * offset_mm).sqrt() - 0.01;
        let along = [-direction[1], direction[0]];
        let standing: Vec<f64> = (0..=400)
            .map(|k| -half + 2.0 * half * f64::from(k) / 400.0)
            .filter(|s| {
                let d = offset_mm - 1e-6;
                let (u, v) = (
                    cu + d * direction[0] + s * along[0],
                    cv + d * direction[1] + s * along[1],
                );
                films[0].remaining_at(u, v) > 0.0
            })
            .collect();
        assert!(
            standing.is_empty(),
            "{} points stand: {standing:?}",
            standing.len()
        );
    }

    #[test]
    fn too_few_passes_thin_the_film_but_leave_it_standing() {
        let mut films = vec![film(0.1)];
        let out = clear(&mut films, &hatch(0.03, 2, 1.0));
        // Where two kerfs overlap a cell gets 2 × 2 passes = 160 µm: cleared; where one
        // reaches it, 80 µm of 100: standing, 20 µm thin. Kerf 41 on pitch 30: overlaps of
        // 11 µm in every 30 µm, about a third.
        let standing = out[0].standing_share;
        assert!((0.55..0.8).contains(&standing), "{out:?}");
        // A single pass clears nothing of a 100 µm film... and one of two passes of a 60 µm
        // film clears only the overlaps.
        let mut films = vec![film(0.1)];
        let out = clear(&mut films, &hatch(0.03, 1, 1.0));
        assert!((out[0].standing_share - 1.0).abs() < 1e-12, "{out:?}");
        assert!((films[0].remaining_at(-16.0, -30.0) - 0.06).abs() < 1e-9);
    }

    #[test]
    fn tracks_farther_apart_than_the_kerf_leave_strips_whatever_the_passes() {
        // Pitch 50 µm on a 41 µm kerf: a 9 µm strip between every two tracks, about 18 % of
        // the film (on a 10 µm grid: 0 or 1 cell of every 5).
        let mut films = vec![film(0.05)];
        let out = clear(&mut films, &hatch(0.05, 10, 1.0));
        assert!(
            (0.1..0.3).contains(&out[0].standing_share),
            "standing {out:?}"
        );
        assert!(cleared(&films[0]) > 0.7);
    }

    #[test]
    fn cuts_off_the_film_or_over_part_of_it_clear_only_what_they_reach() {
        // 2 mm above the face: off the film, nothing.
        let mut films = vec![film(0.05)];
        let out = clear(&mut films, &hatch(0.03, 3, 3.0));
        assert_eq!(
            (out[0].cells_cut, out[0].standing_share),
            (0, 1.0),
            "{out:?}"
        );
        // Tracks over the half v < centre only: about half cleared, the other half whole.
        let half: Vec<LandedCut> = hatch(0.03, 3, 1.0)
            .into_iter()
            .filter(|c| c.from.y < -30.0 - 0.0205)
            .collect();
        let out = clear(&mut films, &half);
        assert!((out[0].standing_share - 0.5).abs() < 0.05, "{out:?}");
        assert!(films[0].remaining_at(-16.0, -29.5) > 0.049);
        assert_eq!(films[0].remaining_at(-16.0, -30.5), 0.0);
        // No cuts, no films: nothing happens, nothing panics.
        assert!(clear(&mut [], &half).is_empty());
        let out = clear(&mut films, &[]);
        assert_eq!(out[0].cells_cut, 0);
    }

    #[test]
    fn a_sweep_counts_once_at_its_joints_and_a_closed_loop_once_a_pass() {
        let p = |x: f64, y: f64| Point3::new(x, y, 0.0);
        let square = [
            p(0.0, 0.0),
            p(1.0, 0.0),
            p(1.0, 1.0),
            p(0.0, 1.0),
            p(0.0, 0.0),
        ];
        let loop_once: Vec<LandedCut> = square
            .windows(2)
            .map(|w| LandedCut {
                from: w[0],
                to: w[1],
            })
            .collect();
        let twice: Vec<LandedCut> = loop_once.iter().chain(&loop_once).copied().collect();
        assert_eq!(chains(&twice), vec![0, 0, 0, 0, 1, 1, 1, 1]);
        let mut jumped = loop_once.clone();
        jumped[2].from.x += 0.5;
        assert_eq!(chains(&jumped), vec![0, 0, 1, 1]);
        // On a film: a closed loop marked twice removes two passes at a corner, not four.
        let mut films = vec![film(0.2)];
        let corner: Vec<LandedCut> = [
            p(-16.5, -30.5),
            p(-15.5, -30.5),
            p(-15.5, -29.5),
            p(-16.5, -29.5),
            p(-16.5, -30.5),
        ]
        .windows(2)
        .map(|w| LandedCut {
            from: Point3::new(w[0].x, w[0].y, 1.0),
            to: Point3::new(w[1].x, w[1].y, 1.0),
        })
        .collect();
        let marked: Vec<LandedCut> = corner.iter().chain(&corner).copied().collect();
        clear(&mut films, &marked);
        assert!((films[0].removed_at(-15.5, -30.5) - 0.08).abs() < 1e-9);
        assert!((films[0].removed_at(-16.0, -30.5) - 0.08).abs() < 1e-9);
    }
}
