//! The run record: an MCAP file with Foxglove well-known schemas, JSON encoded (message encoding
//! "json", schema encoding "jsonschema"), plus one JSON channel per device with every command
//! and reply. Chunked and flushed at every finished layer, so a crash leaves the file readable up
//! to the last finished chunk.
//!
//! Topics: `/scan` and `/cad` (foxglove.PointCloud), `/template` and `/registered`
//! (foxglove.SceneUpdate with line strips), `/tf` (foxglove.FrameTransform per zone frame),
//! `/layer` (trimctl.Layer: the current layer and its state), `/log` (foxglove.Log),
//! `/device/galvo`, `/device/laser`, `/device/cnc` (trimctl.DeviceIo).

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use serde_json::{Value, json};
use trim_plan::job::{Job, LayerKey};

use crate::tap::{DeviceIo, Tap};

/// Target uncompressed chunk size (bytes); chunks are also closed at every [`Recorder::flush`].
pub const CHUNK_BYTES: u64 = 256 * 1024;
/// The frame everything in the work-piece frame is published in.
pub const WORKPIECE_FRAME: &str = "workpiece";

/// foxglove.PointCloud (JSON schema).
pub const POINT_CLOUD_SCHEMA: &str = r#"{"title":"foxglove.PointCloud","type":"object","properties":{"timestamp":{"type":"object","properties":{"sec":{"type":"integer","minimum":0},"nsec":{"type":"integer","minimum":0,"maximum":999999999}}},"frame_id":{"type":"string"},"pose":{"type":"object","properties":{"position":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},"orientation":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}}}}},"point_stride":{"type":"integer","minimum":0},"fields":{"type":"array","items":{"type":"object","properties":{"name":{"type":"string"},"offset":{"type":"integer","minimum":0},"type":{"type":"integer","description":"foxglove.NumericType: 7 FLOAT32, 8 FLOAT64"}}}},"data":{"type":"string","contentEncoding":"base64"}}}"#;
/// A JSON object of any shape (the topic's schema name says what it holds).
pub const OBJECT_SCHEMA: &str = r#"{"type":"object"}"#;
/// foxglove.SceneUpdate (JSON schema; the parts used: entities with line primitives).
pub const SCENE_UPDATE_SCHEMA: &str = r#"{"title":"foxglove.SceneUpdate","type":"object","properties":{"deletions":{"type":"array","items":{"type":"object"}},"entities":{"type":"array","items":{"type":"object","properties":{"timestamp":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"frame_id":{"type":"string"},"id":{"type":"string"},"lifetime":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"frame_locked":{"type":"boolean"},"metadata":{"type":"array","items":{"type":"object","properties":{"key":{"type":"string"},"value":{"type":"string"}}}},"arrows":{"type":"array"},"cubes":{"type":"array"},"spheres":{"type":"array"},"cylinders":{"type":"array"},"lines":{"type":"array","items":{"type":"object","properties":{"type":{"type":"integer","description":"0 LINE_STRIP, 1 LINE_LOOP, 2 LINE_LIST"},"pose":{"type":"object"},"thickness":{"type":"number"},"scale_invariant":{"type":"boolean"},"points":{"type":"array","items":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}}},"color":{"type":"object","properties":{"r":{"type":"number"},"g":{"type":"number"},"b":{"type":"number"},"a":{"type":"number"}}},"colors":{"type":"array"},"indices":{"type":"array"}}}},"triangles":{"type":"array"},"texts":{"type":"array"},"models":{"type":"array"}}}}}}"#;
/// foxglove.FrameTransform (JSON schema).
pub const FRAME_TRANSFORM_SCHEMA: &str = r#"{"title":"foxglove.FrameTransform","type":"object","properties":{"timestamp":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"parent_frame_id":{"type":"string"},"child_frame_id":{"type":"string"},"translation":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"}}},"rotation":{"type":"object","properties":{"x":{"type":"number"},"y":{"type":"number"},"z":{"type":"number"},"w":{"type":"number"}}}}}"#;
/// foxglove.Log (JSON schema).
pub const LOG_SCHEMA: &str = r#"{"title":"foxglove.Log","type":"object","properties":{"timestamp":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"level":{"type":"integer","description":"1 DEBUG, 2 INFO, 3 WARNING, 4 ERROR, 5 FATAL"},"message":{"type":"string"},"name":{"type":"string"},"file":{"type":"string"},"line":{"type":"integer"}}}"#;
/// trimctl.Layer (JSON schema).
pub const LAYER_SCHEMA: &str = r#"{"title":"trimctl.Layer","type":"object","properties":{"zone":{"type":"integer"},"layer":{"type":"integer"},"state":{"type":"string"},"vectors_done":{"type":"integer"},"vectors":{"type":"integer"},"pose":{"type":"object"},"focus_point":{"type":"array","items":{"type":"number"}}}}"#;
/// trimctl.DeviceIo (JSON schema).
pub const DEVICE_IO_SCHEMA: &str = r#"{"title":"trimctl.DeviceIo","type":"object","properties":{"time_ns":{"type":"integer"},"device":{"type":"string"},"direction":{"type":"string","enum":["command","reply"]},"text":{"type":"string"}}}"#;

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
    /// The MCAP writer failed.
    #[error("record: {0}")]
    Mcap(#[from] mcap::McapError),
    /// A message came after [`Recorder::finish`].
    #[error("record: the file is finished")]
    Finished,
}

