//! `trimctl beam` (filled by its issue).

/// Arguments of `trimctl beam`.
#[derive(clap::Args, Debug)]
pub struct Args {}

/// Runs the command.
pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("`trimctl beam` is not built yet")
}
