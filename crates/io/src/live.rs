//! The live view (`trimctl run --live`): the run served over the Foxglove WebSocket protocol
//! while it runs, by the Foxglove SDK's `WebSocketServer` on the context the run record
//! ([`crate::record`]) writes through, so a viewer sees exactly the record's channels.
//!
//! - *Late viewers.* The static scene (clouds, paths, zone frames, the current layer's scene) is
//!   kept as encoded messages; when a viewer subscribes to one of those topics, its messages are
//!   sent to that viewer alone (`on_subscribe` → `log_to_sink` with the viewer's sink id), so a
//!   viewer that connects mid-run still sees the part, and the file and other viewers get no
//!   copies.
//! - *Never in the job's way.* Logging to a viewer is a `try_send` onto the viewer's bounded
//!   queue ([`MESSAGE_BACKLOG`] messages); a full queue drops its oldest message (foxglove
//!   0.30 `websocket/connected_client/send_lossy.rs`), and a viewer whose control queue fills is
//!   disconnected. The server runs on a runtime of its own (one thread), apart from the
//!   executor's, so a slow or vanished viewer costs the run the copy into its queue, nothing
//!   more.
//! - *Channels first.* The record's channels are declared before the server listens
//!   ([`crate::record::declare_run_channels`]): a channel created while a viewer is connected
//!   can have the viewer's subscription refused (an SDK race), one that exists when it connects
//!   cannot.
//! - *Protocol.* The SDK speaks the subprotocols `foxglove.sdk.v1` (inline schemas) and
//!   `foxglove.sdk.v1.1`; a client offering only the older `foxglove.websocket.v1` is refused
//!   at the handshake (HTTP 400).

use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::str::FromStr;
use std::sync::{Arc, Mutex, PoisonError};

use foxglove::bytes::Bytes;
use foxglove::websocket::{ChannelView, Client, ServerListener};
use foxglove::{
    ChannelId, Context, FoxgloveError, PartialMetadata, RawChannel, SinkId, WebSocketServer,
    WebSocketServerHandle,
};

/// Where `--live` listens when given no address.
pub const DEFAULT_LIVE_ADDR: &str = "127.0.0.1:8765";
/// Messages queued per viewer before the oldest is dropped (the SDK's default, named here).
pub const MESSAGE_BACKLOG: usize = 1024;

/// The live view could not start.
#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    /// The address is not `HOST:PORT`.
    #[error("expected HOST:PORT (e.g. {DEFAULT_LIVE_ADDR}), got {given:?}: {reason}")]
    Address {
        /// What was given.
        given: String,
        /// What is wrong with it.
        reason: String,
    },
    /// The server's runtime could not start.
    #[error("cannot start the live view's runtime: {0}")]
    Runtime(std::io::Error),
    /// The record's channels could not be declared.
    #[error("cannot declare the record's channels: {0}")]
    Channels(crate::record::RecordError),
    /// The server could not listen (the port is taken, the host is not this machine's).
    #[error("cannot listen on {addr}: {source}")]
    Listen {
        /// The address.
        addr: LiveAddr,
        /// The SDK's error.
        source: FoxgloveError,
    },
}

/// Where the live view listens: a host name or IP address and a TCP port (0: any free port).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LiveAddr {
    /// Host name or IP address (an IPv6 address without brackets).
    pub host: String,
    /// TCP port.
    pub port: u16,
}

impl FromStr for LiveAddr {
    type Err = LiveError;

    fn from_str(s: &str) -> Result<LiveAddr, LiveError> {
        let bad = |reason: &str| LiveError::Address {
            given: s.to_owned(),
            reason: reason.to_owned(),
        };
        let (host, port) = s.rsplit_once(':').ok_or_else(|| bad("no ':PORT'"))?;
        let host = host
            .strip_prefix('[')
            .and_then(|h| h.strip_suffix(']'))
            .unwrap_or(host);
        if host.is_empty() {
            return Err(bad("no host"));
        }
        if host.contains(':') && !s.starts_with('[') {
            return Err(bad("an IPv6 host goes in brackets: [::1]:8765"));
        }
        if host.chars().any(char::is_whitespace) {
            return Err(bad("the host holds a space"));
        }
        let port = port
            .parse::<u16>()
            .map_err(|_| bad("the port is not a number from 0 to 65535"))?;
        Ok(LiveAddr {
            host: host.to_owned(),
            port,
        })
    }
}

