//! The twin's true part through a run (DESIGN.md "Ablation and the twin's part"): a synthetic
//! core with its burrs, placed in the work-piece frame, trimmed by the landed cuts of each round
//! and rescanned.
//!
//! The part is a [`SynthCase`] (its own frame: the synthetic scene) carried into the true
//! work-piece frame by `workpiece_from_case`. After a round's cuts ([`TwinPart::trim`]) the burr
//! webs that stand are the stubs the ablation left, the gouges add up over the rounds, the films
//! over blocked openings are thinner or cleared where the cuts swept them
//! ([`crate::film_ablation`]), and [`TwinPart::rescan`] scans the part as it now is.

use std::collections::BTreeMap;

use trim_cell::ProcessSettings;
use trim_geom::{GeomError, PointCloud, Similarity3};
use trim_synth::{Burr, Film, SynthCase, stubs};

use crate::ablation::{LandedCut, TrueEdge, ablate};
use crate::film_ablation::clear_films;

/// One contour's state after the rounds so far, µm.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ContourTrim {
    /// The contour id.
    pub id: i64,
    /// The tallest burr web still standing off the edge.
    pub residual_um: f64,
    /// How far the cuts have cut the edge back into the material, at most.
    pub gouge_um: f64,
    /// For a contour rimming a blocked opening: the share of the opening its film still covers
    /// (0: cleared); none where no film was.
    pub film_covered_share: Option<f64>,
}

/// The true part as the twin carries it.
#[derive(Debug, Clone)]
pub struct TwinPart {
    case: SynthCase,
    workpiece_from_case: Similarity3,
    burrs: Vec<Burr>,
    /// The films over blocked openings as they stand.
    films: Vec<Film>,
    /// Per contour, per point: the deepest cut back into the material so far, mm.
    gouge_mm: BTreeMap<i64, Vec<f64>>,
}

impl TwinPart {
    /// The part of `case`, placed in the work-piece frame by `workpiece_from_case`, before any
    /// cut.
    #[must_use]
    pub fn new(case: SynthCase, workpiece_from_case: Similarity3) -> TwinPart {
        let burrs = case.burrs.clone();
        let films = Film::of(&case.blockages);
        TwinPart {
            case,
            workpiece_from_case,
            burrs,
            films,
            gouge_mm: BTreeMap::new(),
        }
    }

    /// The films over blocked openings as they stand.
    #[must_use]
    pub fn films(&self) -> &[Film] {
        &self.films
    }

    /// The burrs standing now (domain measures, as [`SynthCase::burrs`]).
    #[must_use]
    pub fn burrs(&self) -> &[Burr] {
        &self.burrs
    }

    /// The trimming edges as they stand now, work-piece frame.
    pub fn edges(&self) -> Result<Vec<TrueEdge>, GeomError> {
        let truth = self.case.truth.transformed(&self.workpiece_from_case)?;
        let rotation = self.workpiece_from_case.isometry.rotation;
        Ok(self
            .case
            .edge_truth_with(&self.burrs)
            .into_iter()
            .zip(truth.contours())
            .map(|(e, c)| TrueEdge {
                contour: e.contour,
                points: c.points().to_vec(),
                outward: e.outward.iter().map(|m| rotation * m).collect(),
                burr_height_mm: e.burr_height_mm,
                burr_thickness_mm: e.burr_thickness_mm,
            })
            .collect())
    }

    /// Applies a round's landed cuts: the webs they sever fall away, the stubs stay, the gouges
    /// add to those of earlier rounds, the films lose what the cuts' kerfs swept. Returns every
    /// contour's state after it.
    pub fn trim(
        &mut self,
        cuts: &[LandedCut],
        process: &ProcessSettings,
        kerf_mm: f64,
    ) -> Result<Vec<ContourTrim>, GeomError> {
        let edges = self.edges()?;
        let outcome = ablate(&edges, cuts, process, kerf_mm);
        let residual: BTreeMap<i64, Vec<f64>> = outcome
            .edges
            .iter()
            .map(|(id, pts)| (*id, pts.iter().map(|o| o.residual_mm).collect()))
            .collect();
        self.burrs = stubs(&self.burrs, self.case.params.path_spacing_mm, |id, k| {
            residual
                .get(&id)
                .and_then(|r| r.get(k))
                .copied()
                .unwrap_or(0.0)
        });
        let workpiece_from_case = self.workpiece_from_case;
        let case = &self.case;
        clear_films(
            &mut self.films,
            &|_, u, v| workpiece_from_case * case.top_face_point(u, v),
            cuts,
            process,
            kerf_mm,
        );
        for (id, pts) in &outcome.edges {
            let g = self
                .gouge_mm
                .entry(*id)
                .or_insert_with(|| vec![0.0; pts.len()]);
            for (acc, o) in g.iter_mut().zip(pts) {
                *acc = acc.max(o.gouge_mm);
            }
        }
        Ok(self.state())
    }

