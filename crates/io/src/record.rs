//! The run record: an MCAP file written by the Foxglove SDK's `McapWriter`, with Foxglove's own
//! schemas (protobuf: `foxglove.PointCloud`, `foxglove.SceneUpdate`, `foxglove.FrameTransform`,
//! `foxglove.Log`) and trimctl's own JSON channels (schemas generated from the Rust types), one
//! per device with every command and reply. Chunked, uncompressed, and flushed at every finished
//! layer, so a crash leaves the file readable up to the last finished chunk.
//!
//! Every message goes through one SDK [`Context`]: with a [`LiveServer`] (`trimctl run --live`)
//! the same messages reach the viewers connected to it, and the static scene (clouds, paths,
//! zone frames, the current layer) is kept to be sent again to each viewer that subscribes late.
//!
//! Topics: `/scan` and `/cad` (foxglove.PointCloud), `/path/template` and `/path/registered` in
//! a run (`/template`, `/registered` in the example; foxglove.SceneUpdate with line strips),
//! `/tf` (foxglove.FrameTransform per zone frame), `/layer` (trimctl.Layer: the current layer
//! and its state), `/layer/scene` (foxglove.SceneUpdate: the current layer's polylines and a
//! plate at its focal plane, highlighted while it is marked), `/progress` (trimctl.Progress),
//! `/log` (foxglove.Log), `/device/galvo`, `/device/laser`, `/device/cnc` (trimctl.DeviceIo),
//! and run summaries (`/calibration`, `/twin/spot_error`).

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use foxglove::bytes::Bytes;
use foxglove::messages::{
    Color, CubePrimitive, FrameTransform, KeyValuePair, LinePrimitive, Log, PackedElementField,
    PointCloud, Pose, Quaternion, SceneEntity, SceneUpdate, TextPrimitive, Timestamp, Vector3,
};
use foxglove::{
    ChannelBuilder, Context, Encode, FoxgloveError, McapCompression, McapWriteOptions, McapWriter,
    McapWriterHandle, PartialMetadata, RawChannel, Schema,
};
use schemars::JsonSchema;
use serde::Serialize;
use trim_cell::job::{Job, LayerKey};

use crate::live::{LiveServer, StaticScene};
use crate::tap::{Device, DeviceIo, Tap};

/// Target uncompressed chunk size (bytes); chunks are also closed at every [`Recorder::flush`].
pub const CHUNK_BYTES: u64 = 256 * 1024;
/// The frame everything in the work-piece frame is published in.
pub const WORKPIECE_FRAME: &str = "workpiece";
/// The topics of a run's record.
pub mod topic {
    /// The scan (foxglove.PointCloud).
    pub const SCAN: &str = "/scan";
    /// The CAD points in the scan's frame (foxglove.PointCloud).
    pub const CAD: &str = "/cad";
    /// The template path in the scan's frame (foxglove.SceneUpdate).
    pub const TEMPLATE: &str = "/path/template";
    /// The registered path (foxglove.SceneUpdate).
    pub const REGISTERED: &str = "/path/registered";
    /// The zone frames (foxglove.FrameTransform).
    pub const TF: &str = "/tf";
    /// The current layer and its state (trimctl.Layer).
    pub const LAYER: &str = "/layer";
    /// The current layer's scene: polylines and focal plate (foxglove.SceneUpdate).
    pub const LAYER_SCENE: &str = "/layer/scene";
    /// How far the run is (trimctl.Progress).
    pub const PROGRESS: &str = "/progress";
    /// Log lines (foxglove.Log).
    pub const LOG: &str = "/log";
    /// The calibration, lens and scan pose the run used (trimctl.Calibration, JSON object).
    pub const CALIBRATION: &str = "/calibration";
    /// The twin's spot errors (trimctl.SpotError, JSON object).
    pub const SPOT_ERROR: &str = "/twin/spot_error";
    /// How a stopped run's way down went: each step acknowledged or not, every emission-off
    /// attempt (trimctl.Shutdown, JSON object: the executor's `ShutdownReport` with the stop's
    /// cause, layer and phase).
    pub const SHUTDOWN: &str = "/shutdown";
    /// Schema name of [`SHUTDOWN`].
    pub const SHUTDOWN_SCHEMA: &str = "trimctl.Shutdown";
    /// Schema name of [`CALIBRATION`].
    pub const CALIBRATION_SCHEMA: &str = "trimctl.Calibration";
    /// Schema name of [`SPOT_ERROR`].
    pub const SPOT_ERROR_SCHEMA: &str = "trimctl.SpotError";

