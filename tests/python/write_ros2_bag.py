"""Rewrites a smokenav recording as a team's own ROS 2 bags, with tools
independent of smokenav: mcap_ros2 decodes the recording, rosbags writes the
bags (storage mcap and sqlite3, ROS 2 Humble types).

    write_ros2_bag.py RECORDING.mcap OUT_DIR

Writes OUT_DIR/mcap/ and OUT_DIR/sqlite3/ (rosbag2 folders; and
OUT_DIR/tf-only/, /tf_static alone), each holding
/scan (sensor_msgs/LaserScan), /odom (nav_msgs/Odometry) and /tf_static, on
the topic names a ROS 2 robot uses, with the receive times of the
recording (moved back onto its stamps' clock by its unix_offset_ns), and
prints one JSON line of counts.
"""

import json
import sys
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


def main():
    recording, out = Path(sys.argv[1]), Path(sys.argv[2])
    with open(recording, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        offset = 0
        for md in reader.iter_metadata():
            if md.name == "smokenav" and "unix_offset_ns" in md.metadata:
                offset = int(md.metadata["unix_offset_ns"])
        msgs = []
        for _schema, channel, message, ros in reader.iter_decoded_messages(
            topics=list(TOPICS), log_time_order=False
        ):
            msgs.append((channel.topic, message.log_time - offset, convert(channel.topic, ros)))
    counts = {}
    for storage, plugin in (("mcap", StoragePlugin.MCAP), ("sqlite3", StoragePlugin.SQLITE3)):
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
        by_topic[TOPICS[topic][0]] = by_topic.get(TOPICS[topic][0], 0) + 1
    print(json.dumps({"written": counts, "topics": by_topic}))


if __name__ == "__main__":
    main()
