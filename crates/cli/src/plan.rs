//! `trimctl plan` (filled by its issue).

/// Arguments of `trimctl plan`.
#[derive(clap::Args, Debug)]
pub struct Args {}

/// Runs the command.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("`trimctl plan` is not built yet")
}
