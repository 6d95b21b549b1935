//! `trimctl register` (filled by its issue).

/// Arguments of `trimctl register`.
#[derive(clap::Args, Debug)]
pub struct Args {}

/// Runs the command.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("`trimctl register` is not built yet")
}
