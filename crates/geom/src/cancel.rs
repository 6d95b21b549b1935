//! Cooperative cancellation of long work (registration, planning) without a dependency on
//! whoever asks for it: the caller runs the work inside [`run_cancellable`] with a shared flag,
//! and the long loops call [`check`] once per iteration. When the flag is set, `check` returns
//! [`GeomError::Cancelled`] and the work unwinds through its ordinary error path.
//!
//! The flag is held per thread (the thread that runs the work and its sequential loops); work
//! outside any [`run_cancellable`] is never cancelled. Parallel inner loops (rayon) are not
//! checked: each is one bounded step of an outer loop that is. A checked loop handed to another
//! thread (`rayon::join`) takes the flag along: `let cancel = current();` before, and
//! `cancel.run(|| …)` inside. The Python module sets the flag on Ctrl-C so the native worker
//! stops instead of running on to the end.

use std::cell::RefCell;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use crate::error::{GeomError, Result};

thread_local! {
    static FLAG: RefCell<Option<Arc<AtomicBool>>> = const { RefCell::new(None) };
}

/// Restores the previous flag when [`run_cancellable`] returns or unwinds.
struct Restore(Option<Arc<AtomicBool>>);

impl Drop for Restore {
    fn drop(&mut self) {
        let previous = self.0.take();
        FLAG.with(|f| *f.borrow_mut() = previous);
    }
}

/// Runs `work` on this thread with `flag` as its cancel flag: once another thread sets it,
/// every [`check`] inside `work` fails. Nested calls see the innermost flag.
pub fn run_cancellable<T>(flag: Arc<AtomicBool>, work: impl FnOnce() -> T) -> T {
    let previous = FLAG.with(|f| f.borrow_mut().replace(flag));
    let _restore = Restore(previous);
    work()
}

/// The cancel flag of the work running on this thread (none outside [`run_cancellable`]), to
/// hand to another thread.
#[derive(Debug, Clone, Default)]
pub struct CancelFlag(Option<Arc<AtomicBool>>);

/// This thread's [`CancelFlag`].
#[must_use]
pub fn current() -> CancelFlag {
    CancelFlag(FLAG.with(|f| f.borrow().clone()))
}

impl CancelFlag {
    /// Runs `work` on this thread under the flag (none: not cancellable).
    pub fn run<T>(&self, work: impl FnOnce() -> T) -> T {
        let previous = FLAG.with(|f| std::mem::replace(&mut *f.borrow_mut(), self.0.clone()));
        let _restore = Restore(previous);
        work()
    }
}

/// Whether the work running on this thread has been asked to stop.
#[must_use]
pub fn is_cancelled() -> bool {
    FLAG.with(|f| {
        f.borrow()
            .as_ref()
            .is_some_and(|flag| flag.load(Ordering::Relaxed))
    })
}

/// `Err(GeomError::Cancelled)` when the work running on this thread has been asked to stop;
/// long loops call it once per iteration.
pub fn check() -> Result<()> {
    if is_cancelled() {
        Err(GeomError::Cancelled)
    } else {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_fails_only_inside_a_cancelled_scope_and_the_scope_is_restored() {
        assert!(check().is_ok(), "no scope: never cancelled");
        let outer = Arc::new(AtomicBool::new(false));
        let inner = Arc::new(AtomicBool::new(true));
        run_cancellable(outer.clone(), || {
            assert!(check().is_ok());
            run_cancellable(inner, || {
                assert!(matches!(check(), Err(GeomError::Cancelled)));
            });
            assert!(check().is_ok(), "the outer flag is back");
            outer.store(true, Ordering::Relaxed);
            assert!(matches!(check(), Err(GeomError::Cancelled)));
        });
        assert!(check().is_ok(), "restored after the scope");
        // Another thread sets the flag while the work loops.
        let flag = Arc::new(AtomicBool::new(false));
        let setter = {
            let flag = flag.clone();
            std::thread::spawn(move || {
                std::thread::sleep(std::time::Duration::from_millis(20));
                flag.store(true, Ordering::Relaxed);
            })
        };
        let iterations = run_cancellable(flag, || {
            let mut n = 0u64;
            while check().is_ok() {
                n += 1;
                std::thread::yield_now();
            }
            n
        });
        setter.join().unwrap();
        assert!(iterations > 0);
        // The flag handed to another thread.
        let flag = Arc::new(AtomicBool::new(true));
        let seen = run_cancellable(flag, || {
            let cancel = current();
            std::thread::spawn(move || (check().is_ok(), cancel.run(|| check().is_err())))
                .join()
                .unwrap()
        });
        assert_eq!(
            seen,
            (true, true),
            "not set on a new thread until handed over"
        );
    }
}
