"""A second Zenoh session for the Zenoh link's end-to-end test, as a ROS 2
node on rmw_zenoh would see `smokenav-zenoh`.

Opens an `eclipse-zenoh` session in client mode to one endpoint (multicast
scouting off, listening nowhere), lists the rmw_zenoh liveliness tokens,
subscribes to `/laser/scan` on rmw_zenoh's key — built here from the
`rosbags` type store's own RIHS01 hash of sensor_msgs/msg/LaserScan, not
from anything the bridge says — and decodes each payload with `rosbags`'
CDR deserialiser. Optionally publishes geometry_msgs/Twist on `cmd_vel`
first, with an rmw_zenoh attachment (one stale sample, then fresh ones),
and geometry_msgs/PoseWithCovarianceStamped on `initialpose` (RViz's 2D
Pose Estimate), once in each frame given.
Prints one JSON object per line:

  {"op": "tokens", "keys": [...]}
  {"op": "scan", "key": ..., "stamp_ns": ..., "angle_min": ..., "ranges": [...],
   "attachment": {"seq": ..., "unix_ns": ..., "gid_len": ...}}
  {"op": "sent_cmd", "count": N}
  {"op": "sent_pose", "frames": [...]}

  zenoh_client.py ENDPOINT --scans N [--namespace /robot1] [--cmd-vel LIN,ANG,SECONDS]
                  [--initial-pose X,Y,YAW,FRAME[,FRAME...]]
"""

import argparse
import json
import math
import struct
import sys
import time

import zenoh
from rosbags.typesys import Stores, get_typestore

STORE = get_typestore(Stores.ROS2_JAZZY)


def dds(name):
    pkg, _, ty = name.rpartition("/")
    return pkg.replace("/", "::") + "::dds_::" + ty + "_"


def key(domain, namespace, topic, typename):
    fq = (namespace.rstrip("/") + topic).lstrip("/")
    return f"{domain}/{fq}/{dds(typename)}/{STORE.hash_rihs01(typename)}"


def attachment(seq, unix_ns, gid=bytes(range(16))):
    return struct.pack("<qqB", seq, unix_ns, 16) + gid


def finite(v):
    return v if math.isfinite(v) else None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("endpoint")
    ap.add_argument("--scans", type=int, default=5)
    ap.add_argument("--namespace", default="")
    ap.add_argument("--domain", type=int, default=0)
    ap.add_argument("--cmd-vel", default=None)
    ap.add_argument("--initial-pose", default=None)
    ap.add_argument("--timeout", type=float, default=60.0)
    a = ap.parse_args()

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([a.endpoint]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)

    def out(obj):
        print(json.dumps(obj), flush=True)

    # rmw_zenoh's graph: every token of the domain, as a new node queries it.
    tokens = []
    deadline = time.monotonic() + (a.timeout if a.scans > 0 else 0)
    while time.monotonic() < deadline:
        tokens = [str(r.ok.key_expr) for r in session.liveliness().get(f"@ros2_lv/{a.domain}/**") if r.ok]
        if any("/MP/" in t and "%laser%scan/" in t for t in tokens):
            break
        time.sleep(0.2)
    out({"op": "tokens", "keys": tokens})

    if a.cmd_vel:
        lin, ang, secs = (float(x) for x in a.cmd_vel.split(","))
        twist = STORE.types["geometry_msgs/msg/Twist"]
        vec = STORE.types["geometry_msgs/msg/Vector3"]
        k = key(a.domain, a.namespace, "/cmd_vel", "geometry_msgs/msg/Twist")
        pub = session.declare_publisher(k)
        now = time.time_ns()
        # Sent 10 s ago: a command the network held back must never move the robot.
        stale = STORE.serialize_cdr(twist(linear=vec(x=9.0, y=0.0, z=0.0), angular=vec(x=0.0, y=0.0, z=0.0)), "geometry_msgs/msg/Twist")
        pub.put(bytes(stale), attachment=attachment(1, now - 10_000_000_000))
        time.sleep(0.2)
        fresh = bytes(STORE.serialize_cdr(twist(linear=vec(x=lin, y=0.0, z=0.0), angular=vec(x=0.0, y=0.0, z=ang)), "geometry_msgs/msg/Twist"))
        n, end = 0, time.monotonic() + secs
        while time.monotonic() < end:
            n += 1
            pub.put(fresh, attachment=attachment(n + 1, time.time_ns()))
            time.sleep(0.1)
        pub.undeclare()
        out({"op": "sent_cmd", "count": n})

    if a.initial_pose:
        import numpy as np
        x, y, yaw, *frames = a.initial_pose.split(",")
        x, y, yaw = float(x), float(y), float(yaw)
        t = STORE.types
        name = "geometry_msgs/msg/PoseWithCovarianceStamped"
        k = key(a.domain, a.namespace, "/initialpose", name)
        pub = session.declare_publisher(k)
        time.sleep(0.3)
        cov = np.zeros(36)
        cov[0], cov[7], cov[35] = 0.25, 0.25, 0.0685  # RViz's defaults
        for n, frame in enumerate(frames):
            msg = t[name](
                header=t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=frame),
                pose=t["geometry_msgs/msg/PoseWithCovariance"](
                    pose=t["geometry_msgs/msg/Pose"](
                        position=t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
                    ),
                    covariance=cov,
                ),
            )
            pub.put(bytes(STORE.serialize_cdr(msg, name)), attachment=attachment(n + 1, time.time_ns()))
            time.sleep(0.3)
        pub.undeclare()
        out({"op": "sent_pose", "frames": frames})

    k = key(a.domain, a.namespace, "/laser/scan", "sensor_msgs/msg/LaserScan")
    sub = session.declare_subscriber(k)
    got = 0
    deadline = time.monotonic() + a.timeout
    while got < a.scans and time.monotonic() < deadline:
        s = sub.try_recv()
        if s is None:
            time.sleep(0.02)
            continue
        msg = STORE.deserialize_cdr(bytes(s.payload.to_bytes()), "sensor_msgs/msg/LaserScan")
        att = s.attachment.to_bytes() if s.attachment is not None else b""
        seq, unix_ns, gid_len = struct.unpack("<qqB", att[:17]) if len(att) >= 17 else (None, None, None)
        out({
            "op": "scan",
            "key": str(s.key_expr),
            "stamp_ns": msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec,
            "frame_id": msg.header.frame_id,
            "angle_min": msg.angle_min,
            "angle_increment": msg.angle_increment,
            "ranges": [finite(float(r)) for r in msg.ranges],
            "attachment": {"len": len(att), "seq": seq, "unix_ns": unix_ns, "gid_len": gid_len},
        })
        got += 1
    session.close()
    if got < a.scans:
        print(f"only {got} of {a.scans} scans in {a.timeout} s", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
