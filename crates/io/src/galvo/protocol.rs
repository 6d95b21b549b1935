//! The galvo telegram protocol (docs/protocols/galvo.md): frames, requests, replies and list
//! commands as pure encode/decode functions, and a tokio-util codec over them. No I/O here.

use bytes::{Buf, BufMut, BytesMut};
use tokio_util::codec::{Decoder, Encoder};

/// The frame magic, "TG".
pub const MAGIC: [u8; 2] = *b"TG";
/// The protocol version this code speaks.
pub const PROTOCOL_VERSION: u8 = 1;
/// Header length in bytes.
pub const HEADER_LEN: usize = 14;
/// Largest payload accepted (bytes).
pub const MAX_PAYLOAD_LEN: usize = 1 << 20;
/// Flag bit: a CRC32 trailer follows the payload.
pub const FLAG_CRC: u8 = 0x01;
/// Reply type bit.
pub const REPLY_BIT: u16 = 0x8000;
/// Number of replies the controller keeps for resends.
pub const REPLY_CACHE_LEN: usize = 64;
/// The list id that means "no list executed yet" in a status block.
pub const NO_LIST: u8 = 255;

/// A whole frame: header fields and payload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    /// Whether a CRC32 trailer is (to be) present.
    pub crc: bool,
    /// The sequence number.
    pub sequence: u32,
    /// The type (request type, or request type | [`REPLY_BIT`]).
    pub frame_type: u16,
    /// The payload bytes.
    pub payload: Vec<u8>,
}

/// Why bytes are not a valid frame or payload.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// The magic is not "TG".
    #[error("bad magic {0:02x?}")]
    BadMagic([u8; 2]),
    /// The version is not [`PROTOCOL_VERSION`].
    #[error("unsupported protocol version {version} (sequence {sequence})")]
    UnsupportedVersion {
        /// The version found.
        version: u8,
        /// The frame's sequence number, so the reply can carry it.
        sequence: u32,
    },
    /// Unknown flag bits are set.
    #[error("unknown flag bits {0:#04x}")]
    BadFlags(u8),
    /// The payload length is over [`MAX_PAYLOAD_LEN`].
    #[error("payload length {0} over the limit")]
    TooLong(usize),
    /// The CRC32 trailer does not match.
    #[error("CRC mismatch: frame says {found:#010x}, bytes give {computed:#010x}")]
    BadCrc {
        /// The trailer value.
        found: u32,
        /// The CRC computed over the frame.
        computed: u32,
    },
    /// The payload does not fit the type.
    #[error("bad payload for type {frame_type:#06x}: {what}")]
    BadPayload {
        /// The frame type.
        frame_type: u16,
        /// What is wrong.
        what: String,
    },
    /// The type is not known.
    #[error("unknown frame type {0:#06x}")]
    UnknownType(u16),
}

/// Encodes a frame into bytes (header, payload, optional CRC).
#[must_use]
pub fn encode_frame(frame: &Frame) -> Vec<u8> {
    let mut out = BytesMut::with_capacity(HEADER_LEN + frame.payload.len() + 4);
    put_frame(frame, &mut out);
    out.to_vec()
}

fn put_frame(frame: &Frame, out: &mut BytesMut) {
    let start = out.len();
    out.put_slice(&MAGIC);
    out.put_u8(PROTOCOL_VERSION);
    out.put_u8(if frame.crc { FLAG_CRC } else { 0 });
    out.put_u32_le(frame.sequence);
    out.put_u16_le(frame.frame_type);
    out.put_u32_le(u32::try_from(frame.payload.len()).unwrap_or(u32::MAX));
    out.put_slice(&frame.payload);
    if frame.crc {
        let crc = crc32fast::hash(&out[start..]);
        out.put_u32_le(crc);
    }
}

