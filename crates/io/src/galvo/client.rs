//! The host side of the galvo protocol: one TCP connection, request/reply with a timeout on every
//! await, resend with the same sequence number, and a heartbeat task.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use futures::{SinkExt, StreamExt};
use tokio::net::TcpStream;
use tokio::sync::Mutex;
use tokio::task::JoinHandle;
use tokio_util::codec::Framed;

use super::protocol::{
    Frame, FrameBlock, FrameCodec, ListCommand, MAX_PAYLOAD_LEN, Request, StatusBlock, StatusCode,
    split_reply, type_name,
};
use crate::tap::{Device, Direction, Tap};

/// Default time to wait for one reply (ms).
pub const REPLY_TIMEOUT_MS: u64 = 500;
/// Default number of resends of a request whose reply did not come.
pub const RESENDS: u32 = 1;
/// Default heartbeat timeout the host asks the controller for (ms).
pub const HEARTBEAT_TIMEOUT_MS: u32 = 250;
/// Default time to connect (ms).
pub const CONNECT_TIMEOUT_MS: u64 = 2000;
/// List commands per `LOAD_LIST` / `APPEND_LIST` frame (a record is at most 17 bytes).
pub const COMMANDS_PER_FRAME: usize = 4096;
const _: () = assert!(COMMANDS_PER_FRAME * 17 + 5 <= MAX_PAYLOAD_LEN);

/// Client settings.
#[derive(Debug, Clone, Copy)]
pub struct GalvoClientConfig {
    /// Time to wait for one reply.
    pub reply_timeout: Duration,
    /// Resends after a reply timeout.
    pub resends: u32,
    /// Heartbeat timeout asked of the controller (ms); the host beats every quarter of it.
    pub heartbeat_timeout_ms: u32,
    /// Time to connect.
    pub connect_timeout: Duration,
    /// Send CRC32 trailers.
    pub crc: bool,
}

impl Default for GalvoClientConfig {
    fn default() -> Self {
        GalvoClientConfig {
            reply_timeout: Duration::from_millis(REPLY_TIMEOUT_MS),
            resends: RESENDS,
            heartbeat_timeout_ms: HEARTBEAT_TIMEOUT_MS,
            connect_timeout: Duration::from_millis(CONNECT_TIMEOUT_MS),
            crc: true,
        }
    }
}

/// A transport failure: the link, not the controller, failed.
#[derive(Debug, Clone, thiserror::Error)]
pub enum GalvoError {
    /// Could not connect.
    #[error("galvo: cannot connect to {addr}: {reason}")]
    Connect {
        /// The address.
        addr: SocketAddr,
        /// Why.
        reason: String,
    },
    /// No reply within the timeout (after the resends).
    #[error("galvo: no reply to {request} within {timeout_ms} ms ({attempts} attempts)")]
    Timeout {
        /// The request name.
        request: &'static str,
        /// The timeout per attempt (ms).
        timeout_ms: u64,
        /// Attempts made.
        attempts: u32,
    },
    /// The connection closed or failed.
    #[error("galvo: link lost during {request}: {reason}")]
    LinkLost {
        /// The request name.
        request: &'static str,
        /// Why.
        reason: String,
    },
    /// The bytes received are not a valid reply.
    #[error("galvo: garbled reply to {request}: {reason}")]
    Garbled {
        /// The request name.
        request: &'static str,
        /// What was wrong.
        reason: String,
    },
}

/// The controller's refusal of a request (a status code other than OK).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("galvo refused {request}: {code:?}: {message}")]
pub struct GalvoFault {
    /// The request name.
    pub request: &'static str,
    /// The status code.
    pub code: StatusCode,
    /// The controller's message.
    pub message: String,
}

/// A device result: transport error outside, the device's refusal inside.
pub type GalvoResult<T> = Result<Result<T, GalvoFault>, GalvoError>;

struct Conn {
    framed: Framed<TcpStream, FrameCodec>,
    next_seq: u32,
    last_tx: Instant,
    broken: Option<String>,
}

