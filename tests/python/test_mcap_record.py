"""The run record (MCAP) opens in the official Python reader with the expected channels, schemas
and message counts, and its messages decode as their schemas say: Foxglove's own schemas as
protobuf (decoded from the FileDescriptorSet the file carries, by mcap-protobuf-support), trimctl's
own channels as JSON under a JSON schema.

The record is written by the `trim-io` example `write_record` (`cargo run -q -p trim-io --example
write_record -- OUT.mcap`, or the build `cargo test` left): a small
job executed on the in-process simulators, with clouds and paths. The example prints what it
wrote per topic; this reader counts independently.
"""

import json
import os
import pathlib
import struct
import subprocess

import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

ROOT = pathlib.Path(__file__).resolve().parents[2]

FOXGLOVE_TOPICS = {
    "/scan": "foxglove.PointCloud",
    "/cad": "foxglove.PointCloud",
    "/template": "foxglove.SceneUpdate",
    "/registered": "foxglove.SceneUpdate",
    "/layer/scene": "foxglove.SceneUpdate",
    "/tf": "foxglove.FrameTransform",
    "/log": "foxglove.Log",
}
OWN_TOPICS = {
    "/layer": "trimctl.Layer",
    "/device/galvo": "trimctl.DeviceIo",
    "/device/laser": "trimctl.DeviceIo",
    "/device/cnc": "trimctl.DeviceIo",
}
# The example's job: 2 zones x 2 layers.
ZONES, LAYERS = 2, 2


def write_record_command(out):
    """The example `cargo test` built (target/debug/examples), when it is newer than every Rust
    source and manifest under crates/ and the workspace's Cargo.toml and Cargo.lock; else
    `cargo run`, which builds it anew for the dev profile and the crate's own features
    (2.5 minutes on a clean checkout)."""
    target = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    built = target / "debug" / "examples" / "write_record"
    if built.exists():
        sources = [*(ROOT / "crates").rglob("*.rs"), *(ROOT / "crates").rglob("Cargo.toml"),
                   ROOT / "Cargo.toml", ROOT / "Cargo.lock"]
        if built.stat().st_mtime > max(p.stat().st_mtime for p in sources):
            return [str(built), str(out)]
    return ["cargo", "run", "-q", "-p", "trim-io", "--example", "write_record", "--", str(out)]


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    out = tmp_path_factory.mktemp("record") / "run.mcap"
    proc = subprocess.run(
        write_record_command(out),
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    assert proc.returncode == 0, proc.stderr
    return out, json.loads(proc.stdout)


def read_all(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        messages = [(schema, channel, message) for schema, channel, message in reader.iter_messages()]
    return summary, messages


def decode(schema, channel, message):
    """A protobuf message object for Foxglove's schemas, a dict for JSON channels."""
    if channel.message_encoding == "json":
        return json.loads(message.data)
    decoder = DecoderFactory().decoder_for(channel.message_encoding, schema)
    assert decoder is not None, (channel.topic, channel.message_encoding, schema.encoding)
    return decoder(message.data)


def test_channels_schemas_and_counts(record):
    path, written = record
    summary, messages = read_all(path)
    topics = {c.topic: c for c in summary.channels.values()}
    assert set(topics) == set(FOXGLOVE_TOPICS) | set(OWN_TOPICS)
    for topic, name in FOXGLOVE_TOPICS.items():
        channel = topics[topic]
        schema = summary.schemas[channel.schema_id]
        assert schema.name == name
        assert schema.encoding == "protobuf"
        assert channel.message_encoding == "protobuf"
    for topic, name in OWN_TOPICS.items():
        channel = topics[topic]
        schema = summary.schemas[channel.schema_id]
        assert schema.name == name
        assert schema.encoding == "jsonschema"
        assert channel.message_encoding == "json"
        assert json.loads(schema.data)["title"] == name
    counts = {}
    for _, channel, _ in messages:
        counts[channel.topic] = counts.get(channel.topic, 0) + 1
    assert counts == written["messages_per_topic"]
    assert summary.statistics.message_count == len(messages)
    assert counts["/scan"] == counts["/cad"] == 1
    assert counts["/template"] == counts["/registered"] == 1
    assert counts["/tf"] == ZONES
    # Per layer: started, done; and the layer's scene for each.
    assert counts["/layer"] == counts["/layer/scene"] == 2 * ZONES * LAYERS
    assert written["layers_marked"] == ZONES * LAYERS
    for device in ("galvo", "laser", "cnc"):
        assert counts[f"/device/{device}"] >= 2 * ZONES * LAYERS


def test_messages_decode_as_their_schemas_say(record):
    path, written = record
    _, messages = read_all(path)
    by_topic = {}
    for schema, channel, message in messages:
        by_topic.setdefault(channel.topic, []).append((message, decode(schema, channel, message)))

    _, scan = by_topic["/scan"][0]
    assert scan.point_stride == 24 and scan.frame_id == "workpiece"
    assert [f.name for f in scan.fields] == ["x", "y", "z"]
    assert [f.type for f in scan.fields] == [8, 8, 8]  # FLOAT64
    assert len(scan.data) == 24 * written["cloud_points"]
    x0, y0, z0 = struct.unpack_from("<3d", scan.data, 0)
    assert (x0, y0, z0) == (10.0, 0.0, 0.0)

    _, tf = by_topic["/tf"][1]
    assert tf.parent_frame_id == "workpiece" and tf.child_frame_id == "zone_1"
    assert (tf.translation.x, tf.translation.y, tf.translation.z) == (10.0, 0.0, 0.0)
    assert abs(tf.rotation.w - 1.0) < 1e-12

    _, scene = by_topic["/registered"][0]
    line = scene.entities[0].lines[0]
    assert line.type == 0 and len(line.points) == 3  # LINE_STRIP

    # The layer's scene: its polyline in the work-piece frame (focus + x X + y Y: zone 0 layer 1
    # has its focus at z = -0.1), yellow while marked, then green once done.
    layer_scenes = [m for _, m in by_topic["/layer/scene"]]
    first = layer_scenes[0].entities[0]
    assert first.id == "current_layer"
    pts = [(p.x, p.y, p.z) for p in first.lines[0].points]
    assert pts == [(-3.0, -1.0, 0.0), (0.0, 2.0, 0.0), (3.0, -1.0, 0.0)]
    started, done = first.lines[0].color, layer_scenes[1].entities[0].lines[0].color
    assert (started.r, started.g, started.b) != (done.r, done.g, done.b)
    assert {kv.key: kv.value for kv in first.metadata} == {"zone": "0", "layer": "0", "state": "started"}
    z_layer1 = [p.z for p in layer_scenes[2].entities[0].lines[0].points]
    assert z_layer1 == pytest.approx([-0.1] * 3)

    states = [(m["zone"], m["layer"], m["state"]) for _, m in by_topic["/layer"]]
    assert states[:2] == [(0, 0, "started"), (0, 0, "done")]
    assert states[-1] == (1, 1, "done")

    for device in ("galvo", "laser", "cnc"):
        ios = [m for _, m in by_topic[f"/device/{device}"]]
        assert {io["direction"] for io in ios} == {"command", "reply"}
        assert all(io["device"] == device for io in ios)
        times = [io["time_ns"] for io in ios]
        assert times == sorted(times)
    laser_commands = [io["text"] for _, io in by_topic["/device/laser"] if io["direction"] == "command"]
    assert laser_commands.count("L=1") == ZONES * LAYERS

    # Log times are message times.
    for message, log in by_topic["/log"]:
        assert message.log_time == log.timestamp.seconds * 1_000_000_000 + log.timestamp.nanos