    /// A device's topic: `/device/<name>` (trimctl.DeviceIo).
    #[must_use]
    pub fn device(device: crate::tap::Device) -> String {
        format!("/device/{}", device.name())
    }
}
/// How long a flush of the record may take before its disk counts as hung (ms): the executor
/// then takes the way down. Writes never wait for the disk (they queue: [`crate::disk`]).
pub const FLUSH_TIMEOUT_MS: u64 = 5000;
/// The id of the current layer's scene entity.
pub const LAYER_ENTITY: &str = "current_layer";
/// Colour of the layer being marked (RGBA).
const MARKING_RGBA: [f64; 4] = [1.0, 0.85, 0.0, 1.0];
/// Colour of a layer once marked (RGBA).
const DONE_RGBA: [f64; 4] = [0.2, 0.8, 0.3, 1.0];
/// Colour of a layer cut short (RGBA).
const CUT_RGBA: [f64; 4] = [0.9, 0.1, 0.1, 1.0];
/// Opacity of the focal plate under the current layer.
const PLATE_ALPHA: f64 = 0.25;
/// Margin of the focal plate around the layer's polylines (mm).
const PLATE_MARGIN_MM: f64 = 0.5;
/// Line width of the current layer's polylines (screen pixels, scale invariant).
const LAYER_LINE_PX: f64 = 3.0;
/// Line width of the template and registered paths (mm).
const PATH_LINE_MM: f64 = 0.2;

/// foxglove.Log levels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LogLevel {
    /// 1.
    Debug = 1,
    /// 2.
    Info = 2,
    /// 3.
    Warning = 3,
    /// 4.
    Error = 4,
}

/// Writing the record failed.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The file could not be created.
    #[error("record {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// The Foxglove SDK (its MCAP writer, or a channel) failed.
    #[error("record: {0}")]
    Sdk(#[from] FoxgloveError),
    /// A message could not be encoded.
    #[error("record: {topic}: cannot encode the message: {message}")]
    Encode {
        /// The topic.
        topic: String,
        /// What went wrong.
        message: String,
    },
    /// A message came after [`Recorder::finish`].
    #[error("record: the file is finished")]
    Finished,
}

/// trimctl.Layer: the current layer and its state.
#[derive(Debug, Clone, Serialize, JsonSchema)]
#[schemars(title = "trimctl.Layer")]
pub struct LayerMessage {
    /// Zone id.
    pub zone: usize,
    /// Layer index within the zone.
    pub layer: usize,
    /// "started", "done", "cut" or "skipped".
    pub state: String,
    /// Vectors of the layer marked so far.
    pub vectors_done: u32,
    /// Vectors in the layer.
    pub vectors: u32,
    /// The machine pose (axis name → value, mm or degrees).
    pub pose: Option<BTreeMap<String, f64>>,
    /// The layer's focus point (mm, work-piece frame).
    pub focus_point: Option<[f64; 3]>,
}

/// trimctl.Progress: how far the run is.
#[derive(Debug, Clone, Default, PartialEq, Serialize, JsonSchema)]
#[schemars(title = "trimctl.Progress")]
pub struct ProgressMessage {
    /// Layers finished (in this run and, on a resume, before it).
    pub layers_done: u64,
    /// Layers in the job.
    pub layers_total: u64,
    /// Vectors marked (finished layers' and the running layer's).
    pub vectors_done: u64,
    /// Vectors in the job.
    pub vectors_total: u64,
    /// `vectors_done / vectors_total` (0 for a job without vectors).
    pub fraction: f64,
    /// The running layer's zone, if one is running.
    pub zone: Option<usize>,
    /// The running layer's index, if one is running.
    pub layer: Option<usize>,
    /// The running layer's phase (the executor's `Phase`, e.g. "WaitDone").
    pub phase: Option<String>,
}

