//! The `trimctl` command line: one struct per subcommand, results on stdout, diagnostics on
//! stderr. `main` alone owns the exit codes (see [`exit`]).

mod beam;
mod cad;
mod calibrate;
mod calibrate_cell;
mod calibrate_field;
mod calibrate_timing;
mod config;
mod config_cmd;
mod deviation_map;
mod exit;
mod frame;
mod hatch;
mod info;
mod inspect;
mod outputs;
mod plan;
mod progress;
mod register;
mod registration_svg;
mod report_cmd;
mod run;
mod scans;
#[cfg(feature = "sim")]
mod sim;
mod simulated;
mod stop_signal;
mod summary;
mod synth;
mod timing_record;
mod twin_demo;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Zone-layered ultrafast-laser trimming of deformed freeform parts.
#[derive(Parser, Debug)]
#[command(name = "trimctl", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Register, plan and execute a job on the cell (no argument: the built-in demo).
    Run(run::Args),
    /// Register a CAM path onto a scan of the clamped part.
    Register(register::Args),
    /// Plan zones, layers, galvo polylines and machine poses from a (registered) path.
    Plan(plan::Args),
    /// Print the beam optics figures as JSON.
    Beam(beam::Args),
    /// Print what a point cloud, mesh or path file holds, as JSON.
    Info(info::Args),
    /// Write a synthetic ceramic-core-like test case.
    Synth(synth::Args),
    /// Start device simulators as servers.
    #[cfg(feature = "sim")]
    Sim(sim::Args),
    /// Show the job.toml configuration.
    Config(config_cmd::Args),
    /// Calibrate the cell: rotary axes and scanner pose (`cell`), galvo field (`field`).
    Calibrate(calibrate::Args),
    /// Hatch a region of a scanned surface with equally spaced tracks.
    Hatch(hatch::Args),
    /// Trace each zone's outline with the galvo's pointer (red light), the laser gate shut.
    Frame(frame::Args),
    /// Inspect a trimmed part: scan fitted to the CAD, every contour measured and judged.
    Inspect(inspect::Args),
    /// Compare a recorded run's time estimate with its actual time, per layer, move and list.
    Report(report_cmd::Args),
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => return exit::code_for_usage(&e),
    };
    exit::init_logging();
    let result = match cli.command {
        Command::Run(a) => run::run(a),
        Command::Register(a) => register::run(a),
        Command::Plan(a) => plan::run(a),
        Command::Beam(a) => beam::run(a),
        Command::Info(a) => info::run(a),
        Command::Synth(a) => synth::run(a),
        #[cfg(feature = "sim")]
        Command::Sim(a) => sim::run(a),
        Command::Config(a) => config_cmd::run(a),
        Command::Calibrate(a) => calibrate::run(a),
        Command::Hatch(a) => hatch::run(a),
        Command::Frame(a) => frame::run(a),
        Command::Report(a) => report_cmd::run(a),
        Command::Inspect(a) => inspect::run(a),
    };
    exit::code_for(result)
}