/// Decodes one frame from the front of `buf`. `Ok(None)`: more bytes are needed. On success
/// the frame's bytes are consumed.
pub fn decode_frame(buf: &mut BytesMut) -> Result<Option<Frame>, FrameError> {
    if buf.len() < HEADER_LEN {
        return Ok(None);
    }
    let magic = [buf[0], buf[1]];
    if magic != MAGIC {
        return Err(FrameError::BadMagic(magic));
    }
    let version = buf[2];
    let flags = buf[3];
    let sequence = u32::from_le_bytes([buf[4], buf[5], buf[6], buf[7]]);
    if version != PROTOCOL_VERSION {
        return Err(FrameError::UnsupportedVersion { version, sequence });
    }
    if flags & !FLAG_CRC != 0 {
        return Err(FrameError::BadFlags(flags));
    }
    let frame_type = u16::from_le_bytes([buf[8], buf[9]]);
    let length = u32::from_le_bytes([buf[10], buf[11], buf[12], buf[13]]) as usize;
    if length > MAX_PAYLOAD_LEN {
        return Err(FrameError::TooLong(length));
    }
    let crc = flags & FLAG_CRC != 0;
    let total = HEADER_LEN + length + if crc { 4 } else { 0 };
    if buf.len() < total {
        buf.reserve(total - buf.len());
        return Ok(None);
    }
    if crc {
        let at = HEADER_LEN + length;
        let found = u32::from_le_bytes([buf[at], buf[at + 1], buf[at + 2], buf[at + 3]]);
        let computed = crc32fast::hash(&buf[..at]);
        if found != computed {
            return Err(FrameError::BadCrc { found, computed });
        }
    }
    let bytes = buf.split_to(total);
    Ok(Some(Frame {
        crc,
        sequence,
        frame_type,
        payload: bytes[HEADER_LEN..HEADER_LEN + length].to_vec(),
    }))
}

/// The tokio-util codec for frames (both directions).
#[derive(Debug, Default, Clone, Copy)]
pub struct FrameCodec;

impl Decoder for FrameCodec {
    type Item = Frame;
    type Error = std::io::Error;
    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Frame>, std::io::Error> {
        decode_frame(src).map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))
    }
}

impl Encoder<Frame> for FrameCodec {
    type Error = std::io::Error;
    fn encode(&mut self, item: Frame, dst: &mut BytesMut) -> Result<(), std::io::Error> {
        if item.payload.len() > MAX_PAYLOAD_LEN {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                FrameError::TooLong(item.payload.len()),
            ));
        }
        put_frame(&item, dst);
        Ok(())
    }
}

/// Request type codes (control requests, §5).
pub mod types {
    /// `HELLO`.
    pub const HELLO: u16 = 0x0001;
    /// `HEARTBEAT`.
    pub const HEARTBEAT: u16 = 0x0002;
    /// `STATUS`.
    pub const STATUS: u16 = 0x0003;
    /// `FRAME_STATUS`.
    pub const FRAME_STATUS: u16 = 0x0004;
    /// `LOAD_LIST`.
    pub const LOAD_LIST: u16 = 0x0010;
    /// `APPEND_LIST`.
    pub const APPEND_LIST: u16 = 0x0011;
    /// `EXECUTE`.
    pub const EXECUTE: u16 = 0x0012;
    /// `STOP`.
    pub const STOP: u16 = 0x0013;
    /// `EXECUTE_FRAME`.
    pub const EXECUTE_FRAME: u16 = 0x0014;
    /// `LASER_SIGNALS`.
    pub const LASER_SIGNALS: u16 = 0x0020;
    /// `RESET_ERROR`.
    pub const RESET_ERROR: u16 = 0x0021;
    /// `POINTER`.
    pub const POINTER: u16 = 0x0022;
}

/// One list command (§6). Coordinates in bits, speeds in bits/ms, delays in nanoseconds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ListCommand {
    /// Move with the gate closed.
    Jump {
        /// Target x (bits).
        x: i32,
        /// Target y (bits).
        y: i32,
    },
    /// Move with the gate open: one vector.
    Mark {
        /// Target x (bits).
        x: i32,
        /// Target y (bits).
        y: i32,
    },
    /// Jump and mark speeds (bits/ms).
    Speeds {
        /// Jump speed (bits/ms).
        jump_bits_per_ms: f64,
        /// Mark speed (bits/ms).
        mark_bits_per_ms: f64,
    },
    /// Laser on and off delays (ns).
    LaserDelays {
        /// Laser on delay (ns).
        on_ns: u32,
        /// Laser off delay (ns).
        off_ns: u32,
    },
    /// Scanner delays (ns).
    ScannerDelays {
        /// After a jump (ns).
        jump_ns: u32,
        /// After a mark run (ns).
        mark_ns: u32,
        /// At each vertex inside a mark run (ns).
        polygon_ns: u32,
    },
    /// Wait (ns).
    Dwell {
        /// The wait (ns).
        ns: u32,
    },
}

