//! `trimctl config` (filled by its issue).

/// Arguments of `trimctl config`.
#[derive(clap::Args, Debug)]
pub struct Args {}

/// Runs the command.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("`trimctl config` is not built yet")
}
