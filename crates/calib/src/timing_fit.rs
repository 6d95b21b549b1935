//! The cycle-time model fitted from recorded runs (`trimctl calibrate timing`; DESIGN.md
//! "Estimates learned from runs").
//!
//! - *Moves* ([`fit_moves`]): the coordinated move of [`trim_cell::kinematics::coordinated_move_s`]
//!   (LinuxCNC's G0: the slowest axis limits the path speed and acceleration, trapezoidal
//!   profile) plus a settle time, over the recorded moves (from/to axis values, measured move
//!   command → in position). Parameters: linear and rotary speed and acceleration (log scale,
//!   so they stay positive) and the settle time; Levenberg–Marquardt with a central-difference
//!   Jacobian ([`crate::least_squares`]). A parameter no sample moves (no rotary motion, say) keeps its start value and is
//!   named in [`MoveFit::not_determined`]. Standard deviations: σ̂²(JᵀJ)⁻¹.
//! - *Lists* ([`fit_lists`]): `measured − commanded model = c + p·mark_runs + v·vertices`, linear
//!   least squares (the commanded delays are what the controller is sent and stay as they are;
//!   c, p and v are the `[timing]` list terms). A term the lists cannot tell apart from the others
//!   (collinear columns) is left at 0 and named. A term that fits negative (the controller
//!   quicker than commanded on that count) is held at 0, the others re-fitted without it, and
//!   named with the value it fitted ([`ListFit::held_at_zero`]): an overhead is time the cell
//!   adds, `[timing]` refuses a negative one, and a negative per-vertex term times a part's
//!   thousands of vertices drove estimates below zero. What the process engineer gets is a
//!   file `plan` and `run` take, whose estimate never falls below the commanded model.
//! - *Per-layer overhead*: the median of the measured overheads (0 when that is negative).

use nalgebra::{DMatrix, DVector};
use trim_cell::GalvoSettings;
use trim_cell::galvo_timing::{ListComposition, TimingSettings};
use trim_cell::kinematics::{AxisPose, MachineSettings, MoveModel, move_time_s};

use crate::CalibError;
use crate::least_squares;

/// Fewer recorded moves than this are refused.
pub const MIN_MOVES: usize = 6;
/// Fewer recorded lists than this are refused.
pub const MIN_LISTS: usize = 3;
/// Start factors of the speeds and of the accelerations (each pair of them is one start).
const START_FACTORS: [f64; 3] = [0.6, 1.0, 1.7];
/// A parameter whose Jacobian column is below this fraction of the largest is not determined.
const DETERMINED_FRACTION: f64 = 1e-6;
/// A list term is kept when the normalised design matrix's smallest singular value is above
/// this fraction of its largest.
const LIST_CONDITION: f64 = 1e-6;

/// The move-model parameters, in fit order.
pub const MOVE_PARAMETERS: [&str; 5] = [
    "linear_speed_mm_per_s",
    "rotary_speed_deg_per_s",
    "linear_accel_mm_per_s2",
    "rotary_accel_deg_per_s2",
    "settle_s",
];

/// One recorded move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MoveSample {
    /// Where the machine was (commanded axis values).
    pub from: AxisPose,
    /// Where it went.
    pub to: AxisPose,
    /// Measured: move command to in position (s).
    pub measured_s: f64,
}

/// The fitted move model.
#[derive(Debug, Clone, PartialEq)]
pub struct MoveFit {
    /// The start settings with the fitted speeds, accelerations, settle time and
    /// `move_model = "coordinated"`.
    pub machine: MachineSettings,
    /// Each parameter's standard deviation (units of [`MOVE_PARAMETERS`]; NaN when not
    /// determined).
    pub sigma: [f64; 5],
    /// Parameters the moves do not determine (kept at their start values).
    pub not_determined: Vec<&'static str>,
    /// Moves fitted.
    pub samples: usize,
    /// RMS of estimate − measured with the start settings (s).
    pub rms_before_s: f64,
    /// RMS of estimate − measured with the fit (s).
    pub rms_after_s: f64,
    /// Levenberg–Marquardt iterations of the best start ([`least_squares::Solution::iterations`]).
    pub iterations: usize,
}

fn with_parameters(start: &MachineSettings, x: &[f64]) -> MachineSettings {
    MachineSettings {
        move_model: MoveModel::Coordinated,
        linear_speed_mm_per_s: x[0].exp(),
        rotary_speed_deg_per_s: x[1].exp(),
        linear_accel_mm_per_s2: x[2].exp(),
        rotary_accel_deg_per_s2: x[3].exp(),
        settle_s: x[4],
        ..*start
    }
}

