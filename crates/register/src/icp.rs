//! Iterative closest point: point-to-point (Besl & McKay 1992, with the Umeyama step) and
//! point-to-plane (Chen & Medioni 1992, Gauss-Newton on the linearised residual), rigid or with
//! scale, with a maximum correspondence distance, a robust kernel, trimming, a voxel pyramid and
//! convergence on the transform change.
//!
//! Deterministic: correspondences are found in parallel into a vector in source order, and every
//! sum is a [`crate::reduce::chunked_sum`]; the same input gives the same result to the bit on
//! any number of threads.

use rayon::prelude::*;
use trim_geom::voxel::voxel_downsample;
use trim_geom::{Point3, PointCloud, Similarity3, Vector3};

use crate::error::{RegisterError, Result};
use crate::kdtree::{KdTree, Scratch};
use crate::kernel::RobustKernel;
use crate::point_to_plane::{
    NormalEquations, Pair, point_to_plane_equations, point_to_point_equations, solve_increment,
    weighted_centre,
};
use crate::umeyama::umeyama_weighted;

/// The error metric.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IcpMethod {
    /// Minimise `|T·x − q|²` (Umeyama step).
    PointToPoint,
    /// Minimise `((T·x − q)·n_q)²` (Gauss-Newton step; the target needs normals).
    PointToPlane,
}

/// ICP settings. Lengths in millimetres (or the clouds' unit), angles in radians.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IcpSettings {
    /// The error metric.
    pub method: IcpMethod,
    /// Estimate a uniform scale as well.
    pub with_scale: bool,
    /// Pairs farther apart than this are not correspondences.
    pub max_correspondence_distance_mm: f64,
    /// Iteration cap.
    pub max_iterations: usize,
    /// Converged when an iteration moves the transform's translation less than this…
    pub translation_epsilon_mm: f64,
    /// …its rotation less than this…
    pub rotation_epsilon_rad: f64,
    /// …and its scale by a relative amount less than this.
    pub scale_epsilon: f64,
    /// The robust kernel on the residual.
    pub kernel: RobustKernel,
    /// Drop this fraction of the farthest correspondences each iteration (0: none).
    pub trim_fraction: f64,
    /// Fewest correspondences to take a step.
    pub min_correspondences: usize,
}

impl Default for IcpSettings {
    fn default() -> Self {
        IcpSettings {
            method: IcpMethod::PointToPlane,
            with_scale: false,
            max_correspondence_distance_mm: 1.0,
            max_iterations: 50,
            translation_epsilon_mm: 1e-6,
            rotation_epsilon_rad: 1e-8,
            scale_epsilon: 1e-9,
            kernel: RobustKernel::None,
            trim_fraction: 0.0,
            min_correspondences: 6,
        }
    }
}

impl IcpSettings {
    /// Refuses out-of-range settings, naming the key.
    pub fn validate(&self) -> Result<()> {
        let bad = |name: &str, msg: &str| Err(RegisterError::setting(name, msg));
        if !(self.max_correspondence_distance_mm.is_finite()
            && self.max_correspondence_distance_mm > 0.0)
        {
            return bad("max_correspondence_distance_mm", "must be finite and > 0");
        }
        if self.max_iterations == 0 {
            return bad("max_iterations", "must be at least 1");
        }
        for (name, v) in [
            ("translation_epsilon_mm", self.translation_epsilon_mm),
            ("rotation_epsilon_rad", self.rotation_epsilon_rad),
            ("scale_epsilon", self.scale_epsilon),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(name, "must be finite and ≥ 0");
            }
        }
        if !self.kernel.is_valid() {
            return bad("kernel", "threshold must be finite and > 0");
        }
        if !(0.0..0.95).contains(&self.trim_fraction) {
            return bad("trim_fraction", "must be in [0, 0.95)");
        }
        if self.min_correspondences < 3 {
            return bad("min_correspondences", "must be at least 3");
        }
        Ok(())
    }
}