/// A serde type sent as JSON under the JSON schema schemars derives for it; its schema name is
/// the schema's title (`trimctl.Layer`, ...).
struct Json<'a, T>(&'a T);

impl<T: Serialize + JsonSchema> Encode for Json<'_, T> {
    type Error = serde_json::Error;

    fn get_schema() -> Option<Schema> {
        let schema = schemars::schema_for!(T);
        let name = schema
            .get("title")
            .and_then(serde_json::Value::as_str)
            .map_or_else(|| T::schema_name().into_owned(), str::to_owned);
        Some(Schema::new(
            name,
            "jsonschema",
            serde_json::to_vec(&schema).ok()?,
        ))
    }

    fn get_message_encoding() -> String {
        "json".to_owned()
    }

    fn encode(&self, buf: &mut impl foxglove::bytes::BufMut) -> Result<(), Self::Error> {
        serde_json::to_writer(foxglove::bytes::BufMut::writer(buf), self.0)
    }
}

/// Whether a message is part of the static scene a late viewer is sent, and under which key
/// (a later message with the same key replaces it).
enum Latch<'a> {
    /// Sent once, to whoever is subscribed.
    No,
    /// Kept for late subscribers under this key.
    Keep(&'a str),
}

/// The MCAP writer with its channels.
pub struct Recorder {
    context: Arc<Context>,
    writer: Option<McapWriterHandle<crate::disk::DiskWriter>>,
    disk_hung: crate::disk::HungFlag,
    channels: HashMap<String, Arc<RawChannel>>,
    scene: StaticScene,
    messages: u64,
    per_topic: BTreeMap<String, u64>,
    encode_buf: Vec<u8>,
}

/// A recorder shared between the executor and the device taps.
pub type SharedRecorder = Arc<Mutex<Recorder>>;

fn stamp(t_ns: u64) -> Option<Timestamp> {
    // A u32 of seconds reaches 2106; a time past it is stamped then.
    let sec = u32::try_from(t_ns / 1_000_000_000).unwrap_or(u32::MAX);
    Some(Timestamp::new(sec, (t_ns % 1_000_000_000) as u32))
}

fn identity_pose() -> Option<Pose> {
    Some(Pose {
        position: Some(Vector3::default()),
        orientation: Some(Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }),
    })
}

fn color(rgba: [f64; 4]) -> Option<Color> {
    Some(Color {
        r: rgba[0],
        g: rgba[1],
        b: rgba[2],
        a: rgba[3],
    })
}

fn point3(p: [f64; 3]) -> foxglove::messages::Point3 {
    foxglove::messages::Point3 {
        x: p[0],
        y: p[1],
        z: p[2],
    }
}

impl Recorder {
    /// Creates the file, on a context of its own (nothing is served live).
    pub fn create(path: &Path) -> Result<Recorder, RecordError> {
        Recorder::create_in(path, Context::new(), StaticScene::default())
    }

    /// Creates the file on the live server's context: every message also reaches the viewers
    /// subscribed to its topic, and the static scene is kept for late subscribers.
    pub fn create_live(path: &Path, live: &LiveServer) -> Result<Recorder, RecordError> {
        Recorder::create_in(path, live.context().clone(), live.scene().clone())
    }

    fn create_in(
        path: &Path,
        context: Arc<Context>,
        scene: StaticScene,
    ) -> Result<Recorder, RecordError> {
        let file = File::create(path).map_err(|source| RecordError::Io {
            path: path.to_owned(),
            source,
        })?;
        Recorder::create_on_in(BufWriter::new(file), path, context, scene)
    }

    /// Records to `file` (tests: a disk that hangs); `path` names it in errors.
    pub fn create_on(
        file: impl crate::disk::RecordFile,
        path: &Path,
    ) -> Result<Recorder, RecordError> {
        Recorder::create_on_in(file, path, Context::new(), StaticScene::default())
    }