fn move_residuals(start: &MachineSettings, x: &[f64], samples: &[MoveSample]) -> DVector<f64> {
    let m = with_parameters(start, x);
    DVector::from_iterator(
        samples.len(),
        samples
            .iter()
            .map(|s| move_time_s(&m, &s.from, &s.to) - s.measured_s),
    )
}

fn rms(r: &DVector<f64>) -> f64 {
    if r.is_empty() {
        0.0
    } else {
        (r.norm_squared() / r.len() as f64).sqrt()
    }
}

/// Fits the coordinated move model and the settle time to recorded moves, starting from
/// `start` (the settings the runs were planned with). Moves that do not move are left out.
pub fn fit_moves(start: &MachineSettings, samples: &[MoveSample]) -> Result<MoveFit, CalibError> {
    for (key, v) in [
        ("linear_speed_mm_per_s", start.linear_speed_mm_per_s),
        ("rotary_speed_deg_per_s", start.rotary_speed_deg_per_s),
        ("linear_accel_mm_per_s2", start.linear_accel_mm_per_s2),
        ("rotary_accel_deg_per_s2", start.rotary_accel_deg_per_s2),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(CalibError::Invalid {
                key: format!("machine.{key}"),
                message: format!("the start value must be a finite number > 0, got {v}"),
            });
        }
    }
    let samples: Vec<MoveSample> = samples
        .iter()
        .copied()
        .filter(|s| s.measured_s.is_finite() && s.from != s.to)
        .collect();
    if samples.len() < MIN_MOVES {
        return Err(CalibError::TooFew {
            what: "recorded moves (with a known start pose)".into(),
            needed: MIN_MOVES,
            got: samples.len(),
        });
    }
    let rms_before_s = rms(&DVector::from_iterator(
        samples.len(),
        samples
            .iter()
            .map(|s| move_time_s(start, &s.from, &s.to) - s.measured_s),
    ));
    let x0 = [
        start.linear_speed_mm_per_s.ln(),
        start.rotary_speed_deg_per_s.ln(),
        start.linear_accel_mm_per_s2.ln(),
        start.rotary_accel_deg_per_s2.ln(),
        start.settle_s,
    ];
    let all: Vec<usize> = (0..5).collect();
    let residuals = |x: &[f64]| move_residuals(start, x, &samples);
    // Which parameters the moves determine, at the start (a parameter no move depends on,
    // anywhere near the start, has a zero column).
    let mut free = determined(&x0, &all, &residuals);
    // The slowest axis switches from move to move, so the cost has kinks: start from the
    // given settings and from scaled copies of them, keep the best. A parameter the fit then
    // drives where no move depends on it (an acceleration run off to 10¹⁵ because the moves
    // are as fast as the speeds alone allow: LinuxCNC's blending hides the ramps of short
    // moves) is not determined either: it is held at its start value and the rest re-fitted.
    let (x, r, cost, iterations) = loop {
        let mut best: Option<(Vec<f64>, DVector<f64>, f64, usize)> = None;
        for speed_factor in START_FACTORS {
            for accel_factor in START_FACTORS {
                // A held parameter stays at its start value: the fit is the one reported.
                let mut x = x0.to_vec();
                for (k, factor) in [speed_factor, speed_factor, accel_factor, accel_factor]
                    .into_iter()
                    .enumerate()
                {
                    if free.contains(&k) {
                        x[k] += factor.ln();
                    }
                }
                let found = levenberg_marquardt(x, &free, &residuals);
                if best.as_ref().is_none_or(|b| found.2 < b.2) {
                    best = Some(found);
                }
            }
        }
        let Some(found) = best else {
            unreachable!("START_FACTORS is not empty")
        };
        let kept = determined(&found.0, &free, &residuals);
        if kept.len() == free.len() || kept.is_empty() {
            break found;
        }
        free = kept;
    };
    let not_determined: Vec<&'static str> = (0..5)
        .filter(|k| !free.contains(k))
        .map(|k| MOVE_PARAMETERS[k])
        .collect();
    // What the moves do not determine stays exactly as it was.
    let mut machine = with_parameters(start, &x);
    for name in &not_determined {
        match *name {
            "linear_speed_mm_per_s" => machine.linear_speed_mm_per_s = start.linear_speed_mm_per_s,
            "rotary_speed_deg_per_s" => {
                machine.rotary_speed_deg_per_s = start.rotary_speed_deg_per_s;
            }
            "linear_accel_mm_per_s2" => {
                machine.linear_accel_mm_per_s2 = start.linear_accel_mm_per_s2;
            }
            "rotary_accel_deg_per_s2" => {
                machine.rotary_accel_deg_per_s2 = start.rotary_accel_deg_per_s2;
            }
            _ => machine.settle_s = start.settle_s,
        }
    }
    if let Err(e) = machine.validate() {
        return Err(CalibError::NotConverged {
            what: "the move fit".into(),
            detail: format!("it ended on invalid settings: {e}"),
        });
    }
    // Standard deviations from the normal matrix at the solution, in the parameters' units
    // (d value = value · d ln value for the log-scale ones).
    let mut sigma = [f64::NAN; 5];
    let dof = samples.len().saturating_sub(free.len()).max(1);
    let s2 = cost / dof as f64;
    let j = jacobian(&x, &free, &residuals);
    if let Some(inv) = (j.transpose() * &j).try_inverse() {
        for (i, &k) in free.iter().enumerate() {
            let sd = (s2 * inv[(i, i)]).max(0.0).sqrt();
            sigma[k] = if k < 4 { x[k].exp() * sd } else { sd };
        }
    }
    Ok(MoveFit {
        machine,
        sigma,
        not_determined,
        samples: samples.len(),
        rms_before_s,
        rms_after_s: rms(&r),
        iterations,
    })
}

