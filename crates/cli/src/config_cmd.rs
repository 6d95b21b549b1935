//! `trimctl config`: show or check the job.toml configuration.

use std::path::PathBuf;

use crate::config::{JobConfig, dump_default};

/// Arguments of `trimctl config`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Print the full default job file, with comments.
    #[arg(long, conflicts_with_all = ["check", "schema"])]
    dump: bool,
    /// Print job.toml's JSON Schema (for editors: taplo, Even Better TOML).
    #[arg(long, conflicts_with = "check")]
    schema: bool,
    /// Check a job file: unknown keys and out-of-range values are refused with the key named.
    #[arg(long, value_name = "JOB.toml")]
    check: Option<PathBuf>,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    match args.check {
        Some(path) => {
            JobConfig::load(&path)?;
            println!("{}: ok", path.display());
        }
        None if args.schema => {
            println!(
                "{}",
                serde_json::to_string_pretty(&crate::config::schema())?
            );
        }
        None => {
            // --dump is the default action.
            let _ = args.dump;
            print!("{}", dump_default());
        }
    }
    Ok(())
}
