//! Exit codes, owned by `main` alone.
//!
//! | code | meaning |
//! |---|---|
//! | 0 | done |
//! | 1 | refused or bad input (nothing was started, or the job refused to start) |
//! | 2 | device fault (the laser acknowledged its emission-off on the way down) |
//! | 3 | interrupted (Ctrl-C, SIGTERM, SIGHUP, SIGQUIT; the laser acknowledged its emission-off; resume with `--resume`) |
//! | 4 | stopped (a fault or an interruption), and the laser's state is unknown: its emission-off was never acknowledged. Switch the laser off at its key. |
//!
//! 2 and 3 are used only when the laser acknowledged its emission-off on the way down; when it
//! did not, 4 replaces either, whatever stopped the run.
//!
//! Commands return `anyhow::Result<()>`. An error that is not a [`Failure`] exits with 1. A
//! command line clap cannot parse is bad input too (1, not clap's own 2, which would read as a
//! device fault); `--help` and `--version` exit with 0 ([`code_for_usage`]).

use std::process::ExitCode;

/// Why a command ended without success.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Exit {
    /// Refused or bad input.
    Refused = 1,
    /// A device fault.
    DeviceFault = 2,
    /// Interrupted by the operator.
    Interrupted = 3,
    /// Stopped, and the laser's emission-off was not acknowledged: its state is unknown.
    LaserStateUnknown = 4,
}

/// An error that carries its exit code.
#[derive(Debug, thiserror::Error)]
#[error("{error:#}")]
pub struct Failure {
    /// The exit code.
    pub exit: Exit,
    /// What happened (printed whole by `Display`, so it is not also the error's `source`).
    pub error: anyhow::Error,
}

impl Failure {
    /// Wraps an error with an exit code.
    pub fn with_exit(exit: Exit, source: impl Into<anyhow::Error>) -> anyhow::Error {
        anyhow::Error::new(Failure {
            exit,
            error: source.into(),
        })
    }
}

/// Logs to stderr; `RUST_LOG` filters (default `info`).
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_writer(std::io::stderr)
        .with_target(false)
        .try_init();
}

/// The exit code of a command line clap did not accept: 0 for `--help`/`--version` (printed on
/// stdout), 1 for a usage error (printed on stderr, with clap's usage hint).
pub fn code_for_usage(e: &clap::Error) -> ExitCode {
    let _ = e.print();
    if e.use_stderr() {
        ExitCode::from(Exit::Refused as u8)
    } else {
        ExitCode::SUCCESS
    }
}

/// The error and its causes on one line, as anyhow's `{:#}` joins them, with a cause left out
/// where the text before it already ends with it: an error whose message shows its source
/// (`#[error("laser profile: {0}")]` over `#[from]`) printed it twice, "… os error 2): No such
/// file or directory (os error 2)".
pub fn one_line(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if out.is_empty() {
            out = text;
        } else if !out.ends_with(&text) {
            out.push_str(": ");
            out.push_str(&text);
        }
    }
    out
}

/// The exit code of a command's result; prints the error as one line on stderr.
pub fn code_for(result: anyhow::Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("trimctl: error: {}", one_line(&e));
            let code = e
                .downcast_ref::<Failure>()
                .map_or(Exit::Refused, |f| f.exit);
            ExitCode::from(code as u8)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An error that shows its source in its own message, as `#[error("…: {0}")]` over
    /// `#[from]` does.
    #[derive(Debug, thiserror::Error)]
    #[error("laser profile: {0}")]
    struct Shows(#[from] std::io::Error);

    #[test]
    fn a_cause_the_message_already_ends_with_is_said_once() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let e = anyhow::Error::from(Shows(io)).context("loading the cell");
        assert_eq!(
            one_line(&e),
            "loading the cell: laser profile: no such file"
        );
        // Causes the text does not end with are all kept, in order.
        let e = anyhow::anyhow!("no such file")
            .context("laser profile")
            .context("loading");
        assert_eq!(one_line(&e), "loading: laser profile: no such file");
    }
}