/// The MCAP writer with its channels.
pub struct Recorder {
    writer: mcap::Writer<BufWriter<File>>,
    schemas: HashMap<&'static str, u16>,
    channels: HashMap<String, u16>,
    sequence: u32,
    messages: u64,
    per_topic: BTreeMap<String, u64>,
    finished: bool,
}

/// A recorder shared between the executor and the device taps.
pub type SharedRecorder = Arc<Mutex<Recorder>>;

fn stamp(t_ns: u64) -> Value {
    json!({"sec": t_ns / 1_000_000_000, "nsec": t_ns % 1_000_000_000})
}

/// Standard base64 (RFC 4648, with padding), for JSON `bytes` fields.
#[must_use]
pub fn base64(bytes: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n = (u32::from(c[0]) << 16)
            | (u32::from(*c.get(1).unwrap_or(&0)) << 8)
            | u32::from(*c.get(2).unwrap_or(&0));
        for i in 0..4 {
            if i <= c.len() {
                out.push(char::from(T[((n >> (18 - 6 * i)) & 63) as usize]));
            } else {
                out.push('=');
            }
        }
    }
    out
}

impl Recorder {
    /// Creates the file.
    pub fn create(path: &Path) -> Result<Recorder, RecordError> {
        let file = File::create(path).map_err(|source| RecordError::Io {
            path: path.to_owned(),
            source,
        })?;
        let writer = mcap::WriteOptions::new()
            .compression(None)
            .chunk_size(Some(CHUNK_BYTES))
            .profile("")
            .library(concat!("trimctl trim-io ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(file))?;
        Ok(Recorder {
            writer,
            schemas: HashMap::new(),
            channels: HashMap::new(),
            sequence: 0,
            messages: 0,
            per_topic: BTreeMap::new(),
            finished: false,
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
        schema_name: &'static str,
        schema: &'static str,
    ) -> Result<u16, RecordError> {
        if let Some(&id) = self.channels.get(topic) {
            return Ok(id);
        }
        let schema_id = match self.schemas.get(schema_name) {
            Some(&id) => id,
            None => {
                let id = self
                    .writer
                    .add_schema(schema_name, "jsonschema", schema.as_bytes())?;
                self.schemas.insert(schema_name, id);
                id
            }
        };
        let id = self
            .writer
            .add_channel(schema_id, topic, "json", &BTreeMap::new())?;
        self.channels.insert(topic.to_owned(), id);
        Ok(id)
    }

    fn write(
        &mut self,
        topic: &str,
        schema_name: &'static str,
        schema: &'static str,
        t_ns: u64,
        msg: &Value,
    ) -> Result<(), RecordError> {
        if self.finished {
            return Err(RecordError::Finished);
        }
        let channel_id = self.channel(topic, schema_name, schema)?;
        self.sequence = self.sequence.wrapping_add(1);
        let data = serde_json::to_vec(msg).unwrap_or_default();
        self.writer.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id,
                sequence: self.sequence,
                log_time: t_ns,
                publish_time: t_ns,
            },
            &data,
        )?;
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

    /// A point cloud (mm) in the work-piece frame as foxglove.PointCloud (float64 x, y, z).
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
        let msg = json!({
            "timestamp": stamp(t_ns),
            "frame_id": WORKPIECE_FRAME,
            "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
            "point_stride": 24,
            "fields": [
                {"name": "x", "offset": 0, "type": 8},
                {"name": "y", "offset": 8, "type": 8},
                {"name": "z", "offset": 16, "type": 8}
            ],
            "data": base64(&data),
        });
        self.write(topic, "foxglove.PointCloud", POINT_CLOUD_SCHEMA, t_ns, &msg)
    }

    /// Paths (mm, work-piece frame) as foxglove.SceneUpdate line strips, one entity per contour.
    pub fn paths(
        &mut self,
        topic: &str,
        t_ns: u64,
        contours: &[(i64, Vec<[f64; 3]>)],
        rgba: [f64; 4],
    ) -> Result<(), RecordError> {
        let entities: Vec<Value> = contours
            .iter()
            .map(|(id, pts)| {
                json!({
                    "timestamp": stamp(t_ns),
                    "frame_id": WORKPIECE_FRAME,
                    "id": format!("{topic}/{id}"),
                    "lifetime": {"sec": 0, "nsec": 0},
                    "frame_locked": true,
                    "metadata": [{"key": "contour", "value": id.to_string()}],
                    "arrows": [], "cubes": [], "spheres": [], "cylinders": [], "triangles": [], "texts": [], "models": [],
                    "lines": [{
                        "type": 0,
                        "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
                        "thickness": 0.2,
                        "scale_invariant": false,
                        "points": pts.iter().map(|p| json!({"x": p[0], "y": p[1], "z": p[2]})).collect::<Vec<_>>(),
                        "color": {"r": rgba[0], "g": rgba[1], "b": rgba[2], "a": rgba[3]},
                        "colors": [],
                        "indices": []
                    }]
                })
            })
            .collect();
        let msg = json!({"deletions": [], "entities": entities});
        self.write(
            topic,
            "foxglove.SceneUpdate",
            SCENE_UPDATE_SCHEMA,
            t_ns,
            &msg,
        )
    }

    /// Every zone frame of the job as foxglove.FrameTransform (`workpiece` → `zone_<id>`).
    pub fn zone_frames(&mut self, t_ns: u64, job: &Job) -> Result<(), RecordError> {
        for z in &job.zones {
            let q = quaternion_from_axes(z.frame.x, z.frame.y, z.frame.z);
            let msg = json!({
                "timestamp": stamp(t_ns),
                "parent_frame_id": WORKPIECE_FRAME,
                "child_frame_id": format!("zone_{}", z.id),
                "translation": {"x": z.origin[0], "y": z.origin[1], "z": z.origin[2]},
                "rotation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
            });
            self.write(
                "/tf",
                "foxglove.FrameTransform",
                FRAME_TRANSFORM_SCHEMA,
                t_ns,
                &msg,
            )?;
        }
        Ok(())
    }

    /// The current layer and its state ("started", "done", "cut", "skipped").
    pub fn layer(
        &mut self,
        t_ns: u64,
        key: LayerKey,
        state: &str,
        vectors_done: u32,
        vectors: u32,
        job: &Job,
    ) -> Result<(), RecordError> {
        let layer = job
            .zones
            .iter()
            .find(|z| z.id == key.zone)
            .and_then(|z| z.layers.iter().find(|l| l.index == key.layer));
        let msg = json!({
            "zone": key.zone,
            "layer": key.layer,
            "state": state,
            "vectors_done": vectors_done,
            "vectors": vectors,
            "pose": layer.map(|l| serde_json::to_value(&l.pose).unwrap_or(Value::Null)),
            "focus_point": layer.map(|l| l.focus_point.to_vec()),
        });
        self.write("/layer", "trimctl.Layer", LAYER_SCHEMA, t_ns, &msg)
    }

    /// A log line as foxglove.Log.
    pub fn log(&mut self, t_ns: u64, level: LogLevel, message: &str) -> Result<(), RecordError> {
        let msg = json!({
            "timestamp": stamp(t_ns),
            "level": level as u8,
            "message": message,
            "name": "trimctl",
            "file": "",
            "line": 0,
        });
        self.write("/log", "foxglove.Log", LOG_SCHEMA, t_ns, &msg)
    }

    /// Any JSON object on `topic` under a permissive schema named `schema_name` (run summaries
    /// such as `/calibration` and `/twin/spot_error`).
    pub fn json(
        &mut self,
        topic: &str,
        schema_name: &'static str,
        t_ns: u64,
        msg: &Value,
    ) -> Result<(), RecordError> {
        self.write(topic, schema_name, OBJECT_SCHEMA, t_ns, msg)
    }

    /// One device command or reply on `/device/<name>`.
    pub fn device(&mut self, io: &DeviceIo) -> Result<(), RecordError> {
        let msg = serde_json::to_value(io).unwrap_or(Value::Null);
        let topic = format!("/device/{}", io.device.name());
        self.write(
            &topic,
            "trimctl.DeviceIo",
            DEVICE_IO_SCHEMA,
            io.time_ns,
            &msg,
        )
    }

    /// Closes the current chunk and flushes the file: everything so far survives a crash.
    pub fn flush(&mut self) -> Result<(), RecordError> {
        if self.finished {
            return Err(RecordError::Finished);
        }
        self.writer.flush()?;
        Ok(())
    }

    /// Writes the summary and the footer; later messages are refused with
    /// [`RecordError::Finished`] (a device tap may outlive the run by a heartbeat).
    pub fn finish(&mut self) -> Result<(), RecordError> {
        if self.finished {
            return Ok(());
        }
        self.finished = true;
        self.writer.finish()?;
        Ok(())
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
    fn base64_matches_rfc4648_vectors() {
        for (raw, enc) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(raw.as_bytes()), enc);
        }
    }

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