    /// Every contour's state now.
    #[must_use]
    pub fn state(&self) -> Vec<ContourTrim> {
        let standing = self.case.edge_truth_with(&self.burrs);
        standing
            .iter()
            .map(|e| ContourTrim {
                id: e.contour,
                residual_um: 1e3 * e.burr_height_mm.iter().copied().fold(0.0, f64::max),
                gouge_um: 1e3
                    * self
                        .gouge_mm
                        .get(&e.contour)
                        .map_or(0.0, |g| g.iter().copied().fold(0.0, f64::max)),
                film_covered_share: self
                    .films
                    .iter()
                    .find(|f| f.contour() == e.contour)
                    .map(Film::covered_share),
            })
            .collect()
    }

    /// A fresh scan of the part as it stands (noise drawn from `seed`), work-piece frame.
    pub fn rescan(&self, seed: u64) -> Result<PointCloud, GeomError> {
        self.case
            .rescan_films(&self.burrs, &self.films, seed)?
            .transformed(&self.workpiece_from_case)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use trim_geom::{Point3, Vector3};
    use trim_synth::{SynthParams, generate};

    fn part() -> TwinPart {
        let case = generate(&SynthParams {
            seed: 5,
            scan_points: 20_000,
            cad_points: 2_000,
            burr_fraction: 0.3,
            ..SynthParams::default()
        })
        .unwrap();
        let placed = Similarity3::from_parts(
            nalgebra::Translation3::new(1.0, -2.0, 30.0),
            nalgebra::UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.3)),
            1.0,
        );
        TwinPart::new(case, placed)
    }

    /// Cuts along every edge at `offset_mm` out of the material, each edge point's stretch to
    /// the next, marked `passes` times.
    fn cuts_along(edges: &[TrueEdge], offset_mm: f64, passes: usize) -> Vec<LandedCut> {
        let mut out = Vec::new();
        for e in edges {
            let at = |i: usize| -> Point3 { e.points[i] + e.outward[i] * offset_mm };
            for _ in 0..passes {
                out.extend((1..e.points.len()).map(|i| LandedCut {
                    from: at(i - 1),
                    to: at(i),
                }));
            }
        }
        out
    }

    #[test]
    fn cuts_on_the_edges_through_every_web_leave_a_clean_part_and_the_rescan_shows_it() {
        let mut p = part();
        let before = p.state();
        assert!(before.iter().any(|c| c.residual_um > 50.0));
        let process = ProcessSettings::default();
        let edges = p.edges().unwrap();
        // The edges are placed: the points sit where the placed true path is.
        assert!((edges[0].points[0].z - 30.0).abs() < 5.0);
        let after = p.trim(&cuts_along(&edges, 0.0, 3), &process, 0.03).unwrap();
        assert!(p.burrs().is_empty(), "{:?}", p.burrs());
        for c in &after {
            assert!(c.residual_um == 0.0, "{c:?}");
            assert!((c.gouge_um - 15.0).abs() < 1.0, "{c:?}");
        }
        let scan = p.rescan(7).unwrap();
        assert!(scan.len() > 15_000);
    }

    #[test]
    fn a_line_beyond_the_edge_leaves_stubs_that_a_second_round_removes() {
        let mut p = part();
        let process = ProcessSettings::default();
        let edges = p.edges().unwrap();
        // 80 µm out, three passes: a stub of 65 µm where a web stood.
        let first = p
            .trim(&cuts_along(&edges, 0.08, 3), &process, 0.03)
            .unwrap();
        let burred: Vec<&ContourTrim> = first.iter().filter(|c| c.residual_um > 0.0).collect();
        assert!(!burred.is_empty());
        assert!(
            burred.iter().all(|c| (c.residual_um - 65.0).abs() < 1.0),
            "{burred:?}"
        );
        assert!(first.iter().all(|c| c.gouge_um == 0.0));
        // The retrim on the line takes the stubs off.
        let edges = p.edges().unwrap();
        let second = p.trim(&cuts_along(&edges, 0.0, 3), &process, 0.03).unwrap();
        assert!(second.iter().all(|c| c.residual_um == 0.0), "{second:?}");
    }
}