/// The result of ICP.
#[derive(Debug, Clone, PartialEq)]
pub struct IcpResult {
    /// The transform taking source points onto the target.
    pub target_from_source: Similarity3,
    /// Its scale (1 for a rigid fit).
    pub scale: f64,
    /// Root-mean-square residual over the final correspondences (distance for point-to-point,
    /// plane distance for point-to-plane) at the final transform, mm. When converged, the final
    /// correspondences are the last iteration's (its step was below the epsilons); otherwise
    /// they are searched at the final transform.
    pub rmse_mm: f64,
    /// Mean squared point distance of the final correspondences, mm² (PCL's fitness score).
    pub mean_squared_distance_mm2: f64,
    /// Fraction of source points with a correspondence (Open3D's fitness).
    pub fitness: f64,
    /// Number of final correspondences.
    pub correspondences: usize,
    /// Iterations run (summed over pyramid levels).
    pub iterations: usize,
    /// Whether the last level met the convergence test before the iteration cap.
    pub converged: bool,
    /// Eigenvalues (ascending) of the final normal matrix per unit weight: 6 rigid, 7 with
    /// scale. A small one marks a direction the data does not fix.
    pub eigenvalues: Vec<f64>,
}

/// A target cloud with its kd-tree, built once and reused across calls.
#[derive(Debug)]
pub struct IcpTarget {
    cloud: PointCloud,
    tree: KdTree,
}

impl IcpTarget {
    /// Builds the kd-tree. Refuses an empty cloud.
    pub fn new(cloud: PointCloud) -> Result<Self> {
        if cloud.is_empty() {
            return Err(RegisterError::EmptyCloud { which: "target" });
        }
        let tree = KdTree::build(cloud.points());
        Ok(IcpTarget { cloud, tree })
    }

    /// The cloud.
    #[must_use]
    pub fn cloud(&self) -> &PointCloud {
        &self.cloud
    }

    /// The kd-tree over the cloud's points.
    #[must_use]
    pub fn tree(&self) -> &KdTree {
        &self.tree
    }
}

/// Source points per parallel task of the correspondence search: small enough to balance two
/// to a few dozen threads on the ~10⁴-point clouds of a pyramid level, large enough that the
/// task overhead stays below a percent.
const QUERY_CHUNK: usize = 256;

/// For each source point (already in the target frame), its nearest target point within
/// `max_distance_mm`: `(target index, squared distance)`, in source order (parallel).
#[must_use]
pub fn nearest_correspondences(
    source_in_target: &[Point3],
    tree: &KdTree,
    max_distance_mm: f64,
) -> Vec<Option<(usize, f64)>> {
    let max_sq = max_distance_mm * max_distance_mm;
    let mut found = vec![None; source_in_target.len()];
    found
        .par_chunks_mut(QUERY_CHUNK)
        .zip(source_in_target.par_chunks(QUERY_CHUNK))
        .for_each(|(out, pts)| {
            let mut scratch = Scratch::default();
            for (o, p) in out.iter_mut().zip(pts) {
                *o = tree
                    .nearest_from(p, max_sq, None, &mut scratch)
                    .map(|n| (n.index, n.distance_sq));
            }
        });
    found
}

/// The per-iteration buffers of [`icp`]: the moved source points and their correspondences,
/// reused across iterations. The previous iteration's correspondences warm-start the next search
/// (the answer does not depend on them, see [`KdTree::nearest_from`]).
#[derive(Debug, Default)]
struct Correspondences {
    moved: Vec<Point3>,
    found: Vec<Option<(usize, f64)>>,
    warm: bool,
}

impl Correspondences {
    /// Moves the source by `target_from_source` and finds each point's nearest target point
    /// within `max_distance_mm`, in source order (parallel over fixed chunks).
    fn update(
        &mut self,
        source: &[Point3],
        target: &IcpTarget,
        target_from_source: &Similarity3,
        max_distance_mm: f64,
    ) {
        let max_sq = max_distance_mm * max_distance_mm;
        let n = source.len();
        if !self.warm || self.found.len() != n {
            self.found.clear();
            self.found.resize(n, None);
            self.warm = false;
        }
        self.moved.resize(n, Point3::origin());
        let tpts = target.cloud.points();
        let tree = &target.tree;
        let warm = self.warm;
        self.moved
            .par_chunks_mut(QUERY_CHUNK)
            .zip(self.found.par_chunks_mut(QUERY_CHUNK))
            .zip(source.par_chunks(QUERY_CHUNK))
            .for_each(|((moved, found), pts)| {
                let mut scratch = Scratch::default();
                for ((m, f), p) in moved.iter_mut().zip(found.iter_mut()).zip(pts) {
                    *m = target_from_source * p;
                    let hint = if warm {
                        f.map(|(j, _)| (j, &tpts[j]))
                    } else {
                        None
                    };
                    *f = tree
                        .nearest_from(m, max_sq, hint, &mut scratch)
                        .map(|nb| (nb.index, nb.distance_sq));
                }
            });
        self.warm = true;
    }
}

