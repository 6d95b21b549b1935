//! A file written on a thread of its own ([`DiskWriter`]), for the run record: the executor's
//! writes queue and return at once, and a flush waits for the disk at most a timeout, so a hung
//! disk cannot hang the run (the record's chunks and flushes go through it).

use std::io::{Seek, SeekFrom, Write};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, Sender, SyncSender};
use std::time::Duration;

/// Bytes queued and not yet written past which writes fail at once (the disk is not keeping up).
pub const MAX_PENDING_BYTES: usize = 64 << 20;

/// What the disk thread is asked to do, in order.
enum DiskOp {
    Write(Vec<u8>),
    Seek(u64),
    Flush(SyncSender<std::io::Result<()>>),
}

/// Something to write the record to.
pub trait RecordFile: Write + Seek + Send + 'static {}
impl<T: Write + Seek + Send + 'static> RecordFile for T {}

/// A writer whose writes go to a thread of its own. Writes and seeks queue (the position is kept
/// here); [`Write::flush`] waits for the thread at most the flush timeout, then fails with
/// [`std::io::ErrorKind::TimedOut`] and marks the disk hung ([`DiskWriter::hung`]).
pub struct DiskWriter {
    tx: Sender<DiskOp>,
    pos: u64,
    len: u64,
    pending: Arc<AtomicUsize>,
    failed: Arc<std::sync::Mutex<Option<String>>>,
    hung: Arc<AtomicBool>,
    flush_timeout: Duration,
}

/// Whether a [`DiskWriter`]'s flush timed out (shared with the recorder's owner).
#[derive(Debug, Clone, Default)]
pub struct HungFlag(Arc<AtomicBool>);

impl HungFlag {
    /// A flush did not return within its timeout.
    #[must_use]
    pub fn is_hung(&self) -> bool {
        self.0.load(Ordering::SeqCst)
    }
}

impl DiskWriter {
    /// Starts the thread writing to `file`.
    pub fn new(file: impl RecordFile, flush_timeout: Duration) -> std::io::Result<DiskWriter> {
        let (tx, rx) = std::sync::mpsc::channel();
        let pending = Arc::new(AtomicUsize::new(0));
        let failed = Arc::new(std::sync::Mutex::new(None));
        let (p, f) = (pending.clone(), failed.clone());
        std::thread::Builder::new()
            .name("record-disk".into())
            .spawn(move || serve(file, &rx, &p, &f))?;
        Ok(DiskWriter {
            tx,
            pos: 0,
            len: 0,
            pending,
            failed,
            hung: Arc::new(AtomicBool::new(false)),
            flush_timeout,
        })
    }

    /// The flag set when a flush times out.
    #[must_use]
    pub fn hung(&self) -> HungFlag {
        HungFlag(self.hung.clone())
    }

    fn failure(&self) -> Option<std::io::Error> {
        self.failed
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
            .map(std::io::Error::other)
    }

    fn send(&self, op: DiskOp) -> std::io::Result<()> {
        self.tx
            .send(op)
            .map_err(|_| std::io::Error::other("the record's disk thread ended"))
    }
}

fn serve(
    mut file: impl RecordFile,
    rx: &Receiver<DiskOp>,
    pending: &AtomicUsize,
    failed: &std::sync::Mutex<Option<String>>,
) {
    let fail = |e: std::io::Error| {
        failed
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .get_or_insert_with(|| e.to_string());
    };
    while let Ok(op) = rx.recv() {
        match op {
            DiskOp::Write(bytes) => {
                if let Err(e) = file.write_all(&bytes) {
                    fail(e);
                }
                pending.fetch_sub(bytes.len(), Ordering::SeqCst);
            }
            DiskOp::Seek(pos) => {
                if let Err(e) = file.seek(SeekFrom::Start(pos)) {
                    fail(e);
                }
            }
            DiskOp::Flush(answer) => {
                let _ = answer.send(file.flush());
            }
        }
    }
}

impl Write for DiskWriter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if let Some(e) = self.failure() {
            return Err(e);
        }
        let queued = self.pending.load(Ordering::SeqCst);
        if queued + buf.len() > MAX_PENDING_BYTES {
            return Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                format!("the record's disk is not keeping up: {queued} bytes not written yet"),
            ));
        }
        self.pending.fetch_add(buf.len(), Ordering::SeqCst);
        self.send(DiskOp::Write(buf.to_vec()))?;
        self.pos += buf.len() as u64;
        self.len = self.len.max(self.pos);
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        let (tx, rx) = std::sync::mpsc::sync_channel(1);
        self.send(DiskOp::Flush(tx))?;
        match rx.recv_timeout(self.flush_timeout) {
            Ok(result) => result.and_then(|()| self.failure().map_or(Ok(()), Err)),
            Err(_) => {
                self.hung.store(true, Ordering::SeqCst);
                Err(std::io::Error::new(
                    std::io::ErrorKind::TimedOut,
                    format!(
                        "the record's disk did not flush within {} ms",
                        self.flush_timeout.as_millis()
                    ),
                ))
            }
        }
    }
}

impl Seek for DiskWriter {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        let target = match to {
            SeekFrom::Start(p) => Some(p),
            SeekFrom::Current(d) => self.pos.checked_add_signed(d),
            SeekFrom::End(d) => self.len.checked_add_signed(d),
        }
        .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::InvalidInput, "seek before 0"))?;
        if target != self.pos {
            self.send(DiskOp::Seek(target))?;
            self.pos = target;
        }
        Ok(target)
    }
}