    fn create_on_in(
        file: impl crate::disk::RecordFile,
        path: &Path,
        context: Arc<Context>,
        scene: StaticScene,
    ) -> Result<Recorder, RecordError> {
        let disk =
            crate::disk::DiskWriter::new(file, std::time::Duration::from_millis(FLUSH_TIMEOUT_MS))
                .map_err(|source| RecordError::Io {
                    path: path.to_owned(),
                    source,
                })?;
        let disk_hung = disk.hung();
        let options = McapWriteOptions::new()
            .compression(None::<McapCompression>)
            .chunk_size(Some(CHUNK_BYTES))
            .profile("");
        let writer = McapWriter::with_options(options)
            .context(&context)
            .create(disk)?;
        Ok(Recorder {
            context,
            writer: Some(writer),
            disk_hung,
            channels: HashMap::new(),
            scene,
            messages: 0,
            per_topic: BTreeMap::new(),
            encode_buf: Vec::new(),
        })
    }

    /// Wraps it for sharing.
    #[must_use]
    pub fn shared(self) -> SharedRecorder {
        Arc::new(Mutex::new(self))
    }

    fn channel(
        &mut self,
        topic: &str,
        schema: Option<Schema>,
        encoding: String,
    ) -> Result<Arc<RawChannel>, RecordError> {
        if let Some(c) = self.channels.get(topic) {
            return Ok(c.clone());
        }
        // A channel declared before the live view listened ([`declare_run_channels`]) is used
        // as it was declared.
        let channel = match self.context.get_channel_by_topic(topic) {
            Some(c) => c,
            None => build_channel(&self.context, topic, schema, encoding)?,
        };
        self.channels.insert(topic.to_owned(), channel.clone());
        Ok(channel)
    }

    fn write<M: Encode>(
        &mut self,
        topic: &str,
        t_ns: u64,
        msg: &M,
        latch: Latch<'_>,
    ) -> Result<(), RecordError> {
        self.encode_buf.clear();
        msg.encode(&mut self.encode_buf)
            .map_err(|e| RecordError::Encode {
                topic: topic.to_owned(),
                message: e.to_string(),
            })?;
        let data = std::mem::take(&mut self.encode_buf);
        let res = self.write_bytes(
            topic,
            M::get_schema(),
            M::get_message_encoding(),
            t_ns,
            &data,
            latch,
        );
        self.encode_buf = data;
        res
    }

    fn write_bytes(
        &mut self,
        topic: &str,
        schema: Option<Schema>,
        encoding: String,
        t_ns: u64,
        data: &[u8],
        latch: Latch<'_>,
    ) -> Result<(), RecordError> {
        if self.writer.is_none() {
            return Err(RecordError::Finished);
        }
        let channel = self.channel(topic, schema, encoding)?;
        // To the MCAP file and every viewer subscribed to the topic: neither waits on a viewer
        // (a viewer's queue drops its oldest message when full, see crate::live).
        channel.log_with_meta(data, PartialMetadata::with_log_time(t_ns));
        if let Latch::Keep(key) = latch {
            self.scene
                .keep(&channel, key, Bytes::copy_from_slice(data), t_ns);
        }
        self.messages += 1;
        *self.per_topic.entry(topic.to_owned()).or_default() += 1;
        Ok(())
    }

    /// Messages written so far.
    #[must_use]
    pub fn messages(&self) -> u64 {
        self.messages
    }

    /// Messages written so far, per topic.
    #[must_use]
    pub fn messages_per_topic(&self) -> BTreeMap<String, u64> {
        self.per_topic.clone()
    }

    /// A point cloud (mm) in the work-piece frame as foxglove.PointCloud (float64 x, y, z);
    /// part of the static scene.
    pub fn point_cloud(
        &mut self,
        topic: &str,
        t_ns: u64,
        points_mm: &[[f64; 3]],
    ) -> Result<(), RecordError> {
        let mut data = Vec::with_capacity(points_mm.len() * 24);
        for p in points_mm {
            for v in p {
                data.extend_from_slice(&v.to_le_bytes());
            }
        }
        let field = |name: &str, offset: u32| PackedElementField {
            name: name.to_owned(),
            offset,
            r#type: foxglove::messages::packed_element_field::NumericType::Float64 as i32,
        };
        let msg = PointCloud {
            timestamp: stamp(t_ns),
            frame_id: WORKPIECE_FRAME.to_owned(),
            pose: identity_pose(),
            point_stride: 24,
            fields: vec![field("x", 0), field("y", 8), field("z", 16)],
            data: Bytes::from(data),
        };
        self.write(topic, t_ns, &msg, Latch::Keep(topic))
    }