/// A connected galvo client. Dropping it stops the heartbeat (the controller then trips).
pub struct GalvoClient {
    conn: Arc<Mutex<Conn>>,
    addr: SocketAddr,
    config: GalvoClientConfig,
    tap: Tap,
    heartbeat: std::sync::Mutex<Option<JoinHandle<()>>>,
}

impl Drop for GalvoClient {
    fn drop(&mut self) {
        let heartbeat = self
            .heartbeat
            .get_mut()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(h) = heartbeat.take() {
            h.abort();
        }
    }
}

/// Opens a TCP connection within the connect timeout.
async fn open_conn(addr: SocketAddr, config: &GalvoClientConfig) -> Result<Conn, GalvoError> {
    let stream = match tokio::time::timeout(config.connect_timeout, TcpStream::connect(addr)).await
    {
        Ok(Ok(s)) => s,
        Ok(Err(e)) => {
            return Err(GalvoError::Connect {
                addr,
                reason: e.to_string(),
            });
        }
        Err(_) => {
            return Err(GalvoError::Connect {
                addr,
                reason: format!("timed out after {} ms", config.connect_timeout.as_millis()),
            });
        }
    };
    let _ = stream.set_nodelay(true);
    Ok(Conn {
        framed: Framed::new(stream, FrameCodec),
        next_seq: 1,
        last_tx: Instant::now(),
        broken: None,
    })
}

impl GalvoClient {
    /// Connects and starts a session (`HELLO`, then the heartbeat task).
    pub async fn connect(
        addr: SocketAddr,
        config: GalvoClientConfig,
        tap: Tap,
    ) -> GalvoResult<GalvoClient> {
        let mut conn = open_conn(addr, &config).await?;
        if let Err(f) = hello(&mut conn, &config, &tap).await? {
            return Ok(Err(f));
        }
        let client = GalvoClient {
            conn: Arc::new(Mutex::new(conn)),
            addr,
            config,
            tap,
            heartbeat: std::sync::Mutex::new(None),
        };
        client.start_heartbeat();
        Ok(Ok(client))
    }

    /// The heartbeat task (none when the heartbeat is off), replacing an earlier one.
    fn start_heartbeat(&self) {
        if self.config.heartbeat_timeout_ms == 0 {
            return;
        }
        let task = tokio::spawn(heartbeat_loop(
            self.conn.clone(),
            self.config,
            self.tap.clone(),
        ));
        let mut slot = self
            .heartbeat
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(old) = slot.replace(task) {
            old.abort();
        }
    }

    /// The way down's session: when the link is marked lost (a missed reply, a garbled frame,
    /// a closed connection), a new connection and `HELLO` replace it, so that the stop path's
    /// `LASER_SIGNALS off`, `STOP` and `STATUS` are still sent. The controller serves one
    /// connection and drops the laser signals when one is replaced or closed (§1, §9 of
    /// docs/protocols/galvo.md), and its status block keeps the interrupted list's tag and
    /// `marks_done`. Returns whether a new session was opened (`false`: the link was not
    /// lost). The link stays marked lost unless the new session's `HELLO` is answered; a
    /// controller that does not answer costs the caller's timeout, nothing more.
    pub async fn reopen_if_lost(&self) -> GalvoResult<bool> {
        if self.conn.lock().await.broken.is_none() {
            return Ok(Ok(false));
        }
        self.tap.record(Device::Galvo, Direction::Command, || {
            format!("reconnect to {} (the link was lost)", self.addr)
        });
        let mut fresh = open_conn(self.addr, &self.config).await?;
        if let Err(f) = hello(&mut fresh, &self.config, &self.tap).await? {
            return Ok(Err(f));
        }
        *self.conn.lock().await = fresh;
        self.start_heartbeat();
        Ok(Ok(true))
    }

    /// Sends one request and returns the reply data.
    pub async fn request(&self, req: Request) -> GalvoResult<Vec<u8>> {
        let mut conn = self.conn.lock().await;
        exchange(&mut conn, &req, &self.config, &self.tap).await
    }

