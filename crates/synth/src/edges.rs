//! The true part's trimming edges and what a trim leaves of its burrs: the twin's view of the
//! case (DESIGN.md "Ablation and the twin's part").
//!
//! [`SynthCase::edge_truth`] gives, along every contour of the true path (scan frame), the
//! direction out of the material and the burr web standing there. After a trim, the web left at
//! each contour point becomes a set of short burrs ([`stubs`]), and [`SynthCase::rescan`] scans
//! the part carrying them: the after-scan.

use rand::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use trim_geom::{Point3, PointCloud, Result, Vector3};

use crate::blockage::{Blockage, BlockageSampler, Film};
use crate::burr::{Burr, BurrSampler};
use crate::case::SynthCase;
use crate::mesh::domain_mesh;
use crate::part::{
    SurfaceSampler, THICKNESS_MM, contour_edges, contour_segments, cutouts, design_point,
};
use crate::scanner::scan_part;

/// A domain step (mm) for the outward direction's finite difference.
const OUTWARD_STEP_MM: f64 = 1e-3;

/// One contour's edge on the true part.
#[derive(Debug, Clone, PartialEq)]
pub struct EdgeTruth {
    /// The contour id (as in the template and true paths).
    pub contour: i64,
    /// At each point of the true contour, the unit direction out of the material, in the top
    /// face, across the edge (scan frame).
    pub outward: Vec<Vector3>,
    /// At each point, the burr web's reach off the edge (mm; 0: clean).
    pub burr_height_mm: Vec<f64>,
    /// At each point, the web's thickness (mm; 0: clean).
    pub burr_thickness_mm: Vec<f64>,
}

impl SynthCase {
    /// The true part's edges, one per contour of [`SynthCase::truth`] and in its order.
    #[must_use]
    pub fn edge_truth(&self) -> Vec<EdgeTruth> {
        self.edge_truth_with(&self.burrs)
    }

    /// The true part's edges carrying `burrs` (what a trim left, [`stubs`]) instead of the
    /// case's.
    #[must_use]
    pub fn edge_truth_with(&self, burrs: &[Burr]) -> Vec<EdgeTruth> {
        let top = THICKNESS_MM / 2.0;
        let map = |u: f64, v: f64| self.scan_from_cad_point(&design_point(u, v, top));
        (1..)
            .zip(contour_edges(&cutouts()))
            .map(|(id, edge)| {
                let n = contour_segments(&edge, self.params.path_spacing_mm);
                let outward = (0..=n)
                    .map(|k| {
                        let (p, m) = edge.at_step(k, n);
                        let d = map(p[0] + OUTWARD_STEP_MM * m[0], p[1] + OUTWARD_STEP_MM * m[1])
                            - map(p[0], p[1]);
                        d.normalize()
                    })
                    .collect();
                let (mut height, mut thickness) = (vec![0.0; n + 1], vec![0.0; n + 1]);
                for b in burrs.iter().filter(|b| b.contour == id) {
                    for k in b.first_point..=b.last_point.min(n) {
                        height[k] = f64::max(height[k], b.height_mm);
                        thickness[k] = f64::max(thickness[k], b.thickness_mm);
                    }
                }
                EdgeTruth {
                    contour: id,
                    outward,
                    burr_height_mm: height,
                    burr_thickness_mm: thickness,
                }
            })
            .collect()
    }

    /// The true scan-frame point of the top face (the parting plane, which a film is flush with)
    /// over the domain point `(u, v)`, mm: where a film's upper side stands over an opening.
    #[must_use]
    pub fn top_face_point(&self, u: f64, v: f64) -> Point3 {
        self.scan_from_cad_point(&design_point(u, v, THICKNESS_MM / 2.0))
    }

    /// A fresh scan (noise, outliers and dropouts drawn from `seed`) of the same part, at the
    /// same pose and under the same views, carrying `burrs` and `blockages` (untouched films)
    /// instead of the case's.
    pub fn rescan(&self, burrs: &[Burr], blockages: &[Blockage], seed: u64) -> Result<PointCloud> {
        self.rescan_films(burrs, &Film::of(blockages), seed)
    }

    /// [`SynthCase::rescan`] with the films as they stand (what hatching left of them). Its
    /// dropout patches lie where `seed` alone puts them, whatever the burrs and films.
    pub fn rescan_films(&self, burrs: &[Burr], films: &[Film], seed: u64) -> Result<PointCloud> {
        let cutouts = cutouts();
        let edges = contour_edges(&cutouts);
        let mesh = domain_mesh(&cutouts, self.params.mesh_step_mm)?;
        let sampler = SurfaceSampler::new(cutouts.clone());
        let scan_from_domain = |d: &Point3| self.scan_from_cad_point(&design_point(d.x, d.y, d.z));
        scan_part(
            &self.params,
            &mut Xoshiro256PlusPlus::seed_from_u64(seed),
            Some(seed ^ RESCAN_DROPOUT_STREAM),
            &sampler,
            (
                &BurrSampler::new(&edges, burrs),
                &BlockageSampler::new(films),
            ),
            &mesh,
            &scan_from_domain,
            &self.views,
        )
    }
}

