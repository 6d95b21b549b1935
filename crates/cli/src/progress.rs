//! Progress on long work: indicatif bars on a terminal, plain log lines otherwise.

use std::io::IsTerminal;
use std::time::Duration;

use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};

/// How often a bar redraws.
const TICK: Duration = Duration::from_millis(100);

/// Zones, layers and vectors of a running job.
pub struct JobProgress {
    bars: Option<(MultiProgress, ProgressBar, ProgressBar, ProgressBar)>,
    zones_total: u64,
    layers_total: u64,
    layers_done: u64,
}

fn style(template: &str) -> ProgressStyle {
    ProgressStyle::with_template(template)
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> ")
}

impl JobProgress {
    /// Bars on stderr when it is a terminal; otherwise a log line per layer.
    pub fn new(zones: u64, layers: u64, vectors: u64) -> JobProgress {
        let bars = std::io::stderr().is_terminal().then(|| {
            let multi = MultiProgress::with_draw_target(ProgressDrawTarget::stderr());
            let z = multi.add(ProgressBar::new(zones));
            z.set_style(style("zones   [{bar:40}] {pos}/{len} {msg}"));
            let l = multi.add(ProgressBar::new(layers));
            l.set_style(style("layers  [{bar:40}] {pos}/{len} eta {eta}"));
            let v = multi.add(ProgressBar::new(vectors));
            v.set_style(style("vectors [{bar:40}] {pos}/{len}"));
            for b in [&z, &l, &v] {
                b.enable_steady_tick(TICK);
            }
            (multi, z, l, v)
        });
        JobProgress {
            bars,
            zones_total: zones,
            layers_total: layers,
            layers_done: 0,
        }
    }

    /// A zone started.
    pub fn zone_started(&mut self, zone: usize, index: u64) {
        match &self.bars {
            Some((_, z, _, _)) => {
                z.set_position(index);
                z.set_message(format!("zone {zone}"));
            }
            None => tracing::info!("zone {zone} started ({}/{})", index + 1, self.zones_total),
        }
    }

    /// A layer finished with `vectors` vectors marked.
    pub fn layer_done(&mut self, zone: usize, layer: usize, vectors: u64) {
        self.layers_done += 1;
        match &self.bars {
            Some((_, _, l, v)) => {
                l.inc(1);
                v.inc(vectors);
            }
            None => tracing::info!(
                "zone {zone} layer {layer} done: {vectors} vectors ({}/{} layers)",
                self.layers_done,
                self.layers_total
            ),
        }
    }

    /// Layers already finished by an earlier run (resume).
    pub fn skip_layers(&mut self, layers: u64, vectors: u64) {
        self.layers_done += layers;
        if let Some((_, _, l, v)) = &self.bars {
            l.inc(layers);
            v.inc(vectors);
        }
    }

    /// Clears the bars.
    pub fn finish(self) {
        if let Some((_, z, l, v)) = self.bars {
            z.set_position(self.zones_total);
            for b in [z, l, v] {
                b.finish_and_clear();
            }
        }
    }
}

/// A spinner for one stage of work (register, plan), or a log line when not on a terminal.
pub fn stage(message: &str) -> Option<ProgressBar> {
    if std::io::stderr().is_terminal() {
        let s = ProgressBar::new_spinner();
        s.set_style(
            ProgressStyle::with_template("{spinner} {msg} {elapsed}")
                .unwrap_or_else(|_| ProgressStyle::default_spinner()),
        );
        s.set_message(message.to_string());
        s.enable_steady_tick(TICK);
        Some(s)
    } else {
        tracing::info!("{message}");
        None
    }
}
