//! `trimctl beam`: the beam optics figures of the configured (or the paper's) cell as JSON.

use std::path::PathBuf;

use anyhow::Context;
use trim_io::laser::Profile;

use crate::config::JobConfig;

/// Arguments of `trimctl beam`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// A job file whose `[beam]` table sets the figures and whose `cell.laser_profile` sets the
    /// source's limits (default: the paper's cell on the default profile).
    #[arg(long)]
    pub config: Option<PathBuf>,
}

/// Runs the command: prints pulse_energy_uj, waist_radius_um, rayleigh_length_mm,
/// peak_fluence_j_per_cm2, focus_half_length_mm, spot_ratio_min, spot_ratio_max (and
/// max_incidence_for_line_width_deg) as one JSON object on stdout; on stderr, the operating
/// point against the laser profile's limits. An operating point outside them is refused.
pub fn run(args: Args) -> anyhow::Result<()> {
    let config = match &args.config {
        Some(path) => JobConfig::load(path)?,
        None => {
            let config = JobConfig::default();
            config.validate().context("the default job")?;
            config
        }
    };
    // Loading (or validating the defaults) checked [beam] and its operating point against
    // cell.laser_profile's limits.
    let beam = config.plan.beam;
    let profile = Profile::builtin(&config.cell.laser_profile)
        .map_err(|e| anyhow::anyhow!("cell.laser_profile: {e}"))?;
    let report = beam.report();
    let l = &profile.limits;
    eprintln!(
        "trimctl beam: laser profile {:?}: {:.2} µJ of {} µJ, {} W of {} W, {} kHz in {}-{} kHz",
        profile.name,
        report.pulse_energy_uj,
        l.pulse_energy_uj_max,
        beam.power_w,
        l.average_power_w_max,
        beam.repetition_rate_hz * 1e-3,
        l.rep_rate_khz_min,
        l.rep_rate_khz_max,
    );
    let text = serde_json::to_string_pretty(&report)?;
    println!("{text}");
    Ok(())
}
