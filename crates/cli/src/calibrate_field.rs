//! `trimctl calibrate field --marks marks.csv --out field.json`.

use std::path::PathBuf;

/// Arguments of `trimctl calibrate field`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// CSV with the header `x_cmd,y_cmd,h_mm,x_meas,y_meas` (mm, head frame).
    #[arg(long)]
    pub marks: PathBuf,
    /// Where to write the field correction (field.json).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    anyhow::bail!("calibrate field: being built ({args:?})")
}
