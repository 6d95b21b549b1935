//! The galvo's time model and the cycle-time terms beyond the machine's moves (DESIGN.md
//! "Estimates learned from runs"): what a layer's galvo list takes ([`ListComposition`], its
//! [`ListComposition::marking_s`] and [`ListComposition::jumping_s`], [`list_time_s`]) and the
//! terms a real cell adds to the commanded speeds and delays (job.toml `[timing]`,
//! [`TimingSettings`]). This is the one model of docs/protocols/galvo.md §6 in millimetres: the
//! planner's estimate, the executor's and `trimctl report`'s all use it; trim-io's `ListClock`
//! runs the same model over list commands in bits (the simulator's clock).
//!
//! A layer's estimate is `move (+ settle) + list + layer overhead`: the move by
//! [`crate::kinematics::move_time_s`] (job.toml `[machine]`), the list by the galvo's own model of
//! its speeds and delays (`[galvo]`, docs/protocols/galvo.md §6) plus the `[timing]` terms. The
//! `[galvo]` delays are commands the controller is sent, so a fit never changes them: it learns
//! what a list takes beyond them (`trimctl calibrate timing`).

use serde::{Deserialize, Serialize};

use crate::error::CellError;
use crate::job::{GalvoSettings, Polyline};

/// Seconds per microsecond.
const S_PER_US: f64 = 1e-6;

/// The time a real cell adds to the commanded model (job.toml `[timing]`); all 0 by default,
/// which is the commanded model alone. Written by `trimctl calibrate timing`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct TimingSettings {
    /// Per layer, outside the move and the list: emission on and off, EXECUTE, journal (s).
    pub layer_overhead_s: f64,
    /// Per galvo list, beyond its speeds and delays: EXECUTE to done seen (s, ≥ 0).
    pub list_overhead_s: f64,
    /// Per polyline (one jump and one mark run), beyond the jump, laser on/off and mark
    /// delays (s, ≥ 0).
    pub polyline_overhead_s: f64,
    /// Per inner vertex of a mark run, beyond the polygon delay (s, ≥ 0).
    pub vertex_overhead_s: f64,
}

impl TimingSettings {
    /// Refuses a non-finite or negative overhead, naming the key: each is time a real cell
    /// adds to the commanded model, and a negative one (per vertex, times the thousands of
    /// vertices of a part) drives the estimate below zero. `trimctl calibrate timing` holds a
    /// term the lists would fit negative at 0 (`trim_calib::timing_fit::fit_lists`).
    pub fn validate(&self) -> Result<(), CellError> {
        for (key, v) in [
            ("timing.layer_overhead_s", self.layer_overhead_s),
            ("timing.list_overhead_s", self.list_overhead_s),
            ("timing.polyline_overhead_s", self.polyline_overhead_s),
            ("timing.vertex_overhead_s", self.vertex_overhead_s),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(CellError::setting(key, v, "must be a finite number ≥ 0"));
            }
        }
        Ok(())
    }

    /// What a layer whose list is `list` adds beyond its move and the commanded list model (s).
    #[must_use]
    pub fn extra_s(&self, list: &ListComposition) -> f64 {
        self.layer_overhead_s
            + self.list_overhead_s
            + self.polyline_overhead_s * list.mark_runs as f64
            + self.vertex_overhead_s * list.vertices as f64
    }
}

/// What a layer's list time depends on: the galvo commands of its polylines (mm, after the
/// lens model), marked from the field centre, each polyline a jump to its start (jump speed +
/// jump delay) and one mark run (length at mark speed + laser-on delay + a polygon delay per
/// inner vertex + laser-off and mark delays).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ListComposition {
    /// Polylines (each with at least one point): one jump each.
    pub jumps: usize,
    /// Jump length, from the field centre and from each polyline's end to the next start (mm).
    pub jump_mm: f64,
    /// Polylines with at least one vector: one mark run each.
    pub mark_runs: usize,
    /// Vectors marked (segments).
    pub vectors: usize,
    /// Inner vertices of the mark runs (vectors − mark runs): one polygon delay each.
    pub vertices: usize,
    /// Marked length (mm).
    pub mark_mm: f64,
}

impl ListComposition {
    /// The composition of a layer's polylines.
    #[must_use]
    pub fn of(polylines: &[Polyline]) -> ListComposition {
        let mut c = ListComposition::default();
        let mut pos = [0.0_f64, 0.0_f64];
        for sent in polylines.iter().flat_map(Polyline::passes_commands) {
            let (Some(first), Some(last)) = (sent.first(), sent.last()) else {
                continue;
            };
            c.jumps += 1;
            c.jump_mm += (first[0] - pos[0]).hypot(first[1] - pos[1]);
            let segments = sent.len() - 1;
            if segments > 0 {
                c.mark_runs += 1;
                c.vectors += segments;
                c.vertices += segments - 1;
                c.mark_mm += sent
                    .windows(2)
                    .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
                    .sum::<f64>();
            }
            pos = *last;
        }
        c
    }