impl ListCommand {
    /// The record's opcode.
    #[must_use]
    pub fn opcode(&self) -> u8 {
        match self {
            ListCommand::Jump { .. } => 0x01,
            ListCommand::Mark { .. } => 0x02,
            ListCommand::Speeds { .. } => 0x03,
            ListCommand::LaserDelays { .. } => 0x04,
            ListCommand::ScannerDelays { .. } => 0x05,
            ListCommand::Dwell { .. } => 0x06,
        }
    }

    fn put(&self, out: &mut Vec<u8>) {
        out.push(self.opcode());
        match *self {
            ListCommand::Jump { x, y } | ListCommand::Mark { x, y } => {
                out.put_i32_le(x);
                out.put_i32_le(y);
            }
            ListCommand::Speeds {
                jump_bits_per_ms,
                mark_bits_per_ms,
            } => {
                out.put_f64_le(jump_bits_per_ms);
                out.put_f64_le(mark_bits_per_ms);
            }
            ListCommand::LaserDelays { on_ns, off_ns } => {
                out.put_u32_le(on_ns);
                out.put_u32_le(off_ns);
            }
            ListCommand::ScannerDelays {
                jump_ns,
                mark_ns,
                polygon_ns,
            } => {
                out.put_u32_le(jump_ns);
                out.put_u32_le(mark_ns);
                out.put_u32_le(polygon_ns);
            }
            ListCommand::Dwell { ns } => out.put_u32_le(ns),
        }
    }
}

/// A request (control requests carry list commands where the spec says so).
#[derive(Debug, Clone, PartialEq)]
pub enum Request {
    /// Start a session; sets the heartbeat timeout (ms, 0 = off).
    Hello {
        /// Heartbeat timeout (ms).
        heartbeat_timeout_ms: u32,
    },
    /// Keep the link alive.
    Heartbeat,
    /// Ask for the status block.
    Status,
    /// Clear a list, tag it and store commands.
    LoadList {
        /// List buffer 0 or 1.
        list: u8,
        /// The host's tag for the list.
        tag: u32,
        /// The commands.
        commands: Vec<ListCommand>,
    },
    /// Append commands to a list.
    AppendList {
        /// List buffer 0 or 1.
        list: u8,
        /// The commands.
        commands: Vec<ListCommand>,
    },
    /// Start a list.
    Execute {
        /// List buffer 0 or 1.
        list: u8,
    },
    /// Stop the running list and drop the laser signals.
    Stop,
    /// Enable or disable the laser signals.
    LaserSignals {
        /// true = enable.
        enable: bool,
    },
    /// Clear the latched error and the watchdog trip.
    ResetError,
    /// Ask for the framing block (§7a).
    FrameStatus,
    /// Trace a list with the pointer: the gate stays closed, nothing is marked (§5a).
    ExecuteFrame {
        /// List buffer 0 or 1.
        list: u8,
        /// Passes over the list (0: until `STOP`).
        passes: u32,
    },
    /// Switch the pointer (aiming laser) on or off.
    Pointer {
        /// true = on.
        on: bool,
    },
}

impl Request {
    /// The request type code.
    #[must_use]
    pub fn frame_type(&self) -> u16 {
        match self {
            Request::Hello { .. } => types::HELLO,
            Request::Heartbeat => types::HEARTBEAT,
            Request::Status => types::STATUS,
            Request::LoadList { .. } => types::LOAD_LIST,
            Request::AppendList { .. } => types::APPEND_LIST,
            Request::Execute { .. } => types::EXECUTE,
            Request::Stop => types::STOP,
            Request::LaserSignals { .. } => types::LASER_SIGNALS,
            Request::ResetError => types::RESET_ERROR,
            Request::FrameStatus => types::FRAME_STATUS,
            Request::ExecuteFrame { .. } => types::EXECUTE_FRAME,
            Request::Pointer { .. } => types::POINTER,
        }
    }

