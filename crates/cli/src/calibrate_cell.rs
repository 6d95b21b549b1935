//! `trimctl calibrate cell --scans DIR --poses poses.csv --sphere-diameter-mm D --tool-mark X,Y,Z --out cal.toml`.

use std::path::PathBuf;

/// Arguments of `trimctl calibrate cell`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The folder holding the sphere scans (PLY or PCD, scanner frame) named in poses.csv.
    #[arg(long)]
    pub scans: PathBuf,
    /// CSV with the header `scan,x,y,z,a,c` (file name in --scans; mm; degrees). A B/C cell
    /// writes `b` for `a`.
    #[arg(long)]
    pub poses: PathBuf,
    /// The precision sphere's diameter (mm).
    #[arg(long)]
    pub sphere_diameter_mm: f64,
    /// The centre of a laser mark made at the field centre, as the scanner saw it at the first
    /// pose (scanner frame, mm): X,Y,Z.
    #[arg(
        long,
        value_delimiter = ',',
        num_args = 3,
        allow_negative_numbers = true
    )]
    pub tool_mark: Vec<f64>,
    /// Where to write the `[calibration]` table (TOML).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    anyhow::bail!("calibrate cell: being built ({args:?})")
}
