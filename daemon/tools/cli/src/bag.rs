//! What `slam`, `fuse` and `play` share to read a team's own ROS 2 bag:
//! the topic → role flags and opening the bag with them.

use anyhow::Context;
use smokenav_platform_recording::bag::{Bag, RoleMap, RoleRequest, SonarKind};
use std::path::Path;

/// Which of the bag's topics play which role (guessed by type when unambiguous).
#[derive(clap::Args, Debug, Clone, Default)]
pub struct RoleArgs {
    /// The bag's sensor_msgs/LaserScan topic (default: the only one).
    #[arg(long, value_name = "TOPIC")]
    pub laser: Option<String>,
    /// The bag's nav_msgs/Odometry topic (default: the only one).
    #[arg(long, value_name = "TOPIC")]
    pub odom: Option<String>,
    /// A sonar topic: sensor_msgs/Range (repeat the flag, one topic per
    /// transducer, in the profile's transducer order unless /tf_static places
    /// their frames) or one sensor_msgs/PointCloud2 holding the ring
    /// (default: every Range topic, else the PointCloud2 topic named *sonar*).
    #[arg(long, value_name = "TOPIC")]
    pub sonar: Vec<String>,
}

impl RoleArgs {
    pub fn request(&self) -> RoleRequest {
        RoleRequest {
            laser: self.laser.clone(),
            odom: self.odom.clone(),
            sonar: self.sonar.clone(),
        }
    }

    pub fn given(&self) -> bool {
        self.laser.is_some() || self.odom.is_some() || !self.sonar.is_empty()
    }
}

/// Opens a bag (a rosbag2 folder, `.mcap` or `.db3`) and resolves the roles;
/// `both` requires the laser and the odometry.
pub fn open(path: &Path, roles: &RoleArgs, both: bool) -> anyhow::Result<(Bag, RoleMap)> {
    let bag = Bag::open(path).with_context(|| format!("cannot read the bag {}", path.display()))?;
    let map = if both {
        bag.laser_and_odometry(&roles.request())?
    } else {
        bag.roles(&roles.request())?
    };
    Ok((bag, map))
}

/// One line saying which sonar topics are read and how, for the logs and reports.
pub fn sonar_summary(map: &RoleMap) -> Option<String> {
    let kind = map.sonar_kind?;
    let what = match kind {
        SonarKind::Range => "sensor_msgs/Range",
        SonarKind::Cloud => "sensor_msgs/PointCloud2",
    };
    Some(format!(
        "{} ({what}, {})",
        map.sonar.join(", "),
        if map.sonar_ordered {
            "transducers by /tf_static, else in the order given"
        } else {
            "transducers by /tf_static"
        }
    ))
}