    /// A short name for logs and fault triggers ("LOAD_LIST", ...).
    #[must_use]
    pub fn name(&self) -> &'static str {
        type_name(self.frame_type())
    }

    /// The request payload bytes.
    #[must_use]
    pub fn encode_payload(&self) -> Vec<u8> {
        let mut out = Vec::new();
        match self {
            Request::Hello {
                heartbeat_timeout_ms,
            } => out.put_u32_le(*heartbeat_timeout_ms),
            Request::Heartbeat
            | Request::Status
            | Request::Stop
            | Request::ResetError
            | Request::FrameStatus => {}
            Request::LoadList {
                list,
                tag,
                commands,
            } => {
                out.put_u8(*list);
                out.put_u32_le(*tag);
                for c in commands {
                    c.put(&mut out);
                }
            }
            Request::AppendList { list, commands } => {
                out.put_u8(*list);
                for c in commands {
                    c.put(&mut out);
                }
            }
            Request::Execute { list } => out.put_u8(*list),
            Request::LaserSignals { enable } => out.put_u8(u8::from(*enable)),
            Request::ExecuteFrame { list, passes } => {
                out.put_u8(*list);
                out.put_u32_le(*passes);
            }
            Request::Pointer { on } => out.put_u8(u8::from(*on)),
        }
        out
    }

    /// Decodes a request from a frame type and payload.
    pub fn decode(frame_type: u16, payload: &[u8]) -> Result<Request, FrameError> {
        let bad = |what: &str| FrameError::BadPayload {
            frame_type,
            what: what.to_owned(),
        };
        let mut p = payload;
        let req = match frame_type {
            types::HELLO => {
                need(p, 4).map_err(|()| bad("HELLO needs 4 bytes"))?;
                Request::Hello {
                    heartbeat_timeout_ms: p.get_u32_le(),
                }
            }
            types::HEARTBEAT => Request::Heartbeat,
            types::STATUS => Request::Status,
            types::STOP => Request::Stop,
            types::RESET_ERROR => Request::ResetError,
            types::FRAME_STATUS => Request::FrameStatus,
            types::EXECUTE_FRAME => {
                need(p, 5).map_err(|()| bad("EXECUTE_FRAME needs a list and passes"))?;
                Request::ExecuteFrame {
                    list: p.get_u8(),
                    passes: p.get_u32_le(),
                }
            }
            types::POINTER => {
                need(p, 1).map_err(|()| bad("POINTER needs a flag"))?;
                Request::Pointer {
                    on: p.get_u8() != 0,
                }
            }
            types::LOAD_LIST => {
                need(p, 5).map_err(|()| bad("LOAD_LIST needs list and tag"))?;
                let list = p.get_u8();
                let tag = p.get_u32_le();
                Request::LoadList {
                    list,
                    tag,
                    commands: decode_list_commands(p).map_err(|w| bad(&w))?,
                }
            }
            types::APPEND_LIST => {
                need(p, 1).map_err(|()| bad("APPEND_LIST needs a list"))?;
                let list = p.get_u8();
                Request::AppendList {
                    list,
                    commands: decode_list_commands(p).map_err(|w| bad(&w))?,
                }
            }
            types::EXECUTE => {
                need(p, 1).map_err(|()| bad("EXECUTE needs a list"))?;
                Request::Execute { list: p.get_u8() }
            }
            types::LASER_SIGNALS => {
                need(p, 1).map_err(|()| bad("LASER_SIGNALS needs a flag"))?;
                Request::LaserSignals {
                    enable: p.get_u8() != 0,
                }
            }
            other => return Err(FrameError::UnknownType(other)),
        };
        if !matches!(req, Request::LoadList { .. } | Request::AppendList { .. }) && !p.is_empty() {
            return Err(bad("trailing bytes"));
        }
        Ok(req)
    }
}

/// The name of a request type ("UNKNOWN" for others).
#[must_use]
pub fn type_name(frame_type: u16) -> &'static str {
    match frame_type & !REPLY_BIT {
        types::HELLO => "HELLO",
        types::HEARTBEAT => "HEARTBEAT",
        types::STATUS => "STATUS",
        types::LOAD_LIST => "LOAD_LIST",
        types::APPEND_LIST => "APPEND_LIST",
        types::EXECUTE => "EXECUTE",
        types::STOP => "STOP",
        types::LASER_SIGNALS => "LASER_SIGNALS",
        types::RESET_ERROR => "RESET_ERROR",
        types::FRAME_STATUS => "FRAME_STATUS",
        types::EXECUTE_FRAME => "EXECUTE_FRAME",
        types::POINTER => "POINTER",
        _ => "UNKNOWN",
    }
}

fn need(p: &[u8], n: usize) -> Result<(), ()> {
    if p.len() < n { Err(()) } else { Ok(()) }
}