    /// Paths (mm, work-piece frame) as foxglove.SceneUpdate line strips, one entity per
    /// contour; part of the static scene.
    pub fn paths(
        &mut self,
        topic: &str,
        t_ns: u64,
        contours: &[(i64, Vec<[f64; 3]>)],
        rgba: [f64; 4],
    ) -> Result<(), RecordError> {
        let entities = contours
            .iter()
            .map(|(id, pts)| SceneEntity {
                timestamp: stamp(t_ns),
                frame_id: WORKPIECE_FRAME.to_owned(),
                id: format!("{topic}/{id}"),
                frame_locked: true,
                metadata: vec![KeyValuePair {
                    key: "contour".to_owned(),
                    value: id.to_string(),
                }],
                lines: vec![LinePrimitive {
                    r#type: foxglove::messages::line_primitive::Type::LineStrip as i32,
                    pose: identity_pose(),
                    thickness: PATH_LINE_MM,
                    scale_invariant: false,
                    points: pts.iter().copied().map(point3).collect(),
                    color: color(rgba),
                    ..LinePrimitive::default()
                }],
                ..SceneEntity::default()
            })
            .collect();
        let msg = SceneUpdate {
            deletions: Vec::new(),
            entities,
        };
        self.write(topic, t_ns, &msg, Latch::Keep(topic))
    }

    /// Every zone frame of the job as foxglove.FrameTransform (`workpiece` → `zone_<id>`), one
    /// message per zone; part of the static scene.
    pub fn zone_frames(&mut self, t_ns: u64, job: &Job) -> Result<(), RecordError> {
        for z in &job.zones {
            let q = quaternion_from_axes(z.frame.x, z.frame.y, z.frame.z);
            let child = format!("zone_{}", z.id);
            let msg = FrameTransform {
                timestamp: stamp(t_ns),
                parent_frame_id: WORKPIECE_FRAME.to_owned(),
                child_frame_id: child.clone(),
                translation: Some(Vector3 {
                    x: z.origin[0],
                    y: z.origin[1],
                    z: z.origin[2],
                }),
                rotation: Some(Quaternion {
                    x: q[0],
                    y: q[1],
                    z: q[2],
                    w: q[3],
                }),
            };
            self.write(topic::TF, t_ns, &msg, Latch::Keep(&child))?;
        }
        Ok(())
    }

    /// The current layer and its state ("started", "done", "cut", "skipped") on `/layer`, and
    /// its scene on [`topic::LAYER_SCENE`]: the layer's polylines and a plate at its focal plane,
    /// yellow while it is marked, green once done, red when cut short.
    pub fn layer(
        &mut self,
        t_ns: u64,
        key: LayerKey,
        state: &str,
        vectors_done: u32,
        vectors: u32,
        job: &Job,
    ) -> Result<(), RecordError> {
        let zone = job.zones.iter().find(|z| z.id == key.zone);
        let layer = zone.and_then(|z| z.layers.iter().find(|l| l.index == key.layer));
        let msg = LayerMessage {
            zone: key.zone,
            layer: key.layer,
            state: state.to_owned(),
            vectors_done,
            vectors,
            pose: layer.map(|l| l.pose.0.clone()),
            focus_point: layer.map(|l| l.focus_point),
        };
        self.write(topic::LAYER, t_ns, &Json(&msg), Latch::No)?;
        let rgba = match state {
            "started" => MARKING_RGBA,
            "done" => DONE_RGBA,
            "cut" => CUT_RGBA,
            _ => return Ok(()),
        };
        if let (Some(zone), Some(layer)) = (zone, layer) {
            let entity = layer_entity(t_ns, job, zone, layer, state, rgba);
            let msg = SceneUpdate {
                deletions: Vec::new(),
                entities: vec![entity],
            };
            self.write(topic::LAYER_SCENE, t_ns, &msg, Latch::Keep(LAYER_ENTITY))?;
        }
        Ok(())
    }

