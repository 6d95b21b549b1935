//! The signals that stop a command the way Ctrl-C does: SIGINT, SIGTERM (a service manager,
//! `kill`), SIGHUP (the terminal closed), SIGQUIT (Ctrl-\). Each cancels the command's token, so
//! `run`, `frame` and `sim` take their normal way down (laser off first) whichever arrives.

use tokio::signal::unix::{Signal, SignalKind, signal};
use tokio_util::sync::CancellationToken;

/// The stop signals' handlers, installed: from here on none of them ends the process at once.
pub struct StopSignals {
    int: Signal,
    term: Signal,
    hup: Signal,
    quit: Signal,
}

impl StopSignals {
    /// Installs a handler for each stop signal (inside a tokio runtime).
    pub fn install() -> anyhow::Result<StopSignals> {
        let install = |kind: SignalKind, name: &str| {
            signal(kind).map_err(|e| anyhow::anyhow!("installing the {name} handler: {e}"))
        };
        Ok(StopSignals {
            int: install(SignalKind::interrupt(), "SIGINT")?,
            term: install(SignalKind::terminate(), "SIGTERM")?,
            hup: install(SignalKind::hangup(), "SIGHUP")?,
            quit: install(SignalKind::quit(), "SIGQUIT")?,
        })
    }

    /// Waits for the next stop signal; returns its name.
    pub async fn next(&mut self) -> &'static str {
        tokio::select! {
            _ = self.int.recv() => "SIGINT (Ctrl-C)",
            _ = self.term.recv() => "SIGTERM",
            _ = self.hup.recv() => "SIGHUP",
            _ = self.quit.recv() => "SIGQUIT",
        }
    }

    /// Cancels `cancel` on the first stop signal, after printing `"\n{command}: {signal}:
    /// {what}"` on stderr. The handlers stay installed until the process ends: a second signal
    /// does not cut the way down short.
    pub fn cancel_on_first(
        mut self,
        cancel: CancellationToken,
        command: &'static str,
        what: &'static str,
    ) {
        tokio::spawn(async move {
            let name = self.next().await;
            eprintln!("\n{command}: {name}: {what}");
            cancel.cancel();
            loop {
                let again = self.next().await;
                eprintln!("{command}: {again}: already stopping (laser off first)");
            }
        });
    }
}
