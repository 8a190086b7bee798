"""Rewrites a smokenav recording as a team's own ROS 2 bags, with tools
independent of smokenav: mcap_ros2 decodes the recording, rosbags writes the
bags (storage mcap and sqlite3, ROS 2 Humble types).

    write_ros2_bag.py RECORDING.mcap OUT_DIR [PROFILE.toml]

Writes OUT_DIR/mcap/ and OUT_DIR/sqlite3/ (rosbag2 folders; and
OUT_DIR/tf-only/, /tf_static alone), each holding
/scan (sensor_msgs/LaserScan), /odom (nav_msgs/Odometry) and /tf_static, on
the topic names a ROS 2 robot uses, with the receive times of the
recording (moved back onto its stamps' clock by its unix_offset_ns), and
prints one JSON line of counts.

With the robot profile, the recording's sonar rings are written too, as a
ROS 2 robot's drivers publish them:
- in mcap/ and sqlite3/, one sensor_msgs/Range topic per transducer
  (/sonar/0 ...; frame sonar_<i>, placed in /tf_static; REP 117: +inf for no
  echo, NaN for no reading);
- in range-notf/ (mcap), the same Range topics with /tf_static placing only
  the laser (the transducers are then known only by the topics' order);
- in cloud-mcap/ and cloud-sqlite3/, the ring as one sensor_msgs/PointCloud2
  on /sonar_pointcloud2 as RosAria publishes it: x, y, z float32 in
  base_link, one point per reading at its echo (at the maximum range for no
  echo, NaN for no reading).
"""

import json
import math
import sys
import tomllib
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

TOPICS = {
    "/laser/scan": ("/scan", "sensor_msgs/msg/LaserScan"),
    "/base/odom": ("/odom", "nav_msgs/msg/Odometry"),
    "/tf_static": ("/tf_static", "tf2_msgs/msg/TFMessage"),
}
SONAR = "/base/sonar"
RANGE = "sensor_msgs/msg/Range"
CLOUD = "sensor_msgs/msg/PointCloud2"
CLOUD_TOPIC = "/sonar_pointcloud2"
VALID, SATURATED = 0, 1

ts = get_typestore(Stores.ROS2_HUMBLE)
T = ts.types
Time = T["builtin_interfaces/msg/Time"]
Header = T["std_msgs/msg/Header"]


def header(h):
    return Header(stamp=Time(sec=h.stamp.sec, nanosec=h.stamp.nanosec), frame_id=h.frame_id)


def vec3(v):
    return T["geometry_msgs/msg/Vector3"](x=v.x, y=v.y, z=v.z)


def quat(q):
    return T["geometry_msgs/msg/Quaternion"](x=q.x, y=q.y, z=q.z, w=q.w)


def convert(topic, m):
    if topic == "/laser/scan":
        return T["sensor_msgs/msg/LaserScan"](
            header=header(m.header),
            angle_min=m.angle_min,
            angle_max=m.angle_max,
            angle_increment=m.angle_increment,
            time_increment=m.time_increment,
            scan_time=m.scan_time,
            range_min=m.range_min,
            range_max=m.range_max,
            ranges=np.array(m.ranges, dtype=np.float32),
            intensities=np.array(m.intensities, dtype=np.float32),
        )
    if topic == "/base/odom":
        p, t = m.pose, m.twist
        return T["nav_msgs/msg/Odometry"](
            header=header(m.header),
            child_frame_id=m.child_frame_id,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](
                pose=T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](
                        x=p.pose.position.x, y=p.pose.position.y, z=p.pose.position.z
                    ),
                    orientation=quat(p.pose.orientation),
                ),
                covariance=np.array(p.covariance, dtype=np.float64),
            ),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](
                    linear=vec3(t.twist.linear), angular=vec3(t.twist.angular)
                ),
                covariance=np.array(t.covariance, dtype=np.float64),
            ),
        )
    return T["tf2_msgs/msg/TFMessage"](
        transforms=[
            T["geometry_msgs/msg/TransformStamped"](
                header=header(x.header),
                child_frame_id=x.child_frame_id,
                transform=T["geometry_msgs/msg/Transform"](
                    translation=vec3(x.transform.translation),
                    rotation=quat(x.transform.rotation),
                ),
            )
            for x in m.transforms
        ]
    )


def header_at(stamp, frame_id):
    return Header(stamp=Time(sec=stamp.sec, nanosec=stamp.nanosec), frame_id=frame_id)


def yaw_quat(yaw):
    return T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))


def sonar_frames(tf_static, sonar):
    """The recording's /tf_static plus base_link -> sonar_<i> per transducer."""
    stamp = tf_static.transforms[0].header.stamp
    extra = [
        T["geometry_msgs/msg/TransformStamped"](
            header=Header(stamp=Time(sec=stamp.sec, nanosec=stamp.nanosec), frame_id="base_link"),
            child_frame_id=f"sonar_{t['index']}",
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=t["x"], y=t["y"], z=0.0),
                rotation=yaw_quat(math.radians(t["yaw_deg"])),
            ),
        )
        for t in sonar["transducers"]
    ]
    return T["tf2_msgs/msg/TFMessage"](transforms=list(tf_static.transforms) + extra)