    /// How far the run is, on `/progress`.
    pub fn progress(&mut self, t_ns: u64, progress: &ProgressMessage) -> Result<(), RecordError> {
        self.write(topic::PROGRESS, t_ns, &Json(progress), Latch::No)
    }

    /// A log line as foxglove.Log.
    pub fn log(&mut self, t_ns: u64, level: LogLevel, message: &str) -> Result<(), RecordError> {
        let msg = Log {
            timestamp: stamp(t_ns),
            level: level as i32,
            message: message.to_owned(),
            name: "trimctl".to_owned(),
            file: String::new(),
            line: 0,
        };
        self.write(topic::LOG, t_ns, &msg, Latch::No)
    }

    /// Any JSON object on `topic` under a schema named `schema_name` that only says it is an
    /// object (run summaries such as `/calibration` and `/twin/spot_error`).
    pub fn json(
        &mut self,
        topic: &str,
        schema_name: &'static str,
        t_ns: u64,
        msg: &serde_json::Value,
    ) -> Result<(), RecordError> {
        let data = serde_json::to_vec(msg).map_err(|e| RecordError::Encode {
            topic: topic.to_owned(),
            message: e.to_string(),
        })?;
        self.write_bytes(
            topic,
            Some(object_schema(schema_name)),
            "json".to_owned(),
            t_ns,
            &data,
            Latch::No,
        )
    }

    /// One device command or reply on `/device/<name>`.
    pub fn device(&mut self, io: &DeviceIo) -> Result<(), RecordError> {
        self.write(&topic::device(io.device), io.time_ns, &Json(io), Latch::No)
    }

    /// A flush did not return within [`FLUSH_TIMEOUT_MS`]: the record's disk hangs.
    #[must_use]
    pub fn disk_hung(&self) -> bool {
        self.disk_hung.is_hung()
    }

    /// Closes the current chunk and flushes the file: everything so far survives a crash.
    pub fn flush(&mut self) -> Result<(), RecordError> {
        self.writer.as_ref().ok_or(RecordError::Finished)?.flush()?;
        Ok(())
    }

    /// Writes the summary and the footer; later messages are refused with
    /// [`RecordError::Finished`] (a device tap may outlive the run by a heartbeat).
    pub fn finish(&mut self) -> Result<(), RecordError> {
        if let Some(writer) = self.writer.take() {
            writer.close()?;
        }
        Ok(())
    }
}

/// A JSON schema that only names an object.
fn object_schema(name: &str) -> Schema {
    let schema = serde_json::json!({"title": name, "type": "object"});
    Schema::new(name, "jsonschema", schema.to_string().into_bytes())
}

fn build_channel(
    context: &Arc<Context>,
    topic: &str,
    schema: Option<Schema>,
    encoding: String,
) -> Result<Arc<RawChannel>, RecordError> {
    Ok(ChannelBuilder::new(topic)
        .context(context)
        .schema(schema)
        .message_encoding(encoding)
        .build_raw()?)
}

/// Creates every channel of a run's record ([`topic`]) on `context`, with its schema, before a
/// live view listens: the SDK (0.30) sends a channel's advertisement to the viewers connected
/// when it is created a moment before it records the channel as theirs, so a quick viewer's
/// subscription to it can be refused as "unknown channel" and is not retried; a viewer that
/// connects after the channel exists is sent the advertisement, channel recorded, before its
/// own messages are read. A declared channel without messages does not appear in the file.
pub fn declare_run_channels(context: &Arc<Context>) -> Result<(), RecordError> {
    fn typed<M: Encode>(context: &Arc<Context>, topic: &str) -> Result<(), RecordError> {
        build_channel(context, topic, M::get_schema(), M::get_message_encoding()).map(drop)
    }
    for t in [topic::SCAN, topic::CAD] {
        typed::<PointCloud>(context, t)?;
    }
    for t in [topic::TEMPLATE, topic::REGISTERED, topic::LAYER_SCENE] {
        typed::<SceneUpdate>(context, t)?;
    }
    typed::<FrameTransform>(context, topic::TF)?;
    typed::<Log>(context, topic::LOG)?;
    typed::<Json<'_, LayerMessage>>(context, topic::LAYER)?;
    typed::<Json<'_, ProgressMessage>>(context, topic::PROGRESS)?;
    for d in [Device::Galvo, Device::Laser, Device::Cnc] {
        typed::<Json<'_, DeviceIo>>(context, &topic::device(d))?;
    }
    for (t, name) in [
        (topic::CALIBRATION, topic::CALIBRATION_SCHEMA),
        (topic::SPOT_ERROR, topic::SPOT_ERROR_SCHEMA),
        (topic::SHUTDOWN, topic::SHUTDOWN_SCHEMA),
    ] {
        build_channel(context, t, Some(object_schema(name)), "json".to_owned())?;
    }
    Ok(())
}