/// Decodes list-command records until the bytes end.
pub fn decode_list_commands(mut p: &[u8]) -> Result<Vec<ListCommand>, String> {
    let mut out = Vec::new();
    while !p.is_empty() {
        let op = p.get_u8();
        let len = match op {
            0x01 | 0x02 | 0x04 => 8,
            0x03 => 16,
            0x05 => 12,
            0x06 => 4,
            other => {
                return Err(format!(
                    "unknown list opcode {other:#04x} at record {}",
                    out.len()
                ));
            }
        };
        if p.len() < len {
            return Err(format!(
                "list record {} (opcode {op:#04x}) is cut short",
                out.len()
            ));
        }
        out.push(match op {
            0x01 => ListCommand::Jump {
                x: p.get_i32_le(),
                y: p.get_i32_le(),
            },
            0x02 => ListCommand::Mark {
                x: p.get_i32_le(),
                y: p.get_i32_le(),
            },
            0x03 => ListCommand::Speeds {
                jump_bits_per_ms: p.get_f64_le(),
                mark_bits_per_ms: p.get_f64_le(),
            },
            0x04 => ListCommand::LaserDelays {
                on_ns: p.get_u32_le(),
                off_ns: p.get_u32_le(),
            },
            0x05 => ListCommand::ScannerDelays {
                jump_ns: p.get_u32_le(),
                mark_ns: p.get_u32_le(),
                polygon_ns: p.get_u32_le(),
            },
            _ => ListCommand::Dwell { ns: p.get_u32_le() },
        });
    }
    Ok(out)
}

/// A status code in a reply (§8).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum StatusCode {
    /// 0: done.
    Ok,
    /// 1: the frame was bad.
    BadFrame,
    /// 2: the version is not spoken.
    UnsupportedVersion,
    /// 3: no such request type.
    UnknownType,
    /// 4: the payload is wrong for the type.
    BadPayload,
    /// 5: the list is executing, or another list runs.
    ListBusy,
    /// 6: execute of an empty list.
    ListEmpty,
    /// 7: a coordinate is outside the field.
    OutOfField,
    /// 8: execute with the laser signals disabled.
    SignalsOff,
    /// 9: a heartbeat trip is latched.
    Watchdog,
    /// 10: refused by the controller.
    Refused,
    /// Any other code.
    Other(u16),
}

impl StatusCode {
    /// The code on the wire.
    #[must_use]
    pub fn code(self) -> u16 {
        match self {
            StatusCode::Ok => 0,
            StatusCode::BadFrame => 1,
            StatusCode::UnsupportedVersion => 2,
            StatusCode::UnknownType => 3,
            StatusCode::BadPayload => 4,
            StatusCode::ListBusy => 5,
            StatusCode::ListEmpty => 6,
            StatusCode::OutOfField => 7,
            StatusCode::SignalsOff => 8,
            StatusCode::Watchdog => 9,
            StatusCode::Refused => 10,
            StatusCode::Other(c) => c,
        }
    }
    /// The code from the wire.
    #[must_use]
    pub fn from_code(code: u16) -> StatusCode {
        match code {
            0 => StatusCode::Ok,
            1 => StatusCode::BadFrame,
            2 => StatusCode::UnsupportedVersion,
            3 => StatusCode::UnknownType,
            4 => StatusCode::BadPayload,
            5 => StatusCode::ListBusy,
            6 => StatusCode::ListEmpty,
            7 => StatusCode::OutOfField,
            8 => StatusCode::SignalsOff,
            9 => StatusCode::Watchdog,
            10 => StatusCode::Refused,
            c => StatusCode::Other(c),
        }
    }
}

/// Controller state in the status block.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum ControllerState {
    /// 0: no list running.
    Idle,
    /// 1: a list runs.
    Executing,
    /// 2: stopped by the host.
    Stopped,
    /// 3: the heartbeat watchdog tripped.
    WatchdogTrip,
    /// 4: an error is latched.
    Error,
}

impl ControllerState {
    fn code(self) -> u8 {
        match self {
            ControllerState::Idle => 0,
            ControllerState::Executing => 1,
            ControllerState::Stopped => 2,
            ControllerState::WatchdogTrip => 3,
            ControllerState::Error => 4,
        }
    }
    fn from_code(c: u8) -> Option<ControllerState> {
        Some(match c {
            0 => ControllerState::Idle,
            1 => ControllerState::Executing,
            2 => ControllerState::Stopped,
            3 => ControllerState::WatchdogTrip,
            4 => ControllerState::Error,
            _ => return None,
        })
    }
}

/// The status block (§7).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct StatusBlock {
    /// Controller state.
    pub state: ControllerState,
    /// The list executing or last executed ([`NO_LIST`] = none).
    pub list: u8,
    /// That list's tag.
    pub tag: u32,
    /// List commands of that list executed.
    pub commands_done: u32,
    /// Mark vectors of that list completed with the light path open.
    pub marks_done: u32,
    /// Laser signals enabled.
    pub laser_signals: bool,
    /// The gate is open right now.
    pub gate_open: bool,
    /// Modelled time of all lists executed since HELLO (ns).
    pub elapsed_ns: u64,
    /// Commands loaded in list 0 and list 1.
    pub loaded: [u32; 2],
    /// Latched error code (0 = none).
    pub last_error: u16,
}