impl fmt::Display for LiveAddr {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.host.contains(':') {
            write!(f, "[{}]:{}", self.host, self.port)
        } else {
            write!(f, "{}:{}", self.host, self.port)
        }
    }
}

/// A topic's kept messages, by key (a later message with the same key replaces the earlier).
struct Kept {
    channel: Arc<RawChannel>,
    messages: BTreeMap<String, (Bytes, u64)>,
}

/// The static scene: encoded messages kept per channel for viewers that subscribe late.
#[derive(Clone, Default)]
pub struct StaticScene(Arc<Mutex<HashMap<ChannelId, Kept>>>);

impl StaticScene {
    /// Keeps `data` (logged at `t_ns` on `channel`) under `key`.
    pub(crate) fn keep(&self, channel: &Arc<RawChannel>, key: &str, data: Bytes, t_ns: u64) {
        let mut kept = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        kept.entry(channel.id())
            .or_insert_with(|| Kept {
                channel: channel.clone(),
                messages: BTreeMap::new(),
            })
            .messages
            .insert(key.to_owned(), (data, t_ns));
    }

    /// The topics that hold kept messages, with how many each.
    #[must_use]
    pub fn topics(&self) -> BTreeMap<String, usize> {
        let kept = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        kept.values()
            .map(|k| (k.channel.topic().to_owned(), k.messages.len()))
            .collect()
    }

    /// Sends the kept messages of `channel` to one sink (a viewer that just subscribed).
    fn replay(&self, channel: ChannelId, sink: Option<SinkId>) {
        // Copied out first: logging takes the viewer's own locks, never under this one.
        let (raw, messages) = {
            let kept = self.0.lock().unwrap_or_else(PoisonError::into_inner);
            let Some(k) = kept.get(&channel) else {
                return;
            };
            (
                k.channel.clone(),
                k.messages.values().cloned().collect::<Vec<_>>(),
            )
        };
        if sink.is_none() {
            return;
        }
        for (data, t_ns) in messages {
            raw.log_with_meta_to_sink(&data, PartialMetadata::with_log_time(t_ns), sink);
        }
    }
}

/// Sends a late subscriber the static scene of the topic it subscribed to.
struct ReplayOnSubscribe(StaticScene);

impl ServerListener for ReplayOnSubscribe {
    fn on_subscribe(&self, client: Client, channel: ChannelView) {
        tracing::debug!(client = ?client.id(), topic = channel.topic(), "live: subscribed");
        self.0.replay(channel.id(), client.sink_id());
    }
}

/// The live view's WebSocket server, with the SDK context the record writes through.
pub struct LiveServer {
    context: Arc<Context>,
    scene: StaticScene,
    addr: LiveAddr,
    handle: Option<WebSocketServerHandle>,
    runtime: Option<tokio::runtime::Runtime>,
}

impl fmt::Debug for LiveServer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LiveServer")
            .field("addr", &self.addr)
            .finish_non_exhaustive()
    }
}

impl LiveServer {
    /// Starts listening on `addr` (port 0: any free port, see [`LiveServer::addr`]), on a
    /// runtime of its own.
    pub fn start(addr: &LiveAddr) -> Result<LiveServer, LiveError> {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("trimctl-live")
            .enable_all()
            .build()
            .map_err(LiveError::Runtime)?;
        let context = Context::new();
        // Before listening: see the function's doc.
        crate::record::declare_run_channels(&context).map_err(LiveError::Channels)?;
        let scene = StaticScene::default();
        let server = WebSocketServer::new()
            .name("trimctl")
            .context(&context)
            .bind(addr.host.clone(), addr.port)
            .message_backlog_size(MESSAGE_BACKLOG)
            .listener(Arc::new(ReplayOnSubscribe(scene.clone())));
        // Started inside the runtime, so the server's tasks run on it.
        let handle = runtime
            .block_on(server.start())
            .map_err(|source| LiveError::Listen {
                addr: addr.clone(),
                source,
            })?;
        let bound = LiveAddr {
            host: addr.host.clone(),
            port: handle.port(),
        };
        Ok(LiveServer {
            context,
            scene,
            addr: bound,
            handle: Some(handle),
            runtime: Some(runtime),
        })
    }

