//! `trimctl sim` (filled by its issue).

/// Arguments of `trimctl sim`.
#[derive(clap::Args, Debug)]
pub struct Args {}

/// Runs the command.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("`trimctl sim` is not built yet")
}