    /// The commanded model's marking time of the list (s): the marked length at the mark speed
    /// plus each mark run's laser-on, laser-off and mark delays and each inner vertex's polygon
    /// delay.
    #[must_use]
    pub fn marking_s(&self, galvo: &GalvoSettings) -> f64 {
        self.mark_mm / galvo.mark_speed_mm_per_s
            + (self.mark_runs as f64
                * (galvo.laser_on_delay_us + galvo.laser_off_delay_us + galvo.mark_delay_us)
                + self.vertices as f64 * galvo.polygon_delay_us)
                * S_PER_US
    }

    /// The commanded model's jumping time of the list (s): the jump length at the jump speed
    /// plus a jump delay per jump.
    #[must_use]
    pub fn jumping_s(&self, galvo: &GalvoSettings) -> f64 {
        self.jump_mm / galvo.jump_speed_mm_per_s
            + self.jumps as f64 * galvo.jump_delay_us * S_PER_US
    }

    /// The commanded model's time of the list (s): lengths at the commanded speeds plus the
    /// commanded delays ([`ListComposition::marking_s`] + [`ListComposition::jumping_s`]).
    #[must_use]
    pub fn commanded_s(&self, galvo: &GalvoSettings) -> f64 {
        self.marking_s(galvo) + self.jumping_s(galvo)
    }
}

/// The estimated time of a layer's list (s): the commanded model plus the `[timing]` list
/// terms (not the per-layer overhead).
#[must_use]
pub fn list_time_s(galvo: &GalvoSettings, timing: &TimingSettings, list: &ListComposition) -> f64 {
    list.commanded_s(galvo)
        + timing.list_overhead_s
        + timing.polyline_overhead_s * list.mark_runs as f64
        + timing.vertex_overhead_s * list.vertices as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn composition_gives_the_galvo_model() {
        let galvo = GalvoSettings::default();
        let polylines = [
            Polyline::from_points(1, vec![[3.0, 4.0], [4.0, 4.0], [4.0, 5.0]]),
            Polyline::from_points(2, vec![[-1.0, 0.0]]),
            Polyline::from_points(3, vec![[0.0, 0.0], [0.0, 2.0]]),
        ];
        let c = ListComposition::of(&polylines);
        assert_eq!((c.jumps, c.mark_runs, c.vectors, c.vertices), (3, 2, 3, 1));
        assert!((c.mark_mm - 4.0).abs() < 1e-12);
        assert!((c.jump_mm - (5.0 + 50.0_f64.sqrt() + 1.0)).abs() < 1e-12);
        // Default galvo: jump 3000 mm/s, 200 µs; mark 500 mm/s; on, off, mark delays 100 µs
        // each; polygon 20 µs.
        let jumping_s = (5.0 + 50.0_f64.sqrt() + 1.0) / 3000.0 + 3.0 * 200e-6;
        let marking_s = 4.0 / 500.0 + (2.0 * 300.0 + 20.0) * 1e-6;
        assert!((c.jumping_s(&galvo) - jumping_s).abs() < 1e-15);
        assert!((c.marking_s(&galvo) - marking_s).abs() < 1e-15);
        assert!((c.commanded_s(&galvo) - (marking_s + jumping_s)).abs() < 1e-15);
        let timing = TimingSettings {
            layer_overhead_s: 1.0,
            list_overhead_s: 0.01,
            polyline_overhead_s: 0.001,
            vertex_overhead_s: 0.0001,
        };
        let extra = list_time_s(&galvo, &timing, &c) - c.commanded_s(&galvo);
        assert!((extra - (0.01 + 0.002 + 0.0001)).abs() < 1e-15);
        assert!((timing.extra_s(&c) - (1.0 + extra)).abs() < 1e-15);
        assert!(TimingSettings::default().validate().is_ok());
        let bad = TimingSettings {
            layer_overhead_s: -0.1,
            ..TimingSettings::default()
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("layer_overhead_s")
        );
        for (bad, key) in [
            (
                TimingSettings {
                    list_overhead_s: -1.0,
                    ..TimingSettings::default()
                },
                "timing.list_overhead_s",
            ),
            (
                TimingSettings {
                    polyline_overhead_s: -1.0,
                    ..TimingSettings::default()
                },
                "timing.polyline_overhead_s",
            ),
            (
                TimingSettings {
                    vertex_overhead_s: -1e-6,
                    ..TimingSettings::default()
                },
                "timing.vertex_overhead_s",
            ),
            (
                TimingSettings {
                    list_overhead_s: f64::INFINITY,
                    ..TimingSettings::default()
                },
                "timing.list_overhead_s",
            ),
        ] {
            let e = bad.validate().unwrap_err().to_string();
            assert!(e.contains(key), "{key}: {e}");
        }
        let bad = TimingSettings {
            vertex_overhead_s: f64::NAN,
            ..TimingSettings::default()
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("vertex_overhead_s")
        );
    }
}
