//! The galvo timing model of docs/protocols/galvo.md §6 over list commands in bits: what the
//! simulator's clock runs on, and the modelled time of a list the executor sends. The same model
//! over a layer's polylines in millimetres (the estimate) is trim-cell's
//! [`trim_cell::galvo_timing::ListComposition`].

use super::protocol::ListCommand;

/// The timing state of a list being executed: position, speeds, delays, and whether a mark run
/// is open. Feed it commands in order; it returns each command's time.
#[derive(Debug, Clone)]
pub struct ListClock {
    pos_bits: [f64; 2],
    jump_bits_per_ms: f64,
    mark_bits_per_ms: f64,
    laser_on_ns: f64,
    laser_off_ns: f64,
    jump_delay_ns: f64,
    mark_delay_ns: f64,
    polygon_ns: f64,
    in_mark_run: bool,
}

impl Default for ListClock {
    fn default() -> Self {
        ListClock {
            pos_bits: [0.0, 0.0],
            // Until a SPEEDS record: 1000 bits/ms. Documented nowhere else: lists set speeds first.
            jump_bits_per_ms: 1000.0,
            mark_bits_per_ms: 1000.0,
            laser_on_ns: 0.0,
            laser_off_ns: 0.0,
            jump_delay_ns: 0.0,
            mark_delay_ns: 0.0,
            polygon_ns: 0.0,
            in_mark_run: false,
        }
    }
}

/// What one command does to the light, for the simulator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Step {
    /// Time spent closing a mark run before this command (laser off + mark delay), ns.
    pub run_end_ns: f64,
    /// Time of the command itself (ns), including a laser-on delay or polygon delay before a mark.
    pub ns: f64,
    /// Whether this command is a vector with the gate open.
    pub is_mark: bool,
}

impl ListClock {
    /// A clock at the field centre with default speeds.
    #[must_use]
    pub fn new() -> ListClock {
        ListClock::default()
    }

    /// Advances over one command.
    pub fn step(&mut self, cmd: &ListCommand) -> Step {
        let mut run_end_ns = 0.0;
        if self.in_mark_run && !matches!(cmd, ListCommand::Mark { .. }) {
            run_end_ns = self.end_run();
        }
        let ns = match *cmd {
            ListCommand::Jump { x, y } => {
                let len = self.move_to(x, y);
                len / self.jump_bits_per_ms * 1e6 + self.jump_delay_ns
            }
            ListCommand::Mark { x, y } => {
                let lead = if self.in_mark_run {
                    self.polygon_ns
                } else {
                    self.in_mark_run = true;
                    self.laser_on_ns
                };
                let len = self.move_to(x, y);
                lead + len / self.mark_bits_per_ms * 1e6
            }
            ListCommand::Speeds {
                jump_bits_per_ms,
                mark_bits_per_ms,
            } => {
                self.jump_bits_per_ms = jump_bits_per_ms;
                self.mark_bits_per_ms = mark_bits_per_ms;
                0.0
            }
            ListCommand::LaserDelays { on_ns, off_ns } => {
                self.laser_on_ns = f64::from(on_ns);
                self.laser_off_ns = f64::from(off_ns);
                0.0
            }
            ListCommand::ScannerDelays {
                jump_ns,
                mark_ns,
                polygon_ns,
            } => {
                self.jump_delay_ns = f64::from(jump_ns);
                self.mark_delay_ns = f64::from(mark_ns);
                self.polygon_ns = f64::from(polygon_ns);
                0.0
            }
            ListCommand::Dwell { ns } => f64::from(ns),
        };
        Step {
            run_end_ns,
            ns,
            is_mark: matches!(cmd, ListCommand::Mark { .. }),
        }
    }

    /// Closes an open mark run (at the end of a list); returns its closing time (ns).
    pub fn finish(&mut self) -> f64 {
        if self.in_mark_run {
            self.end_run()
        } else {
            0.0
        }
    }

    fn end_run(&mut self) -> f64 {
        self.in_mark_run = false;
        self.laser_off_ns + self.mark_delay_ns
    }

    fn move_to(&mut self, x: i32, y: i32) -> f64 {
        let (x, y) = (f64::from(x), f64::from(y));
        let len = ((x - self.pos_bits[0]).powi(2) + (y - self.pos_bits[1]).powi(2)).sqrt();
        self.pos_bits = [x, y];
        len
    }
}

impl ListClock {
    /// The modelled time of a whole list (seconds), from the field centre with default speeds.
    #[must_use]
    pub fn list_s(commands: &[ListCommand]) -> f64 {
        let mut clock = ListClock::new();
        let mut ns = 0.0;
        for c in commands {
            let s = clock.step(c);
            ns += s.run_end_ns + s.ns;
        }
        (ns + clock.finish()) * 1e-9
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use trim_cell::galvo_timing::ListComposition;
    use trim_cell::job::{GalvoSettings, Polyline};

    #[test]
    fn a_square_takes_what_the_model_says() {
        // 10 000 bits/mm; jump 1000 mm/s = 10 000 bits/ms; mark 100 mm/s = 1000 bits/ms.
        let cmds = [
            ListCommand::Speeds {
                jump_bits_per_ms: 10_000.0,
                mark_bits_per_ms: 1000.0,
            },
            ListCommand::LaserDelays {
                on_ns: 100_000,
                off_ns: 50_000,
            },
            ListCommand::ScannerDelays {
                jump_ns: 200_000,
                mark_ns: 30_000,
                polygon_ns: 10_000,
            },
            ListCommand::Jump {
                x: 30_000,
                y: 40_000,
            }, // 5 mm: 5 ms + 0.2 ms
            ListCommand::Mark {
                x: 40_000,
                y: 40_000,
            }, // 1 mm: 0.1 ms on + 10 ms
            ListCommand::Mark {
                x: 40_000,
                y: 50_000,
            }, // 1 mm: 0.01 ms + 10 ms
        ];
        let expected_s = 5e-3 + 0.2e-3 + 0.1e-3 + 10e-3 + 0.01e-3 + 10e-3 + 0.05e-3 + 0.03e-3;
        assert!((ListClock::list_s(&cmds) - expected_s).abs() < 1e-12);
        let settings = GalvoSettings {
            field_mm: [100.0, 100.0],
            bits_per_mm: 10_000.0,
            mark_speed_mm_per_s: 100.0,
            jump_speed_mm_per_s: 1000.0,
            laser_on_delay_us: 100.0,
            laser_off_delay_us: 50.0,
            jump_delay_us: 200.0,
            mark_delay_us: 30.0,
            polygon_delay_us: 10.0,
        };
        let pl = Polyline::from_points(1, vec![[3.0, 4.0], [4.0, 4.0], [4.0, 5.0]]);
        let list = ListComposition::of(&[pl]);
        let (m, j) = (list.marking_s(&settings), list.jumping_s(&settings));
        assert!(
            (m + j - expected_s).abs() < 1e-12,
            "{m} + {j} vs {expected_s}"
        );
        assert!((j - 5.2e-3).abs() < 1e-12);
    }
}