/// The parameters of `free` that the residuals depend on at `x`: those whose Jacobian column
/// is over [`DETERMINED_FRACTION`] of the largest.
fn determined(x: &[f64], free: &[usize], residuals: &dyn Fn(&[f64]) -> DVector<f64>) -> Vec<usize> {
    let j = jacobian(x, free, residuals);
    let norms: Vec<f64> = (0..free.len()).map(|i| j.column(i).norm()).collect();
    let largest = norms.iter().copied().fold(0.0, f64::max);
    free.iter()
        .zip(&norms)
        .filter(|&(_, &n)| n > DETERMINED_FRACTION * largest)
        .map(|(&k, _)| k)
        .collect()
}

/// Levenberg–Marquardt ([`least_squares::minimize`]) over the parameters `free` of `x`, the
/// others held; returns the parameters, the residuals, the cost (Σr²) and the iterations.
fn levenberg_marquardt(
    x: Vec<f64>,
    free: &[usize],
    residuals: &dyn Fn(&[f64]) -> DVector<f64>,
) -> (Vec<f64>, DVector<f64>, f64, usize) {
    let on_free = |y: &DVector<f64>| residuals(&with_free(&x, free, y));
    let y0 = DVector::from_iterator(free.len(), free.iter().map(|&k| x[k]));
    let solution = least_squares::minimize(y0, &on_free);
    (
        with_free(&x, free, &solution.x),
        solution.residuals,
        solution.cost,
        solution.iterations,
    )
}

/// `x` with its parameters `free` set to `y`.
fn with_free(x: &[f64], free: &[usize], y: &DVector<f64>) -> Vec<f64> {
    let mut x = x.to_vec();
    for (i, &k) in free.iter().enumerate() {
        x[k] = y[i];
    }
    x
}

/// The Jacobian of `residuals` over the parameters `free` of `x`
/// ([`least_squares::jacobian`]).
fn jacobian(x: &[f64], free: &[usize], residuals: &dyn Fn(&[f64]) -> DVector<f64>) -> DMatrix<f64> {
    let on_free = |y: &DVector<f64>| residuals(&with_free(x, free, y));
    let y = DVector::from_iterator(free.len(), free.iter().map(|&k| x[k]));
    least_squares::jacobian(&y, &on_free)
}

/// One recorded galvo list.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ListSample {
    /// The galvo settings the list was sent with (speeds and delays commanded).
    pub galvo: GalvoSettings,
    /// What the list held.
    pub list: ListComposition,
    /// Measured: `EXECUTE` to done seen (s).
    pub measured_s: f64,
}

