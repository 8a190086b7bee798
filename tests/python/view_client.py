"""A Foxglove WebSocket client for the view end-to-end test.

Speaks `foxglove.websocket.v1` with the `websockets` package, subscribes to
the given topics and decodes every message's CDR with mcap-ros2-support's
decoder (from the ros2msg schema the server advertised), printing one JSON
object per line:

  {"op": "hello", "subprotocol": ..., "channels": [...]}          first
  {"op": "msg", "topic": ..., "t_ns": arrival (CLOCK_MONOTONIC), ...}

  view_client.py URL --topics /laser/scan,/tf [--all] --seconds 10
                 [--stall-after S --stall D] [--rcvbuf BYTES]

`--stall` stops reading for D seconds after S seconds (a slow client);
`--rcvbuf` shrinks the socket's receive buffer so the stall backs up into
the server instead of this machine's kernel. `--publish-pose X,Y,YAW`
publishes Foxglove's "2D Pose Estimate" instead (client advertise of
`/initialpose`, geometry_msgs/msg/PoseWithCovarianceStamped serialised by
`rosbags`, one client message) and prints
  {"op": "published_pose", "capabilities": [...], "encodings": [...]}
"""

import argparse
import json
import math
import socket
import struct
import sys
import time
import zlib
from urllib.parse import urlparse

from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
from websockets.sync.client import connect

OP_MESSAGE_DATA = 1


def stamp_ns(header):
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def finite(v):
    return v if math.isfinite(v) else None


def summary(schema, m):
    if schema == "sensor_msgs/msg/LaserScan":
        return {
            "stamp_ns": stamp_ns(m.header),
            "frame_id": m.header.frame_id,
            "angle_min": m.angle_min,
            "angle_increment": m.angle_increment,
            "range_max": m.range_max,
            "ranges": [finite(r) for r in m.ranges],
        }
    if schema == "nav_msgs/msg/OccupancyGrid":
        cells = bytes(v & 0xFF for v in m.data)
        return {
            "stamp_ns": stamp_ns(m.header),
            "frame_id": m.header.frame_id,
            "width": m.info.width,
            "height": m.info.height,
            "resolution": m.info.resolution,
            "origin_x": m.info.origin.position.x,
            "origin_y": m.info.origin.position.y,
            "cells_crc32": zlib.crc32(cells),
            "cells": len(cells),
        }
    if schema == "tf2_msgs/msg/TFMessage":
        return {
            "transforms": [
                {
                    "parent": t.header.frame_id,
                    "child": t.child_frame_id,
                    "stamp_ns": stamp_ns(t.header),
                    "x": t.transform.translation.x,
                    "y": t.transform.translation.y,
                    "qz": t.transform.rotation.z,
                    "qw": t.transform.rotation.w,
                }
                for t in m.transforms
            ]
        }
    if schema == "geometry_msgs/msg/PoseStamped":
        return {
            "stamp_ns": stamp_ns(m.header),
            "x": m.pose.position.x,
            "y": m.pose.position.y,
            "qz": m.pose.orientation.z,
            "qw": m.pose.orientation.w,
        }
    return {}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("url")
    ap.add_argument("--topics", default="")
    ap.add_argument("--all", action="store_true")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--stall-after", type=float, default=None)
    ap.add_argument("--stall", type=float, default=0.0)
    ap.add_argument("--rcvbuf", type=int, default=None)
    ap.add_argument("--publish-pose", default=None)
    args = ap.parse_args()
    wanted = set(t for t in args.topics.split(",") if t)

    u = urlparse(args.url)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    if args.rcvbuf:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, args.rcvbuf)
    sock.connect((u.hostname, u.port))
    factory = DecoderFactory()
    out = sys.stdout
    with connect(
        args.url,
        sock=sock,
        subprotocols=["foxglove.websocket.v1"],
        max_size=None,
        compression=None,
    ) as ws:
        info = json.loads(ws.recv(timeout=10))
        assert info["op"] == "serverInfo", info
        adv = json.loads(ws.recv(timeout=10))
        assert adv["op"] == "advertise", adv
        channels = {c["id"]: c for c in adv["channels"]}
        if args.publish_pose:
            publish_pose(ws, info, args.publish_pose, out)
            return 0
        out.write(
            json.dumps(
                {
                    "op": "hello",
                    "subprotocol": ws.subprotocol,
                    "server": info.get("name"),
                    "channels": [
                        {k: c[k] for k in ("topic", "encoding", "schemaName", "schemaEncoding")}
                        for c in adv["channels"]
                    ],
                }
            )
            + "\n"
        )
        subs, decoders = {}, {}
        for cid, c in channels.items():
            if args.all or c["topic"] in wanted:
                sid = len(subs) + 1
                subs[sid] = c
                schema = Schema(id=cid, name=c["schemaName"], encoding=c["schemaEncoding"], data=c["schema"].encode())
                decoders[sid] = factory.decoder_for(c["encoding"], schema)
        missing = wanted - {c["topic"] for c in subs.values()}
        assert not missing, f"not advertised: {missing}"
        ws.send(
            json.dumps(
                {"op": "subscribe", "subscriptions": [{"id": s, "channelId": c["id"]} for s, c in subs.items()]}
            )
        )
        start = time.monotonic()
        stalled = False
        while True:
            now = time.monotonic()
            if now - start >= args.seconds:
                break
            if args.stall_after is not None and not stalled and now - start >= args.stall_after:
                stalled = True
                out.write(json.dumps({"op": "stall", "t_ns": time.monotonic_ns()}) + "\n")
                time.sleep(args.stall)
                out.write(json.dumps({"op": "resume", "t_ns": time.monotonic_ns()}) + "\n")
                continue
            try:
                frame = ws.recv(timeout=max(0.01, args.seconds - (now - start)))
            except TimeoutError:
                break
            t_ns = time.monotonic_ns()
            if isinstance(frame, str) or frame[0] != OP_MESSAGE_DATA:
                continue
            sid, log_time = struct.unpack_from("<IQ", frame, 1)
            c = subs[sid]
            m = decoders[sid](frame[13:])
            rec = {"op": "msg", "topic": c["topic"], "t_ns": t_ns, "log_time": log_time}
            rec.update(summary(c["schemaName"], m))
            out.write(json.dumps(rec) + "\n")
    out.flush()
    return 0


def publish_pose(ws, info, spec, out):
    import numpy as np
    from rosbags.typesys import Stores, get_typestore

    x, y, yaw = (float(v) for v in spec.split(","))
    store = get_typestore(Stores.ROS2_JAZZY)
    t = store.types
    name = "geometry_msgs/msg/PoseWithCovarianceStamped"
    cov = np.zeros(36)
    cov[0], cov[7], cov[35] = 0.25, 0.25, 0.0685
    msg = t[name](
        header=t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="map"),
        pose=t["geometry_msgs/msg/PoseWithCovariance"](
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
            ),
            covariance=cov,
        ),
    )
    ws.send(json.dumps({"op": "advertise", "channels": [{"id": 1, "topic": "/initialpose", "encoding": "cdr", "schemaName": name}]}))
    ws.send(struct.pack("<BI", 1, 1) + bytes(store.serialize_cdr(msg, name)))
    time.sleep(0.5)
    out.write(json.dumps({"op": "published_pose", "capabilities": info.get("capabilities", []), "encodings": info.get("supportedEncodings", [])}) + "\n")
    out.flush()


if __name__ == "__main__":
    sys.exit(main())