/// Mixed into a rescan's seed for its dropout centres' own stream.
const RESCAN_DROPOUT_STREAM: u64 = 0x6472_6f70_6f75_7473;

/// What stands of `burrs` after a trim that left `residual_mm(contour, point)` of web at each
/// contour point: one short burr per stretch between neighbouring points where either end keeps
/// some web, as tall as the taller end, as thick as the burr was.
#[must_use]
pub fn stubs(
    burrs: &[Burr],
    spacing_mm: f64,
    residual_mm: impl Fn(i64, usize) -> f64,
) -> Vec<Burr> {
    let edges = contour_edges(&cutouts());
    let mut out = Vec::new();
    for b in burrs {
        let Some(edge) = usize::try_from(b.contour - 1)
            .ok()
            .and_then(|i| edges.get(i))
        else {
            continue;
        };
        let n = contour_segments(edge, spacing_mm);
        let arc = |k: usize| edge.length() * k as f64 / n as f64;
        for k in b.first_point..b.last_point.min(n) {
            let h =
                f64::max(residual_mm(b.contour, k), residual_mm(b.contour, k + 1)).min(b.height_mm);
            if h > 0.0 {
                out.push(Burr {
                    start_mm: arc(k),
                    end_mm: arc(k + 1),
                    first_point: k,
                    last_point: k + 1,
                    height_mm: h,
                    ..*b
                });
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::case::{SynthParams, generate};

    fn case() -> SynthCase {
        generate(&SynthParams {
            seed: 3,
            scan_points: 20_000,
            cad_points: 5_000,
            burr_fraction: 0.3,
            ..SynthParams::default()
        })
        .unwrap()
    }

    #[test]
    fn the_outward_direction_leaves_the_material_across_the_edge() {
        let c = case();
        let truth = c.edge_truth();
        assert_eq!(truth.len(), c.truth.contours().len());
        for (e, contour) in truth.iter().zip(c.truth.contours()) {
            assert_eq!(e.contour, contour.id());
            let pts = contour.points();
            assert_eq!(e.outward.len(), pts.len());
            // A rim's points surround its opening: out of the material is toward its middle.
            let middle = pts.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / pts.len() as f64;
            for (i, m) in e.outward.iter().enumerate() {
                assert!((m.norm() - 1.0).abs() < 1e-9);
                // Across the edge: perpendicular to the contour's tangent (a chord's direction,
                // off by up to spacing/(4·radius) where a slot's arc meets its side) and to
                // the face normal.
                let last = pts.len() - 1;
                let closed = (pts[0] - pts[last]).norm() < 1e-9;
                let (prev, next) = match i {
                    0 if closed => (last - 1, 1),
                    _ if i == last && closed => (last - 1, 1),
                    _ => (i.saturating_sub(1), (i + 1).min(last)),
                };
                let t = (pts[next] - pts[prev]).normalize();
                if closed {
                    assert!(
                        m.dot(&(middle - pts[i].coords)) > 0.0,
                        "contour {} point {i}",
                        e.contour
                    );
                }
                assert!(
                    m.dot(&t).abs() < 0.1,
                    "contour {} point {i}: {}",
                    e.contour,
                    m.dot(&t)
                );
                assert!(m.dot(&contour.features()[i].normalize()).abs() < 0.02);
            }
        }
        // Every burr's stretch carries its web, and only burred contours carry any.
        let burred: std::collections::HashSet<i64> = c.burrs.iter().map(|b| b.contour).collect();
        for e in &truth {
            let any = e.burr_height_mm.iter().any(|&h| h > 0.0);
            assert_eq!(any, burred.contains(&e.contour), "contour {}", e.contour);
        }
    }

    #[test]
    fn a_trim_that_leaves_nothing_leaves_no_burr_and_a_rescan_sees_the_stubs() {
        let c = case();
        assert!(stubs(&c.burrs, c.params.path_spacing_mm, |_, _| 0.0).is_empty());
        let half = stubs(&c.burrs, c.params.path_spacing_mm, |_, _| 0.05);
        assert!(!half.is_empty());
        assert!(
            half.iter()
                .all(|b| (b.height_mm - 0.05).abs() < 1e-12 || b.height_mm < 0.05)
        );
        let clean = c.rescan(&[], &[], 9).unwrap();
        let stubbed = c.rescan(&half, &[], 9).unwrap();
        // The scan's size, less what the dropout patches take.
        for scan in [&clean, &stubbed] {
            assert!(scan.len() > c.params.scan_points * 9 / 10, "{}", scan.len());
        }
        // The stubs are scanned: the two scans differ where they stand.
        assert_ne!(clean.points(), stubbed.points());
    }
}