/// The fitted list terms.
#[derive(Debug, Clone, PartialEq)]
pub struct ListFit {
    /// `list_overhead_s`, `polyline_overhead_s`, `vertex_overhead_s` (s); `layer_overhead_s` 0.
    pub timing: TimingSettings,
    /// The terms the lists could not tell apart from the others (left at 0).
    pub not_determined: Vec<&'static str>,
    /// The terms that fitted negative, with the value they fitted (s): held at 0, the others
    /// re-fitted without them.
    pub held_at_zero: Vec<(&'static str, f64)>,
    /// Lists fitted.
    pub samples: usize,
    /// RMS of the commanded model − measured (s).
    pub rms_before_s: f64,
    /// RMS with the fitted terms (s).
    pub rms_after_s: f64,
}

/// Fits the `[timing]` list terms to recorded lists (linear least squares on what each list
/// took beyond its commanded speeds and delays). Every term comes out ≥ 0: one that fits
/// negative is held at 0 and named in [`ListFit::held_at_zero`] (see the module docs).
pub fn fit_lists(samples: &[ListSample]) -> Result<ListFit, CalibError> {
    let samples: Vec<&ListSample> = samples
        .iter()
        .filter(|s| s.measured_s.is_finite() && s.list.jumps > 0)
        .collect();
    if samples.len() < MIN_LISTS {
        return Err(CalibError::TooFew {
            what: "recorded galvo lists".into(),
            needed: MIN_LISTS,
            got: samples.len(),
        });
    }
    let n = samples.len();
    let excess = DVector::from_iterator(
        n,
        samples
            .iter()
            .map(|s| s.measured_s - s.list.commanded_s(&s.galvo)),
    );
    // The terms' names and their regressors: per list, per mark run, per inner vertex.
    let names = [
        "list_overhead_s",
        "polyline_overhead_s",
        "vertex_overhead_s",
    ];
    let regressor = |s: &ListSample, k: usize| match k {
        0 => 1.0,
        1 => s.list.mark_runs as f64,
        _ => s.list.vertices as f64,
    };
    // The terms fitted: all but those held at 0. Of them, keep the leading ones while the
    // normalised design stays well conditioned; hold the most negative term at 0 and fit again
    // while one is negative.
    let mut held: Vec<(&'static str, f64)> = Vec::new();
    let mut free: Vec<usize> = (0..names.len()).collect();
    let mut not_determined: Vec<&'static str> = Vec::new();
    let mut terms = [0.0; 3];
    while !free.is_empty() {
        let mut kept = free.len();
        let solution = loop {
            let a = DMatrix::from_fn(n, kept, |i, k| regressor(samples[i], free[k]));
            let scale: Vec<f64> = (0..kept)
                .map(|k| a.column(k).norm().max(f64::MIN_POSITIVE))
                .collect();
            let an = DMatrix::from_fn(n, kept, |i, k| a[(i, k)] / scale[k]);
            let svd = an.clone().svd(true, true);
            let (lo, hi) = (svd.singular_values.min(), svd.singular_values.max());
            if lo > LIST_CONDITION * hi || kept == 1 {
                let y = svd
                    .solve(&excess, 0.0)
                    .map_err(|e| CalibError::Degenerate(format!("the list fit: {e}")))?;
                break (0..kept).map(|k| y[k] / scale[k]).collect::<Vec<f64>>();
            }
            kept -= 1;
        };
        terms = [0.0; 3];
        for (k, &v) in solution.iter().enumerate() {
            terms[free[k]] = v;
        }
        let most_negative = (0..kept)
            .filter(|&k| solution[k] < 0.0)
            .min_by(|&a, &b| solution[a].total_cmp(&solution[b]));
        match most_negative {
            Some(k) => {
                held.push((names[free[k]], solution[k]));
                free.remove(k);
            }
            None => {
                not_determined = free[kept..].iter().map(|&k| names[k]).collect();
                break;
            }
        }
    }
    let timing = TimingSettings {
        layer_overhead_s: 0.0,
        list_overhead_s: terms[0],
        polyline_overhead_s: terms[1],
        vertex_overhead_s: terms[2],
    };
    let after = DVector::from_iterator(
        n,
        samples.iter().enumerate().map(|(i, s)| {
            excess[i]
                - (timing.list_overhead_s
                    + timing.polyline_overhead_s * s.list.mark_runs as f64
                    + timing.vertex_overhead_s * s.list.vertices as f64)
        }),
    );
    Ok(ListFit {
        timing,
        not_determined,
        held_at_zero: held,
        samples: n,
        rms_before_s: rms(&excess),
        rms_after_s: rms(&after),
    })
}

/// The median of the measured per-layer overheads (s); 0 without any.
///
/// `trimctl calibrate timing` writes it as `timing.layer_overhead_s` held at 0 when negative.
#[must_use]
pub fn median_s(values: &[f64]) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_xoshiro::Xoshiro256PlusPlus;

    use super::*;

    fn pose(rng: &mut Xoshiro256PlusPlus, scale: f64) -> AxisPose {
        AxisPose {
            linear_mm: [
                rng.random_range(-scale..scale),
                rng.random_range(-scale..scale),
                rng.random_range(-scale..scale),
            ],
            tilt_deg: rng.random_range(-scale..scale),
            rotary_deg: rng.random_range(-2.0 * scale..2.0 * scale),
        }
    }

    #[test]
    fn recovers_a_coordinated_move_model_from_noisy_moves() {
        let truth = MachineSettings {
            move_model: MoveModel::Coordinated,
            linear_speed_mm_per_s: 17.0,
            rotary_speed_deg_per_s: 41.0,
            linear_accel_mm_per_s2: 140.0,
            rotary_accel_deg_per_s2: 220.0,
            settle_s: 0.15,
            ..MachineSettings::default()
        };
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(7);
        let mut samples = Vec::new();
        let mut at = AxisPose::HOME;
        for i in 0..80 {
            // Long zone changes and short layer steps, as a job has.
            let to = if i % 3 == 0 {
                pose(&mut rng, 30.0)
            } else {
                AxisPose {
                    linear_mm: [at.linear_mm[0], at.linear_mm[1], at.linear_mm[2] + 0.6],
                    ..at
                }
            };
            let noise = rng.random_range(-0.002..0.002);
            samples.push(MoveSample {
                from: at,
                to,
                measured_s: move_time_s(&truth, &at, &to) + noise,
            });
            at = to;
        }
        let fit = fit_moves(&MachineSettings::default(), &samples).expect("fit");
        let m = fit.machine;
        assert!((m.linear_speed_mm_per_s - 17.0).abs() < 0.2, "{m:?}");
        assert!((m.rotary_speed_deg_per_s - 41.0).abs() < 0.5, "{m:?}");
        assert!((m.linear_accel_mm_per_s2 - 140.0).abs() < 10.0, "{m:?}");
        assert!((m.rotary_accel_deg_per_s2 - 220.0).abs() < 40.0, "{m:?}");
        assert!((m.settle_s - 0.15).abs() < 0.005, "{m:?}");
        assert!(fit.rms_after_s < 0.002, "{fit:?}");
        assert!(fit.rms_before_s > 10.0 * fit.rms_after_s, "{fit:?}");
        assert!(fit.not_determined.is_empty());
        assert!(fit.sigma.iter().all(|s| s.is_finite()), "{fit:?}");
    }

    #[test]
    fn an_acceleration_the_moves_do_not_show_is_named_and_kept() {
        // The axes reach their speeds at once (as short blended moves look): the fit would
        // drive the accelerations to infinity, where no move depends on them.
        let truth = MachineSettings {
            move_model: MoveModel::Coordinated,
            linear_speed_mm_per_s: 18.0,
            rotary_speed_deg_per_s: 27.0,
            linear_accel_mm_per_s2: 1e12,
            rotary_accel_deg_per_s2: 1e12,
            settle_s: 0.1,
            ..MachineSettings::default()
        };
        let speed = truth.linear_speed_mm_per_s;
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
        let mut at = AxisPose::HOME;
        let samples: Vec<MoveSample> = (0..30)
            .map(|_| {
                let to = pose(&mut rng, 20.0);
                let s = MoveSample {
                    from: at,
                    to,
                    measured_s: move_time_s(&truth, &at, &to),
                };
                at = to;
                s
            })
            .collect();
        let start = MachineSettings::default();
        let fit = fit_moves(&start, &samples).expect("fit");
        assert!(
            fit.not_determined.contains(&"linear_accel_mm_per_s2"),
            "{fit:?}"
        );
        assert_eq!(
            fit.machine.linear_accel_mm_per_s2,
            start.linear_accel_mm_per_s2
        );
        assert!(
            (fit.machine.linear_speed_mm_per_s - speed).abs() < 0.5,
            "{fit:?}"
        );
        for (k, name) in MOVE_PARAMETERS.iter().enumerate() {
            assert!(
                fit.not_determined.contains(name) || fit.sigma[k].is_finite(),
                "{name}: σ {} ({fit:?})",
                fit.sigma[k]
            );
        }
        assert!(fit.machine.validate().is_ok());
    }

    #[test]
    fn an_axis_no_move_turns_is_named_and_kept() {
        let truth = MachineSettings {
            move_model: MoveModel::Coordinated,
            linear_speed_mm_per_s: 12.0,
            settle_s: 0.2,
            ..MachineSettings::default()
        };
        let samples: Vec<MoveSample> = (1..10)
            .map(|i| {
                let to = AxisPose {
                    linear_mm: [f64::from(i) * 3.0, 0.0, 0.0],
                    ..AxisPose::HOME
                };
                MoveSample {
                    from: AxisPose::HOME,
                    to,
                    measured_s: move_time_s(&truth, &AxisPose::HOME, &to),
                }
            })
            .collect();
        let start = MachineSettings::default();
        let fit = fit_moves(&start, &samples).expect("fit");
        assert!(fit.not_determined.contains(&"rotary_speed_deg_per_s"));
        assert!(fit.not_determined.contains(&"rotary_accel_deg_per_s2"));
        assert_eq!(
            fit.machine.rotary_speed_deg_per_s,
            start.rotary_speed_deg_per_s
        );
        assert!((fit.machine.linear_speed_mm_per_s - 12.0).abs() < 1e-3);
        let too_few = fit_moves(&start, &samples[..3]).unwrap_err();
        assert!(too_few.to_string().contains("need at least 6"), "{too_few}");
    }

    /// 30 random lists (seeded) of the default galvo, each measured as its commanded time
    /// plus `overhead(mark runs, vertices)`.
    fn random_lists(seed: u64, overhead: impl Fn(usize, usize) -> f64) -> Vec<ListSample> {
        let galvo = GalvoSettings::default();
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        (0..30)
            .map(|_| {
                let runs = rng.random_range(1..40);
                let vectors = runs + rng.random_range(0..400);
                let list = ListComposition {
                    jumps: runs,
                    jump_mm: rng.random_range(1.0..200.0),
                    mark_runs: runs,
                    vectors,
                    vertices: vectors - runs,
                    mark_mm: rng.random_range(1.0..500.0),
                };
                ListSample {
                    galvo,
                    list,
                    measured_s: list.commanded_s(&galvo) + overhead(runs, vectors - runs),
                }
            })
            .collect()
    }

    #[test]
    fn recovers_list_terms_and_names_what_it_cannot_tell_apart() {
        let samples = random_lists(3, |runs, vertices| {
            0.004 + 30e-6 * runs as f64 + 2e-6 * vertices as f64
        });
        let fit = fit_lists(&samples).expect("fit");
        assert!((fit.timing.list_overhead_s - 0.004).abs() < 1e-9, "{fit:?}");
        assert!((fit.timing.polyline_overhead_s - 30e-6).abs() < 1e-10);
        assert!((fit.timing.vertex_overhead_s - 2e-6).abs() < 1e-11);
        assert!(fit.rms_after_s < 1e-9 && fit.not_determined.is_empty());
        // Every list one polyline of 5 vectors: only the per-list term is determined.
        let same: Vec<ListSample> = samples
            .iter()
            .map(|s| ListSample {
                list: ListComposition {
                    mark_runs: 1,
                    jumps: 1,
                    vectors: 5,
                    vertices: 4,
                    ..s.list
                },
                ..*s
            })
            .collect();
        let fit = fit_lists(&same).expect("fit");
        assert_eq!(
            fit.not_determined,
            vec!["polyline_overhead_s", "vertex_overhead_s"]
        );
        assert!((median_s(&[3.0, 1.0, 2.0, 10.0]) - 2.5).abs() < 1e-15);
    }

    #[test]
    fn a_term_that_fits_negative_is_held_at_zero_and_named() {
        // The controller is quicker than commanded per vertex (−16.5 µs, as a recorded run
        // fitted): the term is held at 0, the others refitted, and the result validates.
        let samples = random_lists(5, |runs, vertices| {
            0.1 + 400e-6 * runs as f64 - 16.5e-6 * vertices as f64
        });
        let fit = fit_lists(&samples).expect("fit");
        assert_eq!(fit.held_at_zero.len(), 1, "{fit:?}");
        assert_eq!(fit.held_at_zero[0].0, "vertex_overhead_s");
        assert!((fit.held_at_zero[0].1 + 16.5e-6).abs() < 1e-9, "{fit:?}");
        assert_eq!(fit.timing.vertex_overhead_s, 0.0);
        assert!(fit.timing.list_overhead_s >= 0.0 && fit.timing.polyline_overhead_s >= 0.0);
        fit.timing.validate().expect("a fitted model validates");
        assert!(fit.not_determined.is_empty());
    }
}