/// The current layer's scene entity: its polylines (work-piece frame, scale-invariant lines)
/// and a translucent plate at its focal plane, oriented as the zone frame, with a label.
fn layer_entity(
    t_ns: u64,
    job: &Job,
    zone: &trim_cell::job::Zone,
    layer: &trim_cell::job::Layer,
    state: &str,
    rgba: [f64; 4],
) -> SceneEntity {
    let (fx, fy) = (zone.frame.x, zone.frame.y);
    let f = layer.focus_point;
    // A galvo point (x, y) of the layer is P = focus + x·X + y·Y (DESIGN.md, the Job contract).
    let at =
        |g: [f64; 2]| -> [f64; 3] { std::array::from_fn(|i| f[i] + g[0] * fx[i] + g[1] * fy[i]) };
    let lines = layer
        .polylines
        .iter()
        .map(|p| LinePrimitive {
            r#type: foxglove::messages::line_primitive::Type::LineStrip as i32,
            pose: identity_pose(),
            thickness: LAYER_LINE_PX,
            scale_invariant: true,
            points: p.points.iter().map(|&g| point3(at(g))).collect(),
            color: color(rgba),
            ..LinePrimitive::default()
        })
        .collect();
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for g in layer.polylines.iter().flat_map(|p| &p.points) {
        for i in 0..2 {
            lo[i] = lo[i].min(g[i]);
            hi[i] = hi[i].max(g[i]);
        }
    }
    if lo[0] > hi[0] {
        (lo, hi) = ([0.0; 2], [0.0; 2]);
    }
    let centre = at([(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0]);
    let q = quaternion_from_axes(zone.frame.x, zone.frame.y, zone.frame.z);
    let plate_pose = Some(Pose {
        position: Some(Vector3 {
            x: centre[0],
            y: centre[1],
            z: centre[2],
        }),
        orientation: Some(Quaternion {
            x: q[0],
            y: q[1],
            z: q[2],
            w: q[3],
        }),
    });
    let corner = at([lo[0], hi[1] + PLATE_MARGIN_MM]);
    let layers_in_zone = zone.layers.len();
    SceneEntity {
        timestamp: stamp(t_ns),
        frame_id: WORKPIECE_FRAME.to_owned(),
        id: LAYER_ENTITY.to_owned(),
        frame_locked: true,
        metadata: vec![
            KeyValuePair {
                key: "zone".to_owned(),
                value: zone.id.to_string(),
            },
            KeyValuePair {
                key: "layer".to_owned(),
                value: layer.index.to_string(),
            },
            KeyValuePair {
                key: "state".to_owned(),
                value: state.to_owned(),
            },
        ],
        lines,
        cubes: vec![CubePrimitive {
            pose: plate_pose,
            size: Some(Vector3 {
                x: hi[0] - lo[0] + 2.0 * PLATE_MARGIN_MM,
                y: hi[1] - lo[1] + 2.0 * PLATE_MARGIN_MM,
                z: job.layer_step_mm.max(0.01),
            }),
            color: color([rgba[0], rgba[1], rgba[2], PLATE_ALPHA]),
        }],
        texts: vec![TextPrimitive {
            pose: Some(Pose {
                position: Some(Vector3 {
                    x: corner[0],
                    y: corner[1],
                    z: corner[2],
                }),
                orientation: identity_pose().and_then(|p| p.orientation),
            }),
            billboard: true,
            font_size: 14.0,
            scale_invariant: true,
            color: color(rgba),
            text: format!(
                "zone {} layer {}/{layers_in_zone}: {state}",
                zone.id,
                layer.index + 1
            ),
        }],
        ..SceneEntity::default()
    }
}

/// A tap that writes device traffic into a shared recorder (errors are logged, not raised: the
/// record must never stop the machine).
#[must_use]
pub fn device_tap(recorder: &SharedRecorder) -> Tap {
    let r = recorder.clone();
    Tap::new(move |io| {
        let mut rec = r.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Err(e) = rec.device(&io) {
            tracing::warn!(error = %e, "record: device message lost");
        }
    })
}

/// The unit quaternion (x, y, z, w) of the rotation whose columns are the frame's axes.
#[must_use]
pub fn quaternion_from_axes(x: [f64; 3], y: [f64; 3], z: [f64; 3]) -> [f64; 4] {
    let m = nalgebra::Matrix3::new(x[0], y[0], z[0], x[1], y[1], z[1], x[2], y[2], z[2]);
    let r = nalgebra::Rotation3::from_matrix(&m);
    let q = nalgebra::UnitQuaternion::from_rotation_matrix(&r);
    [q.i, q.j, q.k, q.w]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quaternion_of_a_quarter_turn_about_z() {
        let q = quaternion_from_axes([0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
        let h = std::f64::consts::FRAC_1_SQRT_2;
        assert!(
            (q[2] - h).abs() < 1e-12 && (q[3] - h).abs() < 1e-12,
            "{q:?}"
        );
    }

    #[test]
    fn json_channels_carry_their_schema_title_as_name() {
        let schema = Json::<LayerMessage>::get_schema().unwrap();
        assert_eq!(schema.name, "trimctl.Layer");
        assert_eq!(schema.encoding, "jsonschema");
        let json: serde_json::Value = serde_json::from_slice(&schema.data).unwrap();
        assert_eq!(json["title"], "trimctl.Layer");
        assert!(json["properties"]["vectors_done"].is_object(), "{json}");
        let schema = Json::<DeviceIo>::get_schema().unwrap();
        assert_eq!(schema.name, "trimctl.DeviceIo");
    }

    #[test]
    fn a_truncated_record_reads_back_to_the_last_flushed_chunk() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.mcap");
        let mut rec = Recorder::create(&path).unwrap();
        assert!(matches!(
            Recorder::create(&dir.path().join("no/such/dir.mcap")),
            Err(RecordError::Io { .. })
        ));
        let mut ends = Vec::new();
        for batch in 0..8_u64 {
            for i in 0..25_u64 {
                rec.log(
                    batch * 1000 + i,
                    LogLevel::Info,
                    &format!("batch {batch} message {i}"),
                )
                .unwrap();
            }
            rec.flush().unwrap();
            ends.push(std::fs::metadata(&path).unwrap().len());
        }
        rec.finish().unwrap();
        assert!(matches!(
            rec.log(0, LogLevel::Info, "late"),
            Err(RecordError::Finished)
        ));
        assert!(matches!(rec.flush(), Err(RecordError::Finished)));
        let full = std::fs::read(&path).unwrap();
        let count = |bytes: &[u8]| {
            let mut n = 0;
            let Ok(stream) = mcap::MessageStream::new(bytes) else {
                return 0;
            };
            for m in stream {
                if m.is_err() {
                    break;
                }
                n += 1;
            }
            n
        };
        assert_eq!(count(&full), 200);
        // Cut in the middle of the sixth batch's chunk: at least the five flushed batches
        // survive (the reader may also stream part of the cut chunk), never more than written.
        let cut = usize::try_from((ends[4] + ends[5]) / 2).unwrap();
        let n = count(&full[..cut]);
        assert!((125..150).contains(&n), "{n}");
        let cut = usize::try_from(ends[4]).unwrap();
        assert_eq!(count(&full[..cut]), 125);
    }
}
