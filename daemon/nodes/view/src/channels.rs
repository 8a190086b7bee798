//! What the view advertises: every catalog topic as the recordings' MCAP
//! channels (same topic names, `ros2msg` schemas, `cdr` encoding), plus
//! the views the recording derives (`/tf`, `/tf_static`, sonar points).

use smokenav_platform_recording::encoder::{POINTS_SUFFIX, TF_STATIC_TOPIC, TF_TOPIC};
use smokenav_platform_recording::ros2;
use smokenav_platform_recording::schema::{self, MsgDef};
use smokenav_shared_types::MessageKind;
use smokenav_shared_types::catalog::{self, ros2_topic_name};

/// How a channel's messages reach a client.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lane {
    /// A bounded queue per client, oldest dropped (and counted) when full.
    Stream,
    /// One slot per client holding the newest value, sent before any
    /// stream message: a busy scan topic cannot starve it.
    Latest,
}

/// One advertised channel.
#[derive(Debug, Clone)]
pub struct ChannelDef {
    /// The Foxglove channel id (its index in the table).
    pub id: u32,
    /// ROS 2 topic (`/laser/scan`, `/laser/scan/extras`, `/tf`).
    pub topic: String,
    /// Its ros2msg schema.
    pub schema: &'static MsgDef,
    pub lane: Lane,
    /// A late subscriber gets the last message (the map, `/tf_static`).
    pub latched: bool,
}

/// The channels of bus topics `bus_topics`; `geometry`: the robot profile
/// is known, so `/tf_static` and the sonar points exist.
pub fn channel_table(bus_topics: &[String], geometry: bool) -> Vec<ChannelDef> {
    let mut out: Vec<ChannelDef> = Vec::new();
    let mut add = |topic: String, schema: &'static MsgDef, lane: Lane, latched: bool| {
        let id = out.len() as u32;
        out.push(ChannelDef {
            id,
            topic,
            schema,
            lane,
            latched,
        });
    };
    for t in bus_topics {
        let Some(kind) = catalog::topic_kind(t) else {
            continue;
        };
        let layout = ros2::layout(kind);
        let lane = match kind {
            MessageKind::Map | MessageKind::PoseEstimate => Lane::Latest,
            _ => Lane::Stream,
        };
        let main = ros2_topic_name(t);
        add(main.clone(), layout.standard, lane, layout.latched);
        if let Some((suffix, def)) = layout.companion {
            add(format!("{main}{suffix}"), def, lane, layout.latched);
        }
        if kind == MessageKind::SonarRing && geometry {
            add(
                format!("{main}{POINTS_SUFFIX}"),
                &schema::POINT_CLOUD2,
                Lane::Stream,
                false,
            );
        }
    }
    add(TF_TOPIC.into(), &schema::TF_MESSAGE, Lane::Stream, false);
    if geometry {
        add(
            TF_STATIC_TOPIC.into(),
            &schema::TF_MESSAGE,
            Lane::Latest,
            true,
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_catalog_topic_is_advertised_with_the_recordings_schema() {
        let topics = smokenav_platform_bus::tap::default_topics();
        let table = channel_table(&topics, true);
        let find = |t: &str| table.iter().find(|c| c.topic == t).unwrap();
        assert_eq!(find("/laser/scan").schema.name, "sensor_msgs/msg/LaserScan");
        assert_eq!(
            find("/laser/scan/extras").schema.name,
            "smokenav_msgs/msg/ScanExtras"
        );
        assert_eq!(find("/slam/map").schema.name, "nav_msgs/msg/OccupancyGrid");
        assert!(find("/slam/map").latched);
        assert_eq!(find("/slam/map").lane, Lane::Latest);
        assert_eq!(find("/slam/pose").lane, Lane::Latest);
        assert_eq!(find("/laser/scan").lane, Lane::Stream);
        assert_eq!(find("/tf").schema.name, "tf2_msgs/msg/TFMessage");
        assert_eq!(
            find("/base/sonar/points").schema.name,
            "sensor_msgs/msg/PointCloud2"
        );
        assert_eq!(
            find("/smoke/level").schema.name,
            "smokenav_msgs/msg/SmokeReading"
        );
        assert_eq!(find("/health/slam").schema.name, "smokenav_msgs/msg/Health");
        for (i, c) in table.iter().enumerate() {
            assert_eq!(c.id as usize, i);
        }
        let mut names: Vec<&str> = table.iter().map(|c| c.topic.as_str()).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), table.len(), "a topic advertised twice");
        // Without the profile there are no sensor poses: no points, no /tf_static.
        let bare = channel_table(&topics, false);
        assert!(
            bare.iter()
                .all(|c| c.topic != "/tf_static" && !c.topic.ends_with("/points"))
        );
    }
}