/// One ICP iteration's outcome.
#[derive(Debug, Clone)]
pub struct IcpStep {
    /// The updated transform.
    pub target_from_source: Similarity3,
    /// The increment applied this iteration (target frame).
    pub increment: Similarity3,
    /// The normal equations at the pre-step estimate.
    pub equations: NormalEquations,
    /// The weighted centroid of the correspondences' source points (target frame), about which
    /// the increment was solved.
    pub centre: Point3,
    /// Correspondences used.
    pub correspondences: usize,
    /// Mean squared point distance of the correspondences, mm².
    pub mean_squared_distance_mm2: f64,
}

/// One ICP iteration from `target_from_source`: correspondences, weights, trimming, step.
pub fn icp_step(
    source: &PointCloud,
    target: &IcpTarget,
    target_from_source: &Similarity3,
    settings: &IcpSettings,
    stage: &str,
) -> Result<IcpStep> {
    step_with(
        source,
        target,
        target_from_source,
        settings,
        stage,
        &mut Correspondences::default(),
    )
}

fn step_with(
    source: &PointCloud,
    target: &IcpTarget,
    target_from_source: &Similarity3,
    settings: &IcpSettings,
    stage: &str,
    buffers: &mut Correspondences,
) -> Result<IcpStep> {
    buffers.update(
        source.points(),
        target,
        target_from_source,
        settings.max_correspondence_distance_mm,
    );
    let (moved, found) = (&buffers.moved, &buffers.found);
    let mut matched: Vec<(usize, usize, f64)> = found
        .iter()
        .enumerate()
        .filter_map(|(i, m)| m.map(|(j, d2)| (i, j, d2)))
        .collect();
    if settings.trim_fraction > 0.0 && !matched.is_empty() {
        let keep = ((1.0 - settings.trim_fraction) * matched.len() as f64).ceil() as usize;
        let mut d2: Vec<f64> = matched.iter().map(|m| m.2).collect();
        let k = keep.clamp(1, d2.len()) - 1;
        let (_, &mut cut, _) = d2.select_nth_unstable_by(k, f64::total_cmp);
        matched.retain(|m| m.2 <= cut);
    }
    if matched.len() < settings.min_correspondences {
        return Err(RegisterError::TooFewCorrespondences {
            stage: stage.to_string(),
            needed: settings.min_correspondences,
            got: matched.len(),
            max_distance_mm: settings.max_correspondence_distance_mm,
        });
    }
    let normals = target.cloud.normals();
    let plane = settings.method == IcpMethod::PointToPlane;
    let normals = match (plane, normals) {
        (true, None) => {
            return Err(RegisterError::MissingNormals {
                which: "target",
                method: "point-to-plane ICP",
            });
        }
        (_, n) => n,
    };
    let tpts = target.cloud.points();
    let pairs: Vec<Pair> = matched
        .par_iter()
        .map(|&(i, j, d2)| {
            let n = if plane {
                normals.map_or(Vector3::zeros(), |ns| ns[j])
            } else {
                Vector3::zeros()
            };
            let r = if plane {
                (moved[i] - tpts[j]).dot(&n)
            } else {
                d2.sqrt()
            };
            Pair {
                x: moved[i],
                q: tpts[j],
                n,
                w: settings.kernel.weight(r),
            }
        })
        .collect();
    let mean_sq = matched.iter().map(|m| m.2).sum::<f64>() / matched.len() as f64;
    let centre = weighted_centre(&pairs);
    let equations = if plane {
        point_to_plane_equations(&pairs, &centre)
    } else {
        point_to_point_equations(&pairs, &centre)
    };
    let increment = if plane {
        solve_increment(&equations, &centre, settings.with_scale, stage)?
    } else {
        let xs: Vec<Point3> = pairs.iter().map(|p| p.x).collect();
        let qs: Vec<Point3> = pairs.iter().map(|p| p.q).collect();
        let ws: Vec<f64> = pairs.iter().map(|p| p.w).collect();
        umeyama_weighted(&xs, &qs, Some(&ws), settings.with_scale)?.target_from_source
    };
    Ok(IcpStep {
        target_from_source: increment * target_from_source,
        increment,
        equations,
        centre,
        correspondences: matched.len(),
        mean_squared_distance_mm2: mean_sq,
    })
}