    /// Where it listens (the port the system gave for port 0).
    #[must_use]
    pub fn addr(&self) -> &LiveAddr {
        &self.addr
    }

    /// The WebSocket URL a viewer opens (Foxglove: Open connection → Foxglove WebSocket).
    #[must_use]
    pub fn url(&self) -> String {
        format!("ws://{}", self.addr)
    }

    /// Viewers connected now.
    #[must_use]
    pub fn clients(&self) -> usize {
        self.handle
            .as_ref()
            .map_or(0, WebSocketServerHandle::client_count)
    }

    /// The SDK context the record writes through.
    #[must_use]
    pub fn context(&self) -> &Arc<Context> {
        &self.context
    }

    /// The static scene kept for late subscribers.
    #[must_use]
    pub fn scene(&self) -> &StaticScene {
        &self.scene
    }
}

impl Drop for LiveServer {
    fn drop(&mut self) {
        if let Some(handle) = self.handle.take() {
            // Dropping the shutdown handle aborts the viewers' tasks: nothing waits on them.
            drop(handle.stop());
        }
        if let Some(runtime) = self.runtime.take() {
            runtime.shutdown_background();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_parse_or_say_what_is_wrong() {
        let a: LiveAddr = "127.0.0.1:8765".parse().unwrap();
        assert_eq!((a.host.as_str(), a.port), ("127.0.0.1", 8765));
        let a: LiveAddr = "localhost:0".parse().unwrap();
        assert_eq!((a.host.as_str(), a.port), ("localhost", 0));
        let a: LiveAddr = "[::1]:9000".parse().unwrap();
        assert_eq!((a.host.as_str(), a.port), ("::1", 9000));
        assert_eq!(a.to_string(), "[::1]:9000");
        for (bad, why) in [
            ("8765", "no ':PORT'"),
            (":8765", "no host"),
            ("127.0.0.1:", "not a number"),
            ("127.0.0.1:70000", "not a number"),
            ("::1:8765", "brackets"),
        ] {
            let e = bad.parse::<LiveAddr>().unwrap_err().to_string();
            assert!(e.contains(why) && e.contains(bad), "{bad}: {e}");
        }
    }

    #[test]
    fn the_record_on_a_live_context_keeps_the_static_scene_and_only_used_channels() {
        use crate::record::{Recorder, topic};
        let live = LiveServer::start(&"127.0.0.1:0".parse().unwrap()).unwrap();
        let scan = live.context().get_channel_by_topic(topic::SCAN).unwrap();
        assert_eq!(scan.schema().unwrap().name, "foxglove.PointCloud");
        assert!(
            live.context()
                .get_channel_by_topic("/device/galvo")
                .is_some()
        );

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("run.mcap");
        let mut rec = Recorder::create_live(&path, &live).unwrap();
        let cloud = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]];
        rec.point_cloud(topic::SCAN, 5, &cloud).unwrap();
        rec.point_cloud(topic::SCAN, 6, &cloud[..1]).unwrap();
        rec.log(7, crate::record::LogLevel::Info, "not static")
            .unwrap();
        rec.finish().unwrap();
        // The second cloud replaced the first; the log line is not kept.
        assert_eq!(
            live.scene().topics(),
            BTreeMap::from([("/scan".to_owned(), 1)])
        );

        let bytes = std::fs::read(&path).unwrap();
        let mut topics = BTreeMap::<String, usize>::new();
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            assert!(m.channel.schema.is_some());
            *topics.entry(m.channel.topic.clone()).or_default() += 1;
        }
        let want = BTreeMap::from([("/scan".to_owned(), 2), ("/log".to_owned(), 1)]);
        assert_eq!(
            topics, want,
            "declared channels without messages stay out of the file"
        );
    }

    #[test]
    fn a_taken_port_is_refused_with_the_address() {
        let first = LiveServer::start(&"127.0.0.1:0".parse().unwrap()).unwrap();
        let port = first.addr().port;
        assert_ne!(port, 0);
        let e = LiveServer::start(&format!("127.0.0.1:{port}").parse().unwrap()).unwrap_err();
        assert!(
            matches!(e, LiveError::Listen { .. }) && e.to_string().contains(&port.to_string()),
            "{e}"
        );
    }
}