    /// `STATUS`.
    pub async fn status(&self) -> GalvoResult<StatusBlock> {
        Ok(match self.request(Request::Status).await? {
            Ok(data) => Ok(
                StatusBlock::decode(&data).map_err(|reason| GalvoError::Garbled {
                    request: "STATUS",
                    reason,
                })?,
            ),
            Err(f) => Err(f),
        })
    }

    /// Loads a list: `LOAD_LIST` with the first commands, `APPEND_LIST` with the rest.
    pub async fn load_list(&self, list: u8, tag: u32, commands: &[ListCommand]) -> GalvoResult<()> {
        let mut chunks = commands.chunks(COMMANDS_PER_FRAME);
        let first = chunks.next().unwrap_or(&[]);
        if let Err(f) = self
            .request(Request::LoadList {
                list,
                tag,
                commands: first.to_vec(),
            })
            .await?
        {
            return Ok(Err(f));
        }
        for chunk in chunks {
            if let Err(f) = self
                .request(Request::AppendList {
                    list,
                    commands: chunk.to_vec(),
                })
                .await?
            {
                return Ok(Err(f));
            }
        }
        Ok(Ok(()))
    }

    /// `EXECUTE`.
    pub async fn execute(&self, list: u8) -> GalvoResult<()> {
        Ok(self.request(Request::Execute { list }).await?.map(|_| ()))
    }

    /// `STOP`.
    pub async fn stop(&self) -> GalvoResult<()> {
        Ok(self.request(Request::Stop).await?.map(|_| ()))
    }

    /// `LASER_SIGNALS`.
    pub async fn laser_signals(&self, enable: bool) -> GalvoResult<()> {
        Ok(self
            .request(Request::LaserSignals { enable })
            .await?
            .map(|_| ()))
    }

    /// `RESET_ERROR`.
    pub async fn reset_error(&self) -> GalvoResult<()> {
        Ok(self.request(Request::ResetError).await?.map(|_| ()))
    }

    /// `FRAME_STATUS`: the pointer and the trace (§7a).
    pub async fn frame_status(&self) -> GalvoResult<FrameBlock> {
        Ok(match self.request(Request::FrameStatus).await? {
            Ok(data) => Ok(
                FrameBlock::decode(&data).map_err(|reason| GalvoError::Garbled {
                    request: "FRAME_STATUS",
                    reason,
                })?,
            ),
            Err(f) => Err(f),
        })
    }

    /// `EXECUTE_FRAME`: traces list `list` `passes` times (0: until `STOP`) with the gate closed.
    pub async fn execute_frame(&self, list: u8, passes: u32) -> GalvoResult<()> {
        Ok(self
            .request(Request::ExecuteFrame { list, passes })
            .await?
            .map(|_| ()))
    }

    /// `POINTER`: the aiming laser on or off.
    pub async fn pointer(&self, on: bool) -> GalvoResult<()> {
        Ok(self.request(Request::Pointer { on }).await?.map(|_| ()))
    }
}

/// `HELLO` on a connection not yet shared: the session starts.
async fn hello(conn: &mut Conn, config: &GalvoClientConfig, tap: &Tap) -> GalvoResult<Vec<u8>> {
    let req = Request::Hello {
        heartbeat_timeout_ms: config.heartbeat_timeout_ms,
    };
    exchange(conn, &req, config, tap).await
}

async fn heartbeat_loop(conn: Arc<Mutex<Conn>>, config: GalvoClientConfig, tap: Tap) {
    let period = Duration::from_millis(u64::from(config.heartbeat_timeout_ms / 4).max(1));
    loop {
        tokio::time::sleep(period / 2).await;
        let Ok(mut c) = conn.try_lock() else {
            continue; // a request is in flight: that is traffic too
        };
        if c.broken.is_some() {
            return;
        }
        if c.last_tx.elapsed() >= period
            && exchange(&mut c, &Request::Heartbeat, &config, &tap)
                .await
                .is_err()
        {
            return;
        }
    }
}

