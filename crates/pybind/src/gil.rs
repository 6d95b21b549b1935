//! The one helper that runs long work without the GIL and keeps Ctrl-C working.

use std::ffi::CString;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{RecvTimeoutError, channel};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use pyo3::prelude::*;

use crate::errors::{InternalError, TrimWarning};

/// How often the waiting Python thread checks for signals (Ctrl-C).
const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// Runs `work` on a worker thread while the calling thread releases the GIL, so other Python
/// threads run meanwhile. Every [`SIGNAL_POLL`] the caller re-takes the GIL to check signals: a
/// Ctrl-C raises `KeyboardInterrupt` at once and sets the worker's cancel flag
/// (`trim_geom::cancel`), so registration and planning stop at their next iteration instead of
/// running on to the end; the result is dropped. A panic in `work` becomes `InternalError`,
/// never a crash of the interpreter. What `work` warns of on its thread (tracing, WARN and
/// above) is raised as a [`TrimWarning`] through `warnings.warn` once it has returned.
pub fn run_detached<T, F>(py: Python<'_>, work: F) -> PyResult<T>
where
    T: Send + 'static,
    F: FnOnce() -> T + Send + 'static,
{
    let (tx, rx) = channel();
    let cancel = Arc::new(AtomicBool::new(false));
    let flag = cancel.clone();
    std::thread::Builder::new()
        .name("trimctl-worker".into())
        .spawn(move || {
            let warnings = Captured::default();
            let subscriber = tracing_subscriber::fmt()
                .with_max_level(tracing::Level::WARN)
                .without_time()
                .with_level(false)
                .with_target(false)
                .with_ansi(false)
                .with_writer(warnings.clone())
                .finish();
            let result = tracing::subscriber::with_default(subscriber, || {
                std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    trim_geom::cancel::run_cancellable(flag, work)
                }))
            });
            // The receiver is gone only when the caller was interrupted: nothing to tell.
            let _ = tx.send((result, warnings.lines()));
        })
        .map_err(|e| InternalError::new_err(format!("cannot start a worker thread: {e}")))?;
    let mut rx = rx;
    loop {
        // The receiver moves into the GIL-free closure and back (it is Send, not Sync).
        let (received, back) = py.detach(move || (rx.recv_timeout(SIGNAL_POLL), rx));
        rx = back;
        match received {
            Ok((Ok(value), warnings)) => {
                warn(py, &warnings)?;
                return Ok(value);
            }
            Ok((Err(panic), _)) => {
                let message = panic
                    .downcast_ref::<&str>()
                    .map(|s| (*s).to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "unknown panic".into());
                return Err(InternalError::new_err(format!(
                    "internal error (please report): {message}"
                )));
            }
            Err(RecvTimeoutError::Timeout) => {
                if let Err(interrupted) = py.check_signals() {
                    cancel.store(true, Ordering::Relaxed);
                    return Err(interrupted);
                }
            }
            Err(RecvTimeoutError::Disconnected) => {
                return Err(InternalError::new_err(
                    "worker thread ended without a result",
                ));
            }
        }
    }
}

/// The text a worker's tracing wrote, one warning per line.
#[derive(Clone, Default)]
struct Captured(Arc<Mutex<Vec<u8>>>);

impl Captured {
    fn lines(&self) -> Vec<String> {
        let bytes = self.0.lock().unwrap_or_else(|e| e.into_inner());
        String::from_utf8_lossy(&bytes)
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .map(str::to_owned)
            .collect()
    }
}

impl std::io::Write for Captured {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        self.0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .extend_from_slice(bytes);
        Ok(bytes.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl<'a> tracing_subscriber::fmt::MakeWriter<'a> for Captured {
    type Writer = Captured;

    fn make_writer(&'a self) -> Self::Writer {
        self.clone()
    }
}

/// Raises each of `warnings` as a [`TrimWarning`] (an error when the warnings filter says so).
fn warn(py: Python<'_>, warnings: &[String]) -> PyResult<()> {
    let category = py.get_type::<TrimWarning>();
    for w in warnings {
        let text = CString::new(w.replace('\0', " ")).unwrap_or_default();
        PyErr::warn(py, &category, &text, 1)?;
    }
    Ok(())
}
