//! `trimctl info` (filled by its issue).

/// Arguments of `trimctl info`.
#[derive(clap::Args, Debug)]
pub struct Args {}

/// Runs the command.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("`trimctl info` is not built yet")
}