/// Runs ICP from `initial` (`target_from_source`) until the increment is below the epsilons
/// or `max_iterations`.
pub fn icp(
    source: &PointCloud,
    target: &IcpTarget,
    initial: &Similarity3,
    settings: &IcpSettings,
) -> Result<IcpResult> {
    settings.validate()?;
    if source.is_empty() {
        return Err(RegisterError::EmptyCloud { which: "source" });
    }
    if !initial.to_homogeneous().iter().all(|v| v.is_finite()) || initial.scaling() <= 0.0 {
        return Err(RegisterError::NonFinite {
            what: "initial transform".into(),
        });
    }
    let mut current = *initial;
    let mut last: Option<IcpStep> = None;
    let mut converged = false;
    let mut iterations = 0;
    let mut buffers = Correspondences::default();
    for it in 0..settings.max_iterations {
        trim_geom::cancel::check()?;
        let step = step_with(
            source,
            target,
            &current,
            settings,
            &format!("icp iteration {it}"),
            &mut buffers,
        )?;
        iterations = it + 1;
        current = step.target_from_source;
        let inc = &step.increment;
        // The increment's size: rotation angle, motion of the correspondences' centroid, and
        // relative scale change.
        let c = step.centre;
        let small = inc.isometry.rotation.angle() < settings.rotation_epsilon_rad
            && (inc * c - c).norm() < settings.translation_epsilon_mm
            && (inc.scaling() - 1.0).abs() < settings.scale_epsilon;
        last = Some(step);
        if small {
            converged = true;
            break;
        }
    }
    let Some(step) = last else {
        return Err(RegisterError::setting(
            "max_iterations",
            "must be at least 1",
        ));
    };
    Ok(finish(
        source,
        target,
        current,
        settings,
        (step, iterations, converged),
        &mut buffers,
    ))
}

fn finish(
    source: &PointCloud,
    target: &IcpTarget,
    current: Similarity3,
    settings: &IcpSettings,
    (step, iterations, converged): (IcpStep, usize, bool),
    buffers: &mut Correspondences,
) -> IcpResult {
    // Final statistics at the final estimate. Converged, the last step moved every point by
    // less than the epsilons: its correspondences stand, re-evaluated at the final estimate
    // (pairs pushed beyond the maximum distance dropped), and a whole further search, a seventh
    // of a typical run, is saved. Otherwise the correspondences are searched again.
    let max_sq = settings.max_correspondence_distance_mm.powi(2);
    let reuse = converged;
    if !reuse {
        buffers.update(
            source.points(),
            target,
            &current,
            settings.max_correspondence_distance_mm,
        );
    }
    let (moved, found) = (&buffers.moved, &buffers.found);
    let normals = target.cloud.normals();
    let tpts = target.cloud.points();
    let plane = settings.method == IcpMethod::PointToPlane;
    let (count, sum_d2, sum_r2) =
        found
            .iter()
            .enumerate()
            .fold((0usize, 0.0, 0.0), |(c, d, r), (i, m)| match m {
                Some((j, d2)) => {
                    let (x, d2) = if reuse {
                        let x = step.increment * moved[i];
                        (x, (x - tpts[*j]).norm_squared())
                    } else {
                        (moved[i], *d2)
                    };
                    if d2 > max_sq {
                        return (c, d, r);
                    }
                    let res2 = if plane {
                        normals.map_or(d2, |ns| (x - tpts[*j]).dot(&ns[*j]).powi(2))
                    } else {
                        d2
                    };
                    (c + 1, d + d2, r + res2)
                }
                None => (c, d, r),
            });
    let denom = count.max(1) as f64;
    IcpResult {
        target_from_source: current,
        scale: current.scaling(),
        rmse_mm: (sum_r2 / denom).sqrt(),
        mean_squared_distance_mm2: sum_d2 / denom,
        fitness: count as f64 / source.len() as f64,
        correspondences: count,
        iterations,
        converged,
        eigenvalues: step.equations.eigenvalues(settings.with_scale),
    }
}

/// One level of a coarse-to-fine pyramid.
#[derive(
    Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema,
)]
#[serde(deny_unknown_fields)]
pub struct PyramidLevel {
    /// Voxel size for down-sampling both clouds, mm (0: full resolution).
    pub voxel_mm: f64,
    /// Maximum correspondence distance at this level, mm.
    pub max_correspondence_distance_mm: f64,
    /// Iteration cap at this level.
    pub max_iterations: usize,
}

