//! `trimctl run` (filled by its issue).

/// Arguments of `trimctl run`.
#[derive(clap::Args, Debug)]
pub struct Args {}

/// Runs the command.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("`trimctl run` is not built yet")
}
