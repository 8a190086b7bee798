//! What `slam`, `fuse` and `play` share to read a team's own ROS 2 bag:
//! the topic → role flags and opening the bag with them.

use anyhow::Context;
use smokenav_platform_recording::bag::{Bag, RoleMap, RoleRequest};
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
}

impl RoleArgs {
    pub fn request(&self) -> RoleRequest {
        RoleRequest {
            laser: self.laser.clone(),
            odom: self.odom.clone(),
        }
    }

    pub fn given(&self) -> bool {
        self.laser.is_some() || self.odom.is_some()
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