/// ICP over a voxel pyramid, coarse to fine: each level down-samples both clouds (normals are
/// averaged per voxel) and starts from the previous level's result. `settings` gives everything
/// but the per-level distance and iteration cap.
pub fn icp_pyramid(
    source: &PointCloud,
    target: &PointCloud,
    initial: &Similarity3,
    levels: &[PyramidLevel],
    settings: &IcpSettings,
) -> Result<IcpResult> {
    if levels.is_empty() {
        return Err(RegisterError::setting(
            "levels",
            "needs at least one pyramid level",
        ));
    }
    if source.is_empty() {
        return Err(RegisterError::EmptyCloud { which: "source" });
    }
    if target.is_empty() {
        return Err(RegisterError::EmptyCloud { which: "target" });
    }
    let mut current = *initial;
    let mut total_iterations = 0;
    let mut result = None;
    for (k, level) in levels.iter().enumerate() {
        if !(level.voxel_mm.is_finite() && level.voxel_mm >= 0.0) {
            return Err(RegisterError::setting(
                format!("levels[{k}].voxel_mm"),
                "must be finite and ≥ 0",
            ));
        }
        let (src, tgt) = if level.voxel_mm > 0.0 {
            (
                voxel_downsample(source, level.voxel_mm)?,
                voxel_downsample(target, level.voxel_mm)?,
            )
        } else {
            (source.clone(), target.clone())
        };
        let tgt = IcpTarget::new(tgt)?;
        let s = IcpSettings {
            max_correspondence_distance_mm: level.max_correspondence_distance_mm,
            max_iterations: level.max_iterations,
            ..*settings
        };
        let r = icp(&src, &tgt, &current, &s).map_err(|e| match e {
            RegisterError::TooFewCorrespondences {
                stage,
                needed,
                got,
                max_distance_mm,
            } => RegisterError::TooFewCorrespondences {
                stage: format!("pyramid level {k} ({} mm voxels), {stage}", level.voxel_mm),
                needed,
                got,
                max_distance_mm,
            },
            other => other,
        })?;
        current = r.target_from_source;
        total_iterations += r.iterations;
        result = Some(r);
    }
    let mut r = result.ok_or_else(|| RegisterError::setting("levels", "empty"))?;
    r.iterations = total_iterations;
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    /// A wavy patch `z = 2 sin(x/7) cos(y/5)` over 100 × 100 mm with normals.
    fn surface(n: usize, seed: u64) -> PointCloud {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let (mut points, mut normals) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for _ in 0..n {
            let (x, y): (f64, f64) = (rng.random_range(-50.0..50.0), rng.random_range(-50.0..50.0));
            let dzdx = 2.0 / 7.0 * (x / 7.0).cos() * (y / 5.0).cos();
            let dzdy = -2.0 / 5.0 * (x / 7.0).sin() * (y / 5.0).sin();
            points.push(Point3::new(x, y, 2.0 * (x / 7.0).sin() * (y / 5.0).cos()));
            normals.push(Vector3::new(-dzdx, -dzdy, 1.0).normalize());
        }
        PointCloud::with_normals(points, normals).unwrap()
    }

    #[test]
    fn warm_started_icp_is_exact_and_the_same_on_one_and_many_threads() {
        let target = IcpTarget::new(surface(20_000, 1)).unwrap();
        let truth = Similarity3::new(
            Vector3::new(0.3, -0.2, 0.1),
            Vector3::new(0.01, -0.005, 0.02),
            1.0,
        );
        let source = surface(8_000, 2).transformed(&truth.inverse()).unwrap();
        let settings = IcpSettings {
            max_correspondence_distance_mm: 2.0,
            ..IcpSettings::default()
        };
        let run = || icp(&source, &target, &Similarity3::identity(), &settings).unwrap();
        let many = run();
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(run);
        assert_eq!(many, one);
        assert!(many.converged);
        let err = many.target_from_source.to_homogeneous() - truth.to_homogeneous();
        assert!(err.norm() < 0.05, "{err}");
        // The warm-started searches answer as cold ones do: the final correspondences (kept
        // from the converged last iteration) all lie within the distance, and a cold search at
        // the result finds the same count within a few boundary pairs.
        let moved: Vec<Point3> = source
            .points()
            .iter()
            .map(|p| many.target_from_source * p)
            .collect();
        let cold = nearest_correspondences(&moved, target.tree(), 2.0);
        let cold_count = cold.iter().flatten().count();
        assert!(
            cold_count.abs_diff(many.correspondences) <= 8,
            "{cold_count} vs {many:?}"
        );
    }
}
