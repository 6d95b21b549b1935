//! The signals that stop a command the way Ctrl-C does: SIGINT, SIGTERM (a service manager,
//! `kill`), SIGHUP (the terminal closed), SIGQUIT (Ctrl-\). Each cancels the command's token, so
//! `run`, `frame` and `sim` take their normal way down (laser off first) whichever arrives.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};
use std::time::Duration;

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
        self,
        cancel: CancellationToken,
        command: &'static str,
        what: &'static str,
    ) {
        tokio::spawn(self.watch(command, what, move |_| cancel.cancel()));
    }

    /// Calls `stop` with the first signal's name, after printing `"\n{command}: {signal}:
    /// {what}"`; then says "already stopping" at every later one, for ever.
    async fn watch(
        mut self,
        command: &'static str,
        what: &'static str,
        stop: impl FnOnce(&'static str),
    ) {
        let name = self.next().await;
        eprintln!("\n{command}: {name}: {what}");
        stop(name);
        loop {
            let again = self.next().await;
            eprintln!("{command}: {again}: already stopping (laser off first)");
        }
    }
}

/// The stop signals of a command that executes more than once in one process: `trimctl run
/// --verify` runs the job, then rescans, inspects and runs each retrim, each execution in a
/// runtime of its own. A handler tied to one execution's runtime would outlive it (tokio keeps
/// a signal's handler for the rest of the process, so the signal no longer ends it) with no one
/// listening: a Ctrl-C during a rescan would be swallowed and the next retrim would fire the
/// laser. So these handlers are installed once, on a thread of their own, for the rest of the
/// process. The first signal cancels [`ProcessStop::token`] (an execution's way down) and sets
/// [`ProcessStop::flag`] (the `trim_geom::cancel` flag that the rescan's waits, its scan
/// command and the inspection check), and no execution starts after it
/// ([`ProcessStop::stopped_by`]).
pub struct ProcessStop {
    token: CancellationToken,
    flag: Arc<AtomicBool>,
    signal: Arc<OnceLock<&'static str>>,
}

static PROCESS_STOP: OnceLock<Result<ProcessStop, String>> = OnceLock::new();

/// How long the signal thread may take to install its handlers.
const INSTALL_TIMEOUT: Duration = Duration::from_secs(5);

impl ProcessStop {
    /// Installs the handlers (the first call; later calls return the same), printing `"\n
    /// {command}: {signal}: {what}"` on stderr at the first signal and "already stopping" at
    /// every later one.
    pub fn install(command: &'static str, what: &'static str) -> anyhow::Result<&'static Self> {
        PROCESS_STOP
            .get_or_init(|| Self::start(command, what))
            .as_ref()
            .map_err(|e| anyhow::anyhow!("{e}"))
    }

    /// The handlers, if installed.
    pub fn installed() -> Option<&'static Self> {
        PROCESS_STOP.get().and_then(|s| s.as_ref().ok())
    }

    fn start(command: &'static str, what: &'static str) -> Result<Self, String> {
        let stop = ProcessStop {
            token: CancellationToken::new(),
            flag: Arc::new(AtomicBool::new(false)),
            signal: Arc::new(OnceLock::new()),
        };
        let (token, flag, signal) = (stop.token.clone(), stop.flag.clone(), stop.signal.clone());
        let (installed, outcome) = std::sync::mpsc::channel::<Result<(), String>>();
        std::thread::Builder::new()
            .name("stop-signals".into())
            .spawn(move || {
                let runtime = match tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build()
                {
                    Ok(r) => r,
                    Err(e) => {
                        let _ = installed.send(Err(format!("starting the signal thread: {e}")));
                        return;
                    }
                };
                runtime.block_on(async move {
                    let signals = match StopSignals::install() {
                        Ok(s) => s,
                        Err(e) => {
                            let _ = installed.send(Err(format!("{e:#}")));
                            return;
                        }
                    };
                    let _ = installed.send(Ok(()));
                    signals
                        .watch(command, what, move |name| {
                            let _ = signal.set(name);
                            flag.store(true, Ordering::SeqCst);
                            token.cancel();
                        })
                        .await;
                });
            })
            .map_err(|e| format!("starting the signal thread: {e}"))?;
        match outcome.recv_timeout(INSTALL_TIMEOUT) {
            Ok(Ok(())) => Ok(stop),
            Ok(Err(e)) => Err(e),
            Err(_) => Err(format!(
                "the stop signals' handlers were not installed within {} s",
                INSTALL_TIMEOUT.as_secs()
            )),
        }
    }

    /// The token an execution stops on (its way down: laser off first).
    #[must_use]
    pub fn token(&self) -> CancellationToken {
        self.token.clone()
    }

    /// The flag `trim_geom::cancel` checks in the work between executions (rescan waits, the
    /// scan command, the inspection).
    #[must_use]
    #[cfg_attr(
        not(feature = "sim"),
        expect(
            dead_code,
            reason = "the verify loop that checks it is built with the simulators"
        )
    )]
    pub fn flag(&self) -> Arc<AtomicBool> {
        self.flag.clone()
    }

    /// The signal that stopped the process, once one has.
    #[must_use]
    pub fn stopped_by(&self) -> Option<&'static str> {
        self.signal.get().copied()
    }
}
