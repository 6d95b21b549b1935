//! `trimctl beam`: the beam optics figures of the configured (or the paper's) cell as JSON.

use std::path::PathBuf;

use anyhow::Context;
use trim_plan::Beam;

use crate::config::JobConfig;

/// Arguments of `trimctl beam`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// A job file whose `[beam]` table sets the figures (default: the paper's cell).
    #[arg(long)]
    pub config: Option<PathBuf>,
}

/// Runs the command: prints pulse_energy_uj, waist_radius_um, rayleigh_length_mm,
/// peak_fluence_j_per_cm2, focus_half_length_mm, spot_ratio_min, spot_ratio_max (and
/// max_incidence_for_line_width_deg) as one JSON object on stdout.
pub fn run(args: Args) -> anyhow::Result<()> {
    let beam = match &args.config {
        Some(path) => JobConfig::load(path)?.beam,
        None => Beam::default(),
    };
    beam.validate().context("[beam]")?;
    let text = serde_json::to_string_pretty(&beam.report())?;
    println!("{text}");
    Ok(())
}