/// Length of an encoded status block (bytes).
pub const STATUS_BLOCK_LEN: usize = 1 + 1 + 4 + 4 + 4 + 1 + 1 + 8 + 8 + 2;

impl StatusBlock {
    /// Encodes the block.
    #[must_use]
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(STATUS_BLOCK_LEN);
        out.put_u8(self.state.code());
        out.put_u8(self.list);
        out.put_u32_le(self.tag);
        out.put_u32_le(self.commands_done);
        out.put_u32_le(self.marks_done);
        out.put_u8(u8::from(self.laser_signals));
        out.put_u8(u8::from(self.gate_open));
        out.put_u64_le(self.elapsed_ns);
        out.put_u32_le(self.loaded[0]);
        out.put_u32_le(self.loaded[1]);
        out.put_u16_le(self.last_error);
        out
    }
    /// Decodes the block.
    pub fn decode(mut p: &[u8]) -> Result<StatusBlock, String> {
        if p.len() != STATUS_BLOCK_LEN {
            return Err(format!(
                "status block of {} bytes, expected {STATUS_BLOCK_LEN}",
                p.len()
            ));
        }
        let state_code = p.get_u8();
        let state = ControllerState::from_code(state_code)
            .ok_or_else(|| format!("unknown controller state {state_code}"))?;
        Ok(StatusBlock {
            state,
            list: p.get_u8(),
            tag: p.get_u32_le(),
            commands_done: p.get_u32_le(),
            marks_done: p.get_u32_le(),
            laser_signals: p.get_u8() != 0,
            gate_open: p.get_u8() != 0,
            elapsed_ns: p.get_u64_le(),
            loaded: [p.get_u32_le(), p.get_u32_le()],
            last_error: p.get_u16_le(),
        })
    }
}

/// The framing block (§7a, reply to `FRAME_STATUS`): the pointer and the trace.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct FrameBlock {
    /// The pointer (aiming laser) is on.
    pub pointer: bool,
    /// A list is being traced (`EXECUTE_FRAME`) right now.
    pub framing: bool,
    /// The list traced or last traced ([`NO_LIST`] = none yet).
    pub list: u8,
    /// That list's tag.
    pub tag: u32,
    /// Whole passes over that list completed.
    pub passes_done: u32,
    /// `MARK` records of that list traced (all passes; saturates).
    pub vectors_traced: u32,
}

/// Length of an encoded framing block (bytes).
pub const FRAME_BLOCK_LEN: usize = 1 + 1 + 1 + 4 + 4 + 4;

impl FrameBlock {
    /// Encodes the block.
    #[must_use]
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(FRAME_BLOCK_LEN);
        out.put_u8(u8::from(self.pointer));
        out.put_u8(u8::from(self.framing));
        out.put_u8(self.list);
        out.put_u32_le(self.tag);
        out.put_u32_le(self.passes_done);
        out.put_u32_le(self.vectors_traced);
        out
    }
    /// Decodes the block.
    pub fn decode(mut p: &[u8]) -> Result<FrameBlock, String> {
        if p.len() != FRAME_BLOCK_LEN {
            return Err(format!(
                "framing block of {} bytes, expected {FRAME_BLOCK_LEN}",
                p.len()
            ));
        }
        Ok(FrameBlock {
            pointer: p.get_u8() != 0,
            framing: p.get_u8() != 0,
            list: p.get_u8(),
            tag: p.get_u32_le(),
            passes_done: p.get_u32_le(),
            vectors_traced: p.get_u32_le(),
        })
    }
}

/// Builds a reply frame: status code, then data (OK) or a message (not OK).
#[must_use]
pub fn reply_frame(request: &Frame, status: StatusCode, data: &[u8]) -> Frame {
    let mut payload = Vec::with_capacity(2 + data.len());
    payload.put_u16_le(status.code());
    payload.extend_from_slice(data);
    Frame {
        crc: request.crc,
        sequence: request.sequence,
        frame_type: request.frame_type | REPLY_BIT,
        payload,
    }
}