async fn exchange(
    conn: &mut Conn,
    req: &Request,
    config: &GalvoClientConfig,
    tap: &Tap,
) -> GalvoResult<Vec<u8>> {
    let name = req.name();
    if let Some(reason) = &conn.broken {
        return Err(GalvoError::LinkLost {
            request: name,
            reason: format!("link already lost: {reason}"),
        });
    }
    let sequence = conn.next_seq;
    conn.next_seq = conn.next_seq.wrapping_add(1);
    let frame = Frame {
        crc: config.crc,
        sequence,
        frame_type: req.frame_type(),
        payload: req.encode_payload(),
    };
    let attempts = 1 + config.resends;
    for attempt in 1..=attempts {
        tap.record(Device::Galvo, Direction::Command, || {
            describe_request(req, sequence, attempt)
        });
        let sent =
            tokio::time::timeout(config.reply_timeout, conn.framed.send(frame.clone())).await;
        conn.last_tx = Instant::now();
        match sent {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                return Err(broken(
                    conn,
                    GalvoError::LinkLost {
                        request: name,
                        reason: e.to_string(),
                    },
                ));
            }
            Err(_) => continue,
        }
        let deadline = tokio::time::Instant::now() + config.reply_timeout;
        loop {
            match tokio::time::timeout_at(deadline, conn.framed.next()).await {
                Err(_) => break, // timed out: resend
                Ok(None) => {
                    return Err(broken(
                        conn,
                        GalvoError::LinkLost {
                            request: name,
                            reason: "connection closed by the controller".into(),
                        },
                    ));
                }
                Ok(Some(Err(e))) => {
                    return Err(broken(
                        conn,
                        GalvoError::Garbled {
                            request: name,
                            reason: e.to_string(),
                        },
                    ));
                }
                Ok(Some(Ok(reply))) => {
                    if reply.sequence != sequence {
                        continue; // a late reply to an earlier request
                    }
                    if reply.frame_type != frame.frame_type | super::protocol::REPLY_BIT {
                        return Err(broken(
                            conn,
                            GalvoError::Garbled {
                                request: name,
                                reason: format!(
                                    "reply type {:#06x} ({}) to a {name}",
                                    reply.frame_type,
                                    type_name(reply.frame_type)
                                ),
                            },
                        ));
                    }
                    let (code, rest) =
                        split_reply(&reply.payload).map_err(|reason| GalvoError::Garbled {
                            request: name,
                            reason,
                        })?;
                    tap.record(Device::Galvo, Direction::Reply, || {
                        format!("{name} #{sequence} -> {code:?} ({} bytes)", rest.len())
                    });
                    return Ok(if code == StatusCode::Ok {
                        Ok(rest.to_vec())
                    } else {
                        Err(GalvoFault {
                            request: name,
                            code,
                            message: String::from_utf8_lossy(rest).into_owned(),
                        })
                    });
                }
            }
        }
    }
    Err(broken(
        conn,
        GalvoError::Timeout {
            request: name,
            timeout_ms: u64::try_from(config.reply_timeout.as_millis()).unwrap_or(u64::MAX),
            attempts,
        },
    ))
}

fn broken(conn: &mut Conn, e: GalvoError) -> GalvoError {
    conn.broken = Some(e.to_string());
    e
}

fn describe_request(req: &Request, sequence: u32, attempt: u32) -> String {
    let resend = if attempt > 1 { " (resend)" } else { "" };
    match req {
        Request::LoadList {
            list,
            tag,
            commands,
        } => format!(
            "LOAD_LIST #{sequence}{resend} list={list} tag={tag} commands={}",
            commands.len()
        ),
        Request::AppendList { list, commands } => format!(
            "APPEND_LIST #{sequence}{resend} list={list} commands={}",
            commands.len()
        ),
        other => format!("{other:?} #{sequence}{resend}"),
    }
}
