#!/usr/bin/env python3
"""Check a smokenav recording with readers smokenav did not write.

Usage: check_recording.py RECORDING.mcap DUMP.jsonl
       check_recording.py --truncated RECORDING.mcap


Verifies what Foxglove and `ros2 bag` need (ros2 profile, cdr channels with
ros2msg schemas, offered_qos_profiles, a summary with Statistics, no schema
id 0), then decodes every message three ways and requires them to agree:

  1. `mcap` + `mcap-ros2-support`, from the schemas embedded in the file;
  2. `rosbags` (its own MCAP reader), types registered from the file;
  3. for standard ROS 2 types, `rosbags`' built-in Humble and Jazzy type
     stores, ignoring the file's schema text: proves the payload layout is
     the real ROS 2 definition in both distributions.

Writes one JSON line per message to DUMP.jsonl (float fields as their
IEEE-754 bit patterns, so NaN payloads and -0.0 survive) for the Rust test
to compare with what was published. Exit status 0 only if everything holds;
the last line printed is a summary (`OK …` or `FAIL …`).

With --truncated (a file whose writer was killed: no summary), streams the
file with `mcap`'s StreamReader, decodes every message of every complete
chunk with `mcap-ros2-support`, stops at the cut, and prints
`TRUNCATED <messages>`.
"""

import json
import math
import struct
import sys
from collections import Counter

try:
    import numpy as np
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
except ImportError as e:  # the Rust test turns this into a failure with the hint
    print(f"MISSING python package: {e.name}; install with: python3 -m pip install mcap mcap-ros2-support rosbags")
    sys.exit(3)

SEPARATOR = "=" * 80


def f32bits(v):
    return struct.unpack("<I", struct.pack("<f", v))[0]


def f64bits(v):
    return struct.unpack("<Q", struct.pack("<d", v))[0]


def f32list(arr):
    if isinstance(arr, np.ndarray):
        return [int(x) for x in np.asarray(arr, dtype=np.float32).view(np.uint32)]
    return [f32bits(x) for x in arr]


def fields_of(obj):
    """Field names of a decoded message of either library (constants excluded)."""
    if hasattr(obj, "__dataclass_fields__"):
        names = [f for f in obj.__dataclass_fields__ if not f.startswith("__")]
    elif getattr(type(obj), "__slots__", None):
        names = [s for s in type(obj).__slots__ if not s.startswith("_")]
    else:
        names = [k for k in vars(obj) if not k.startswith("_")]
    return [n for n in names if not n.isupper()]


def normalize(v):
    """A plain structure comparable across decoders (NaN as a marker)."""
    if isinstance(v, float):
        return ("nan",) if math.isnan(v) else v
    if isinstance(v, (np.floating,)):
        return normalize(float(v))
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (bytes, bytearray)):
        return list(v)
    if isinstance(v, np.ndarray):
        return [normalize(x) for x in v.tolist()]
    if isinstance(v, (list, tuple)):
        return [normalize(x) for x in v]
    if isinstance(v, (int, str, bool)) or v is None:
        return v
    return {f: normalize(getattr(v, f)) for f in fields_of(v)}


class Failure(Exception):
    pass


def require(cond, what):
    if not cond:
        raise Failure(what)


