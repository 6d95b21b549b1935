//! `trimctl calibrate`: measure the cell (DESIGN.md "Frames and the calibration chain") and its
//! cycle time ("Estimates learned from runs").

use clap::Subcommand;

use crate::{calibrate_cell, calibrate_field, calibrate_timing};

/// What to calibrate.
#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(subcommand)]
    what: What,
}

#[derive(Subcommand, Debug)]
enum What {
    /// Rotary axis lines and the scanner's pose on the head, from scans of a sphere fixed on
    /// the table at N ≥ 8 machine poses and one laser mark seen by the scanner.
    Cell(calibrate_cell::Args),
    /// The galvo field correction (distortion, offset, rotation, lens pivot height) from a
    /// marked and measured grid.
    Field(calibrate_field::Args),
    /// The cycle-time model (machine speeds, accelerations, settle; the galvo lists' and the
    /// layers' overheads) from recorded runs.
    Timing(calibrate_timing::Args),
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    match args.what {
        What::Cell(a) => calibrate_cell::run(a),
        What::Field(a) => calibrate_field::run(a),
        What::Timing(a) => calibrate_timing::run(a),
    }
}
