//! The one helper that runs long work without the GIL and keeps Ctrl-C working.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{RecvTimeoutError, channel};
use std::time::Duration;

use pyo3::prelude::*;

use crate::errors::InternalError;

/// How often the waiting Python thread checks for signals (Ctrl-C).
const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// Runs `work` on a worker thread while the calling thread releases the GIL, so other Python
/// threads run meanwhile. Every [`SIGNAL_POLL`] the caller re-takes the GIL to check signals: a
/// Ctrl-C raises `KeyboardInterrupt` at once and sets the worker's cancel flag
/// (`trim_geom::cancel`), so registration and planning stop at their next iteration instead of
/// running on to the end; the result is dropped. A panic in `work` becomes `InternalError`,
/// never a crash of the interpreter.
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
            let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                trim_geom::cancel::run_cancellable(flag, work)
            }));
            // The receiver is gone only when the caller was interrupted: nothing to tell.
            let _ = tx.send(result);
        })
        .map_err(|e| InternalError::new_err(format!("cannot start a worker thread: {e}")))?;
    let mut rx = rx;
    loop {
        // The receiver moves into the GIL-free closure and back (it is Send, not Sync).
        let (received, back) = py.detach(move || (rx.recv_timeout(SIGNAL_POLL), rx));
        rx = back;
        match received {
            Ok(Ok(value)) => return Ok(value),
            Ok(Err(panic)) => {
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
