//! `trimctl synth` (filled by its issue).

/// Arguments of `trimctl synth`.
#[derive(clap::Args, Debug)]
pub struct Args {}

/// Runs the command.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("`trimctl synth` is not built yet")
}