def range_msgs(ring, sonar):
    """One sensor_msgs/Range per reading, stamped with the ring."""
    for r in ring.readings:
        if r.status == VALID:
            value = r.range
        elif r.status == SATURATED:
            value = math.inf
        else:
            value = math.nan
        yield r.index, T[RANGE](
            header=header_at(ring.header.stamp, f"sonar_{r.index}"),
            radiation_type=0,
            field_of_view=math.radians(sonar["cone_deg"]),
            min_range=sonar.get("min_range_m", 0.1),
            max_range=sonar["max_range_m"],
            range=value,
        )


def cloud_msg(ring, sonar):
    poses = {t["index"]: t for t in sonar["transducers"]}
    pts = []
    for r in ring.readings:
        t = poses[r.index]
        yaw = math.radians(t["yaw_deg"])
        if r.status in (VALID, SATURATED):
            d = r.range if r.status == VALID else sonar["max_range_m"]
            pts.append((t["x"] + d * math.cos(yaw), t["y"] + d * math.sin(yaw), 0.0))
        else:
            pts.append((math.nan, math.nan, math.nan))
    data = np.array(pts, dtype=np.float32).tobytes()
    field = T["sensor_msgs/msg/PointField"]
    return T[CLOUD](
        header=header_at(ring.header.stamp, "base_link"),
        height=1,
        width=len(pts),
        fields=[field(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")],
        is_bigendian=False,
        point_step=12,
        row_step=12 * len(pts),
        data=np.frombuffer(data, dtype=np.uint8),
        is_dense=False,
    )


def write_sonar_bags(out, msgs, sonar):
    """The bags with sonar: Range per transducer (with and without their frames), PointCloud2."""
    indices = [t["index"] for t in sonar["transducers"]]
    counts = {}
    layouts = [
        ("mcap", StoragePlugin.MCAP, "range", True),
        ("sqlite3", StoragePlugin.SQLITE3, "range", True),
        ("range-notf", StoragePlugin.MCAP, "range", False),
        ("cloud-mcap", StoragePlugin.MCAP, "cloud", False),
        ("cloud-sqlite3", StoragePlugin.SQLITE3, "cloud", False),
    ]
    for name, plugin, shape, frames in layouts:
        n = 0
        with Writer(out / name, version=8, storage_plugin=plugin) as w:
            conns = {topic: w.add_connection(TOPICS[topic][0], TOPICS[topic][1], typestore=ts) for topic in TOPICS}
            if shape == "range":
                ranges = {i: w.add_connection(f"/sonar/{i}", RANGE, typestore=ts) for i in indices}
            else:
                cloud = w.add_connection(CLOUD_TOPIC, CLOUD, typestore=ts)
            # The recording's order: the order its recorder received them.
            for topic, t, msg in msgs:
                if topic == SONAR:
                    if shape == "range":
                        for index, r in range_msgs(msg, sonar):
                            w.write(ranges[index], t, ts.serialize_cdr(r, RANGE))
                            n += 1
                    else:
                        w.write(cloud, t, ts.serialize_cdr(cloud_msg(msg, sonar), CLOUD))
                        n += 1
                    continue
                if topic == "/tf_static" and frames:
                    msg = sonar_frames(msg, sonar)
                w.write(conns[topic], t, ts.serialize_cdr(msg, TOPICS[topic][1]))
                n += 1
        counts[name] = n
    return counts


def main():
    recording, out = Path(sys.argv[1]), Path(sys.argv[2])
    sonar = None
    if len(sys.argv) > 3:
        with open(sys.argv[3], "rb") as f:
            sonar = tomllib.load(f)["sonar"]
    with open(recording, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        offset = 0
        for md in reader.iter_metadata():
            if md.name == "smokenav" and "unix_offset_ns" in md.metadata:
                offset = int(md.metadata["unix_offset_ns"])
        msgs = []
        rings = []
        wanted = list(TOPICS) + ([SONAR] if sonar else [])
        for _schema, channel, message, ros in reader.iter_decoded_messages(
            topics=wanted, log_time_order=False
        ):
            if channel.topic == SONAR:
                rings.append(ros)
                msgs.append((SONAR, message.log_time - offset, ros))
                continue
            msgs.append((channel.topic, message.log_time - offset, convert(channel.topic, ros)))
    counts = {}
    if sonar:
        counts = write_sonar_bags(out, msgs, sonar)
    for storage, plugin in () if sonar else (("mcap", StoragePlugin.MCAP), ("sqlite3", StoragePlugin.SQLITE3)):
        with Writer(out / storage, version=8, storage_plugin=plugin) as w:
            conns = {}
            for topic, (name, msgtype) in TOPICS.items():
                conns[topic] = w.add_connection(name, msgtype, typestore=ts)
            for topic, t, msg in msgs:
                w.write(conns[topic], t, ts.serialize_cdr(msg, TOPICS[topic][1]))
        counts[storage] = len(msgs)
    # A bag holding nothing smokenav plays: only the transforms.
    with Writer(out / "tf-only", version=8, storage_plugin=StoragePlugin.MCAP) as w:
        conn = w.add_connection("/tf_static", TOPICS["/tf_static"][1], typestore=ts)
        for topic, t, msg in msgs:
            if topic == "/tf_static":
                w.write(conn, t, ts.serialize_cdr(msg, TOPICS[topic][1]))
    by_topic = {}
    for topic, _, _ in msgs:
        if topic == SONAR:
            continue
        by_topic[TOPICS[topic][0]] = by_topic.get(TOPICS[topic][0], 0) + 1
    if sonar:
        by_topic["sonar rings"] = len(rings)
    print(json.dumps({"written": counts, "topics": by_topic}))


if __name__ == "__main__":
    main()