def check_structure(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        require(header.profile == "ros2", f"profile is {header.profile!r}, expected 'ros2'")
        summary = reader.get_summary()
        require(summary is not None, "no summary section")
        require(summary.statistics is not None, "summary has no Statistics record")
        require(0 not in summary.schemas, "a schema has id 0")
        for cid, ch in summary.channels.items():
            require(ch.schema_id != 0, f"channel {ch.topic} has schema id 0")
            require(ch.message_encoding == "cdr", f"{ch.topic}: message encoding {ch.message_encoding!r}")
            require("offered_qos_profiles" in ch.metadata, f"{ch.topic}: no offered_qos_profiles")
            schema = summary.schemas[ch.schema_id]
            require(schema.encoding == "ros2msg", f"{ch.topic}: schema encoding {schema.encoding!r}")
            text = schema.data.decode()
            for section in text.split(SEPARATOR + "\n")[1:]:
                require(section.startswith("MSG: "), f"{schema.name}: dependency section without MSG: line")
        return summary


def extract(schema_name, msg):
    """Fields the Rust test compares with what was published."""
    n = schema_name
    if n == "sensor_msgs/msg/LaserScan":
        return {
            "stamp": [msg.header.stamp.sec, msg.header.stamp.nanosec],
            "frame_id": msg.header.frame_id,
            "angle_min": f32bits(msg.angle_min),
            "angle_max": f32bits(msg.angle_max),
            "angle_increment": f32bits(msg.angle_increment),
            "range_min": f32bits(msg.range_min),
            "range_max": f32bits(msg.range_max),
            "ranges": f32list(msg.ranges),
            "intensities": f32list(msg.intensities),
        }
    if n == "smokenav_msgs/msg/ScanExtras":
        return {
            "stamp_ns": msg.stamp_ns,
            "seq": msg.seq,
            "has_intensities": bool(msg.has_intensities),
            "beam_error": [int(c) for c in msg.beam_error],
            "error_ranges": f32list(msg.error_ranges),
        }
    if n == "nav_msgs/msg/Odometry":
        p, t = msg.pose.pose, msg.twist.twist
        return {
            "stamp": [msg.header.stamp.sec, msg.header.stamp.nanosec],
            "frame_id": msg.header.frame_id,
            "child_frame_id": msg.child_frame_id,
            "x": f64bits(p.position.x),
            "y": f64bits(p.position.y),
            "yaw": math.atan2(2 * p.orientation.w * p.orientation.z, 1 - 2 * p.orientation.z ** 2),
            "linear": f64bits(t.linear.x),
            "angular": f64bits(t.angular.z),
        }
    if n == "smokenav_msgs/msg/OdometryExtras":
        return {
            "stamp_ns": msg.stamp_ns,
            "seq": msg.seq,
            "theta": f64bits(msg.theta),
            "flags": msg.flags,
            "bumpers": msg.bumpers,
            "battery_v": f32bits(msg.battery_v),
        }
    if n == "smokenav_msgs/msg/SonarRing":
        return {
            "stamp_ns": msg.stamp_ns,
            "seq": msg.seq,
            "frame_id": msg.header.frame_id,
            "max_range": f32bits(msg.max_range),
            "readings": [[r.index, r.status, f32bits(r.range)] for r in msg.readings],
        }
    if n == "smokenav_msgs/msg/SmokeReading":
        return {
            "stamp_ns": msg.stamp_ns,
            "seq": msg.seq,
            "frame_id": msg.header.frame_id,
            "raw_mv": f32bits(msg.raw_mv),
            "raw_counts": msg.raw_counts,
            "level": f32bits(msg.level),
            "baseline_mv": f32bits(msg.baseline_mv),
            "trend": msg.trend,
            "state": msg.state,
        }
    if n == "tf2_msgs/msg/TFMessage":
        return {
            "transforms": [
                [t.header.frame_id, t.child_frame_id, t.transform.translation.x, t.transform.translation.y]
                for t in msg.transforms
            ]
        }
    if n == "sensor_msgs/msg/PointCloud2":
        return {"width": msg.width, "point_step": msg.point_step, "fields": [f.name for f in msg.fields]}
    return {}


def count_truncated(path):
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    schemas, channels, decoders = {}, {}, {}
    factory = DecoderFactory()
    messages = 0
    cut = None
    with open(path, "rb") as f:
        # StreamReader reads a whole Chunk record before yielding anything from
        # it, so an incomplete last chunk contributes nothing.
        records = StreamReader(f, skip_magic=False).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                break
            except Exception as e:  # the cut: an incomplete record
                cut = f"{type(e).__name__}: {e}"
                break
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                ch = channels[record.channel_id]
                if ch.schema_id not in decoders:
                    decoders[ch.schema_id] = factory.decoder_for(ch.message_encoding, schemas[ch.schema_id])
                decoders[ch.schema_id](record.data)
                messages += 1
    require(cut is not None, "the file is complete, not truncated")
    print(f"TRUNCATED {messages}")
    return 0


def main():
    if len(sys.argv) == 3 and sys.argv[1] == "--truncated":
        try:
            return count_truncated(sys.argv[2])
        except Failure as e:
            print(f"FAIL {e}")
            return 1
        except Exception as e:
            print(f"FAIL {type(e).__name__}: {e}")
            return 1
    if len(sys.argv) != 3:
        print(__doc__)
        return 2
    path, dump_path = sys.argv[1], sys.argv[2]
    try:
        summary = check_structure(path)

        # 1. mcap + mcap-ros2-support.
        ros2 = []
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
                ros2.append((channel.topic, schema.name, message.sequence, message.log_time, decoded))
        require(len(ros2) == summary.statistics.message_count,
                f"decoded {len(ros2)} messages, Statistics says {summary.statistics.message_count}")

        # 2. rosbags, types from the file; 3. built-in Humble and Jazzy stores.
        builtin = {name: get_typestore(store) for name, store in
                   (("humble", Stores.ROS2_HUMBLE), ("jazzy", Stores.ROS2_JAZZY))}
        rb = []
        standard_checked = Counter()
        with AnyReader([__import__("pathlib").Path(path)], default_typestore=builtin["jazzy"]) as reader:
            for conn in reader.connections:
                qos = conn.ext.offered_qos_profiles
                require(len(qos) >= 1, f"{conn.topic}: rosbags parsed no offered QoS")
            for conn, _t, raw in reader.messages():
                msg = reader.deserialize(raw, conn.msgtype)
                if not conn.msgtype.startswith("smokenav_msgs/"):
                    for store_name, store in builtin.items():
                        ref = store.deserialize_cdr(raw, conn.msgtype)
                        require(normalize(ref) == normalize(msg),
                                f"{conn.topic}: {store_name} {conn.msgtype} decodes differently")
                        standard_checked[store_name] += 1
                rb.append((conn.topic, conn.msgtype, normalize(msg)))
        require(len(rb) == len(ros2), f"rosbags read {len(rb)} messages, mcap {len(ros2)}")

        # Both decoders agree message by message (same file order).
        rb_by_topic = {}
        for topic, _ty, norm in rb:
            rb_by_topic.setdefault(topic, []).append(norm)
        seen = Counter()
        with open(dump_path, "w") as out:
            for topic, schema_name, sequence, log_time, decoded in ros2:
                i = seen[topic]
                seen[topic] += 1
                require(i < len(rb_by_topic.get(topic, [])), f"{topic}: rosbags has fewer messages")
                require(normalize(decoded) == rb_by_topic[topic][i],
                        f"{topic} message {i}: mcap-ros2-support and rosbags disagree")
                out.write(json.dumps({
                    "topic": topic,
                    "schema": schema_name,
                    "sequence": sequence,
                    "log_time": log_time,
                    "fields": extract(schema_name, decoded),
                }) + "\n")
        per_topic = ", ".join(f"{t}={n}" for t, n in sorted(seen.items()))
        print(f"OK {len(ros2)} messages decoded by mcap-ros2-support and rosbags; "
              f"standard types checked against built-in stores: {dict(standard_checked)}; {per_topic}")
        return 0
    except Failure as e:
        print(f"FAIL {e}")
        return 1
    except Exception as e:  # a decoder raising is a failure of the file
        print(f"FAIL {type(e).__name__}: {e}")
        return 1


if __name__ == "__main__":
    sys.exit(main())