/// Splits a reply payload into its status code and the rest.
pub fn split_reply(payload: &[u8]) -> Result<(StatusCode, &[u8]), String> {
    if payload.len() < 2 {
        return Err("reply shorter than its status code".to_owned());
    }
    Ok((
        StatusCode::from_code(u16::from_le_bytes([payload[0], payload[1]])),
        &payload[2..],
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(req: &Request, seq: u32, crc: bool) -> Frame {
        Frame {
            crc,
            sequence: seq,
            frame_type: req.frame_type(),
            payload: req.encode_payload(),
        }
    }

    #[test]
    fn execute_frame_bytes_are_as_specified() {
        let bytes = encode_frame(&frame(&Request::Execute { list: 1 }, 0x0102_0304, false));
        assert_eq!(
            bytes,
            vec![
                b'T', b'G', 1, 0, 0x04, 0x03, 0x02, 0x01, 0x12, 0x00, 1, 0, 0, 0, 1
            ]
        );
    }

    #[test]
    fn crc_trailer_is_zlib_crc32_of_header_and_payload() {
        let bytes = encode_frame(&frame(&Request::Heartbeat, 7, true));
        assert_eq!(bytes.len(), HEADER_LEN + 4);
        assert_eq!(bytes[3], FLAG_CRC);
        // CRC-32/ISO-HDLC check value of "123456789" is 0xCBF43926: the same function.
        assert_eq!(crc32fast::hash(b"123456789"), 0xCBF4_3926);
        let crc = u32::from_le_bytes([bytes[14], bytes[15], bytes[16], bytes[17]]);
        assert_eq!(crc, crc32fast::hash(&bytes[..14]));
    }

    #[test]
    fn every_request_round_trips_through_bytes() {
        let reqs = vec![
            Request::Hello {
                heartbeat_timeout_ms: 250,
            },
            Request::Heartbeat,
            Request::Status,
            Request::LoadList {
                list: 1,
                tag: 0xDEAD_BEEF,
                commands: vec![
                    ListCommand::Speeds {
                        jump_bits_per_ms: 30_000.0,
                        mark_bits_per_ms: 5_000.5,
                    },
                    ListCommand::LaserDelays {
                        on_ns: 100_000,
                        off_ns: 90_000,
                    },
                    ListCommand::ScannerDelays {
                        jump_ns: 1,
                        mark_ns: 2,
                        polygon_ns: 3,
                    },
                    ListCommand::Jump { x: -5, y: 7 },
                    ListCommand::Mark {
                        x: i32::MAX,
                        y: i32::MIN,
                    },
                    ListCommand::Dwell { ns: 42 },
                ],
            },
            Request::AppendList {
                list: 0,
                commands: vec![ListCommand::Mark { x: 1, y: 2 }],
            },
            Request::Execute { list: 0 },
            Request::Stop,
            Request::LaserSignals { enable: true },
            Request::ResetError,
            Request::FrameStatus,
            Request::ExecuteFrame {
                list: 1,
                passes: 0xFFFF_FFFE,
            },
            Request::Pointer { on: true },
            Request::Pointer { on: false },
        ];
        for (i, req) in reqs.iter().enumerate() {
            for crc in [false, true] {
                let seq = u32::try_from(i).unwrap() * 1000 + 1;
                let mut buf = BytesMut::from(&encode_frame(&frame(req, seq, crc))[..]);
                let got = decode_frame(&mut buf).unwrap().unwrap();
                assert!(buf.is_empty());
                assert_eq!(got.sequence, seq);
                assert_eq!(got.crc, crc);
                assert_eq!(&Request::decode(got.frame_type, &got.payload).unwrap(), req);
            }
        }
    }

    #[test]
    fn partial_frames_wait_for_more_bytes_and_two_frames_split() {
        let a = encode_frame(&frame(&Request::Status, 1, true));
        let b = encode_frame(&frame(&Request::Execute { list: 0 }, 2, false));
        let all: Vec<u8> = a.iter().chain(b.iter()).copied().collect();
        let mut buf = BytesMut::new();
        let mut got = Vec::new();
        let mut codec = FrameCodec;
        for byte in all {
            buf.put_u8(byte);
            while let Some(f) = codec.decode(&mut buf).unwrap() {
                got.push(f.sequence);
            }
        }
        assert_eq!(got, vec![1, 2]);
    }

    #[test]
    fn corrupted_bytes_are_rejected_with_the_reason() {
        let good = encode_frame(&frame(&Request::Execute { list: 0 }, 9, true));
        let mut bad_magic = BytesMut::from(&good[..]);
        bad_magic[0] = b'X';
        assert_eq!(
            decode_frame(&mut bad_magic),
            Err(FrameError::BadMagic([b'X', b'G']))
        );
        let mut bad_version = BytesMut::from(&good[..]);
        bad_version[2] = 2;
        assert_eq!(
            decode_frame(&mut bad_version),
            Err(FrameError::UnsupportedVersion {
                version: 2,
                sequence: 9
            })
        );
        let mut bad_crc = BytesMut::from(&good[..]);
        bad_crc[14] ^= 0xFF; // the payload byte
        assert!(matches!(
            decode_frame(&mut bad_crc),
            Err(FrameError::BadCrc { .. })
        ));
        let mut too_long = BytesMut::from(&good[..]);
        too_long[10..14]
            .copy_from_slice(&(u32::try_from(MAX_PAYLOAD_LEN).unwrap() + 1).to_le_bytes());
        assert!(matches!(
            decode_frame(&mut too_long),
            Err(FrameError::TooLong(_))
        ));
        let mut flags = BytesMut::from(&good[..]);
        flags[3] = 0x81;
        assert_eq!(decode_frame(&mut flags), Err(FrameError::BadFlags(0x81)));
    }

    #[test]
    fn bad_payloads_name_the_problem() {
        assert!(matches!(
            Request::decode(types::LOAD_LIST, &[0, 1, 0, 0, 0, 0x7F]),
            Err(FrameError::BadPayload { .. })
        ));
        assert!(matches!(
            Request::decode(types::LOAD_LIST, &[0, 1, 0, 0, 0, 0x02, 1, 2]),
            Err(FrameError::BadPayload { .. })
        ));
        assert_eq!(
            Request::decode(0x0999, &[]),
            Err(FrameError::UnknownType(0x0999))
        );
        assert!(Request::decode(types::EXECUTE, &[0, 0]).is_err());
    }

    #[test]
    fn status_block_and_replies_round_trip() {
        let s = StatusBlock {
            state: ControllerState::WatchdogTrip,
            list: 1,
            tag: 65_538,
            commands_done: 17,
            marks_done: 12,
            laser_signals: false,
            gate_open: false,
            elapsed_ns: 123_456_789_012,
            loaded: [0, 40],
            last_error: 9,
        };
        let bytes = s.encode();
        assert_eq!(bytes.len(), STATUS_BLOCK_LEN);
        assert_eq!(StatusBlock::decode(&bytes).unwrap(), s);
        assert!(StatusBlock::decode(&bytes[1..]).is_err());
        let req = frame(&Request::Status, 5, false);
        let rep = reply_frame(&req, StatusCode::Ok, &bytes);
        assert_eq!(rep.frame_type, types::STATUS | REPLY_BIT);
        let (code, rest) = split_reply(&rep.payload).unwrap();
        assert_eq!(code, StatusCode::Ok);
        assert_eq!(StatusBlock::decode(rest).unwrap(), s);
        for c in 0..12 {
            assert_eq!(StatusCode::from_code(c).code(), c);
        }
    }

    #[test]
    fn framing_requests_and_block_have_the_documented_bytes() {
        let bytes = encode_frame(&frame(
            &Request::ExecuteFrame { list: 1, passes: 3 },
            2,
            false,
        ));
        assert_eq!(
            bytes,
            vec![
                b'T', b'G', 1, 0, 2, 0, 0, 0, 0x14, 0x00, 5, 0, 0, 0, 1, 3, 0, 0, 0
            ]
        );
        let bytes = encode_frame(&frame(&Request::Pointer { on: true }, 3, false));
        assert_eq!(&bytes[8..], &[0x22, 0x00, 1, 0, 0, 0, 1]);
        assert_eq!(type_name(types::POINTER | REPLY_BIT), "POINTER");
        assert!(Request::decode(types::EXECUTE_FRAME, &[0, 1, 0, 0]).is_err());
        assert!(Request::decode(types::POINTER, &[1, 0]).is_err());
        let b = FrameBlock {
            pointer: true,
            framing: false,
            list: 0,
            tag: 0xF000_0102,
            passes_done: 7,
            vectors_traced: 56,
        };
        let enc = b.encode();
        assert_eq!(enc.len(), FRAME_BLOCK_LEN);
        assert_eq!(&enc[..3], &[1, 0, 0]);
        assert_eq!(FrameBlock::decode(&enc).unwrap(), b);
        assert!(FrameBlock::decode(&enc[1..]).is_err());
    }
}
