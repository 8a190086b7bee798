//! ros2msg schema texts: the standard ROS 2 messages smokenav maps to, and
//! the `smokenav_msgs` package for what they cannot carry.
//!
//! An MCAP `ros2msg` schema is the top-level `.msg` text followed, for each
//! (transitive) dependency, by a line of 80 `=`, a line `MSG: pkg/Type` and
//! that type's text — the layout rosbag2 writes and Foxglove, `ros2 bag`,
//! `mcap-ros2-support` and `rosbags` parse. The standard definitions below
//! are identical in ROS 2 Humble, Jazzy and Kilted (checked against the
//! `rosbags` type stores by `tests/python/check_recording.py`).

/// One message type and the types its fields use.
#[derive(Debug)]
pub struct MsgDef {
    /// `pkg/msg/Type`, the MCAP schema name.
    pub name: &'static str,
    pub text: &'static str,
    pub deps: &'static [&'static MsgDef],
}

impl MsgDef {
    /// `pkg/Type`, as written after `MSG:` and in field declarations.
    pub fn short_name(&self) -> String {
        self.name.replacen("/msg/", "/", 1)
    }

    /// The full schema text with every dependency appended once.
    pub fn schema_text(&self) -> String {
        let mut order: Vec<&MsgDef> = Vec::new();
        fn visit<'a>(d: &'a MsgDef, order: &mut Vec<&'a MsgDef>) {
            for dep in d.deps {
                if !order.iter().any(|o| o.name == dep.name) {
                    order.push(dep);
                    visit(dep, order);
                }
            }
        }
        visit(self, &mut order);
        let mut out = String::from(self.text);
        for dep in order {
            out.push_str(&"=".repeat(80));
            out.push_str("\nMSG: ");
            out.push_str(&dep.short_name());
            out.push('\n');
            out.push_str(dep.text);
        }
        out
    }
}

// ---- builtin_interfaces, std_msgs, geometry_msgs -------------------------

pub static TIME: MsgDef = MsgDef {
    name: "builtin_interfaces/msg/Time",
    text: "int32 sec\nuint32 nanosec\n",
    deps: &[],
};

pub static CLOCK: MsgDef = MsgDef {
    name: "rosgraph_msgs/msg/Clock",
    text: "builtin_interfaces/Time clock\n",
    deps: &[&TIME],
};

pub static HEADER: MsgDef = MsgDef {
    name: "std_msgs/msg/Header",
    text: "builtin_interfaces/Time stamp\nstring frame_id\n",
    deps: &[&TIME],
};

pub static POINT: MsgDef = MsgDef {
    name: "geometry_msgs/msg/Point",
    text: "float64 x\nfloat64 y\nfloat64 z\n",
    deps: &[],
};

pub static QUATERNION: MsgDef = MsgDef {
    name: "geometry_msgs/msg/Quaternion",
    text: "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
    deps: &[],
};

pub static VECTOR3: MsgDef = MsgDef {
    name: "geometry_msgs/msg/Vector3",
    text: "float64 x\nfloat64 y\nfloat64 z\n",
    deps: &[],
};

pub static POSE: MsgDef = MsgDef {
    name: "geometry_msgs/msg/Pose",
    text: "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
    deps: &[&POINT, &QUATERNION],
};

pub static POSE_WITH_COVARIANCE: MsgDef = MsgDef {
    name: "geometry_msgs/msg/PoseWithCovariance",
    text: "geometry_msgs/Pose pose\nfloat64[36] covariance\n",
    deps: &[&POSE],
};

/// RViz's "2D Pose Estimate" (`/initialpose`), taken by `smokenav-zenoh`.
pub static POSE_WITH_COVARIANCE_STAMPED: MsgDef = MsgDef {
    name: "geometry_msgs/msg/PoseWithCovarianceStamped",
    text: "std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose\n",
    deps: &[&HEADER, &POSE_WITH_COVARIANCE],
};

pub static TWIST: MsgDef = MsgDef {
    name: "geometry_msgs/msg/Twist",
    text: "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n",
    deps: &[&VECTOR3],
};

pub static TWIST_WITH_COVARIANCE: MsgDef = MsgDef {
    name: "geometry_msgs/msg/TwistWithCovariance",
    text: "geometry_msgs/Twist twist\nfloat64[36] covariance\n",
    deps: &[&TWIST],
};

pub static POSE_STAMPED: MsgDef = MsgDef {
    name: "geometry_msgs/msg/PoseStamped",
    text: "std_msgs/Header header\ngeometry_msgs/Pose pose\n",
    deps: &[&HEADER, &POSE],
};

pub static TWIST_STAMPED: MsgDef = MsgDef {
    name: "geometry_msgs/msg/TwistStamped",
    text: "std_msgs/Header header\ngeometry_msgs/Twist twist\n",
    deps: &[&HEADER, &TWIST],
};

pub static TRANSFORM: MsgDef = MsgDef {
    name: "geometry_msgs/msg/Transform",
    text: "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
    deps: &[&VECTOR3, &QUATERNION],
};

pub static TRANSFORM_STAMPED: MsgDef = MsgDef {
    name: "geometry_msgs/msg/TransformStamped",
    text: "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n",
    deps: &[&HEADER, &TRANSFORM],
};

// ---- sensor_msgs, nav_msgs, tf2_msgs --------------------------------------

pub static LASER_SCAN: MsgDef = MsgDef {
    name: "sensor_msgs/msg/LaserScan",
    text: "std_msgs/Header header\n\
           float32 angle_min\n\
           float32 angle_max\n\
           float32 angle_increment\n\
           float32 time_increment\n\
           float32 scan_time\n\
           float32 range_min\n\
           float32 range_max\n\
           float32[] ranges\n\
           float32[] intensities\n",
    deps: &[&HEADER],
};

pub static POINT_FIELD: MsgDef = MsgDef {
    name: "sensor_msgs/msg/PointField",
    text: "uint8 INT8=1\n\
           uint8 UINT8=2\n\
           uint8 INT16=3\n\
           uint8 UINT16=4\n\
           uint8 INT32=5\n\
           uint8 UINT32=6\n\
           uint8 FLOAT32=7\n\
           uint8 FLOAT64=8\n\
           string name\n\
           uint32 offset\n\
           uint8 datatype\n\
           uint32 count\n",
    deps: &[],
};

pub static POINT_CLOUD2: MsgDef = MsgDef {
    name: "sensor_msgs/msg/PointCloud2",
    text: "std_msgs/Header header\n\
           uint32 height\n\
           uint32 width\n\
           sensor_msgs/PointField[] fields\n\
           bool is_bigendian\n\
           uint32 point_step\n\
           uint32 row_step\n\
           uint8[] data\n\
           bool is_dense\n",
    deps: &[&HEADER, &POINT_FIELD],
};

pub static ODOMETRY: MsgDef = MsgDef {
    name: "nav_msgs/msg/Odometry",
    text: "std_msgs/Header header\n\
           string child_frame_id\n\
           geometry_msgs/PoseWithCovariance pose\n\
           geometry_msgs/TwistWithCovariance twist\n",
    deps: &[&HEADER, &POSE_WITH_COVARIANCE, &TWIST_WITH_COVARIANCE],
};

pub static MAP_META_DATA: MsgDef = MsgDef {
    name: "nav_msgs/msg/MapMetaData",
    text: "builtin_interfaces/Time map_load_time\n\
           float32 resolution\n\
           uint32 width\n\
           uint32 height\n\
           geometry_msgs/Pose origin\n",
    deps: &[&TIME, &POSE],
};

pub static OCCUPANCY_GRID: MsgDef = MsgDef {
    name: "nav_msgs/msg/OccupancyGrid",
    text: "std_msgs/Header header\nnav_msgs/MapMetaData info\nint8[] data\n",
    deps: &[&HEADER, &MAP_META_DATA],
};

pub static TF_MESSAGE: MsgDef = MsgDef {
    name: "tf2_msgs/msg/TFMessage",
    text: "geometry_msgs/TransformStamped[] transforms\n",
    deps: &[&TRANSFORM_STAMPED],
};

// ---- smokenav_msgs ---------------------------------------------------------
// Every smokenav_msgs type carries the exact stamp (ns of the host
// CLOCK_MONOTONIC; builtin_interfaces/Time has an int32 second) and the
// per-publisher sequence number (ROS 2 headers have none).

pub static SCAN_EXTRAS: MsgDef = MsgDef {
    name: "smokenav_msgs/msg/ScanExtras",
    text: "# What sensor_msgs/LaserScan cannot carry, so a scan replays bit for bit.\n\
           # Written right after the LaserScan it completes, with the same MCAP sequence.\n\
           uint16 BEAM_OK=0\n\
           uint16 BEAM_NO_RETURN=1\n\
           uint16 BEAM_BEYOND_MAX=2\n\
           uint16 BEAM_SENSOR_CODE=256\n\
           uint64 stamp_ns\n\
           uint64 seq\n\
           # 1 when the scan carries intensities (then LaserScan.intensities has one per beam).\n\
           bool has_intensities\n\
           # Per beam: BEAM_OK, NO_RETURN, BEYOND_MAX, or BEAM_SENSOR_CODE + the sensor's code.\n\
           uint16[] beam_error\n\
           # The original range value of every beam whose beam_error is not BEAM_OK, in beam\n\
           # order (LaserScan.ranges holds REP 117 values there: +inf no return, NaN error code).\n\
           float32[] error_ranges\n",
    deps: &[],
};

pub static SECTION_DECISION: MsgDef = MsgDef {
    name: "smokenav_msgs/msg/SectionDecision",
    text: "# The fusion decision for one sonar section of a scan.\n\
           uint8 SOURCE_LASER=0\n\
           uint8 SOURCE_SONAR=1\n\
           uint8 SOURCE_BOTH=2\n\
           uint8 SOURCE_NEITHER=3\n\
           uint16 first_beam\n\
           uint16 end_beam\n\
           uint8 sonar_index\n\
           uint8 source\n\
           float32 rho_sonar\n\
           float32 rho_laser\n\
           float32 sonar_range\n",
    deps: &[],
};

pub static FUSED_DECISIONS: MsgDef = MsgDef {
    name: "smokenav_msgs/msg/FusedDecisions",
    text: "# Why fusion/scan looks the way it does; completes the LaserScan on /fusion/scan.\n\
           uint8 METHOD_LASER_ONLY=0\n\
           uint8 METHOD_V1=1\n\
           uint8 METHOD_V2=2\n\
           uint8 SYNC_COMPLETE=0\n\
           uint8 SYNC_LASER_ONLY=1\n\
           uint8 SYNC_SONAR_ONLY=2\n\
           smokenav_msgs/ScanExtras scan\n\
           # Per beam: SectionDecision.SOURCE_*.\n\
           uint8[] beam_source\n\
           uint8 method\n\
           uint8 sync_state\n\
           smokenav_msgs/SectionDecision[] sections\n\
           float32 smoke_level\n\
           float32 laser_spread\n\
           uint64 sonar_stamp_ns\n\
           uint64 smoke_stamp_ns\n",
    deps: &[&SCAN_EXTRAS, &SECTION_DECISION],
};

pub static ODOMETRY_EXTRAS: MsgDef = MsgDef {
    name: "smokenav_msgs/msg/OdometryExtras",
    text: "# What nav_msgs/Odometry cannot carry; completes the message on /base/odom.\n\
           uint32 MOTORS_ENABLED=1\n\
           uint32 LEFT_STALL=2\n\
           uint32 RIGHT_STALL=4\n\
           uint32 RESET=8\n\
           uint64 stamp_ns\n\
           uint64 seq\n\
           # Heading exactly as published (the quaternion is derived from it).\n\
           float64 theta\n\
           uint32 flags\n\
           # One bit per pressed bumper segment (front 0-7, rear 8-15).\n\
           uint32 bumpers\n\
           float32 battery_v\n",
    deps: &[],
};

pub static STAMP_SEQ: MsgDef = MsgDef {
    name: "smokenav_msgs/msg/StampSeq",
    text: "# Exact stamp and sequence number of the standard message before it.\n\
           uint64 stamp_ns\n\
           uint64 seq\n",
    deps: &[],
};

pub static POSE_EXTRAS: MsgDef = MsgDef {
    name: "smokenav_msgs/msg/PoseExtras",
    text: "# What geometry_msgs/PoseStamped cannot carry; completes the message on /slam/pose.\n\
           uint64 stamp_ns\n\
           uint64 seq\n\
           float64 theta\n\
           # Row-major 3x3 covariance of (x, y, theta).\n\
           float64[9] covariance\n\
           float32 n_eff\n\
           uint32 particles\n\
           uint64 scans_skipped\n\
           uint32 processing_us\n",
    deps: &[],
};

pub static MAP_EXTRAS: MsgDef = MsgDef {
    name: "smokenav_msgs/msg/MapExtras",
    text: "# What nav_msgs/OccupancyGrid cannot carry; completes the message on /slam/map.\n\
           uint64 stamp_ns\n\
           uint64 seq\n\
           float64 origin_theta\n",
    deps: &[],
};

pub static SONAR_READING: MsgDef = MsgDef {
    name: "smokenav_msgs/msg/SonarReading",
    text: "uint8 STATUS_VALID=0\n\
           uint8 STATUS_SATURATED=1\n\
           uint8 STATUS_INVALID=2\n\
           # Transducer index as numbered in the robot profile.\n\
           uint8 index\n\
           uint8 status\n\
           float32 range\n",
    deps: &[],
};

pub static SONAR_RING: MsgDef = MsgDef {
    name: "smokenav_msgs/msg/SonarRing",
    text: "# One cycle of the sonar ring, complete.\n\
           std_msgs/Header header\n\
           uint64 stamp_ns\n\
           uint64 seq\n\
           float32 max_range\n\
           smokenav_msgs/SonarReading[] readings\n",
    deps: &[&HEADER, &SONAR_READING],
};

pub static SMOKE_READING: MsgDef = MsgDef {
    name: "smokenav_msgs/msg/SmokeReading",
    text: "# One smoke-sensor reading, complete.\n\
           uint8 TREND_STEADY=0\n\
           uint8 TREND_RISING=1\n\
           uint8 TREND_FALLING=2\n\
           uint8 STATE_WARMING_UP=0\n\
           uint8 STATE_READY=1\n\
           uint8 STATE_DISCONNECTED=2\n\
           uint8 STATE_SATURATED=3\n\
           std_msgs/Header header\n\
           uint64 stamp_ns\n\
           uint64 seq\n\
           float32 raw_mv\n\
           uint32 raw_counts\n\
           # mV above the clean-air baseline (the SmokeNav paper's scale).\n\
           float32 level\n\
           float32 baseline_mv\n\
           uint8 trend\n\
           uint8 state\n",
    deps: &[&HEADER],
};

pub static METRIC: MsgDef = MsgDef {
    name: "smokenav_msgs/msg/Metric",
    text: "string name\n\
           float64 value\n\
           # NaN when the metric has no expected value.\n\
           float64 expected\n",
    deps: &[],
};

pub static HEALTH: MsgDef = MsgDef {
    name: "smokenav_msgs/msg/Health",
    text: "# A process's periodic health report, complete.\n\
           uint8 STATE_STARTING=0\n\
           uint8 STATE_OK=1\n\
           uint8 STATE_DEGRADED=2\n\
           uint8 STATE_ERROR=3\n\
           uint8 STATE_STOPPING=4\n\
           std_msgs/Header header\n\
           uint64 stamp_ns\n\
           uint64 seq\n\
           string role\n\
           uint32 pid\n\
           uint8 state\n\
           float64 uptime_s\n\
           float32 latency_p50_us\n\
           float32 latency_p99_us\n\
           float32 latency_max_us\n\
           uint64 deadline_misses\n\
           smokenav_msgs/Metric[] metrics\n\
           string last_error\n",
    deps: &[&HEADER, &METRIC],
};

/// Every top-level type a recording can contain.
pub static VOXEL_EXTRAS: MsgDef = MsgDef {
    name: "smokenav_msgs/msg/VoxelExtras",
    text: "# What sensor_msgs/PointCloud2 cannot carry; completes the cloud on /mapping/voxels.\n\
           uint64 stamp_ns\n\
           uint64 seq\n\
           # Voxel side, m.\n\
           float32 resolution\n\
           # Occupied voxels left out because the message was full.\n\
           uint32 truncated\n",
    deps: &[],
};

pub static ALL: &[&MsgDef] = &[
    &LASER_SCAN,
    &POINT_CLOUD2,
    &ODOMETRY,
    &OCCUPANCY_GRID,
    &POSE_STAMPED,
    &TWIST_STAMPED,
    &TF_MESSAGE,
    &CLOCK,
    &SCAN_EXTRAS,
    &FUSED_DECISIONS,
    &ODOMETRY_EXTRAS,
    &STAMP_SEQ,
    &POSE_EXTRAS,
    &MAP_EXTRAS,
    &VOXEL_EXTRAS,
    &SONAR_RING,
    &SMOKE_READING,
    &HEALTH,
];

/// Every `smokenav_msgs` type, dependencies included (the ROS package's messages).
pub static SMOKENAV_MSGS: &[&MsgDef] = &[
    &SCAN_EXTRAS,
    &SECTION_DECISION,
    &FUSED_DECISIONS,
    &ODOMETRY_EXTRAS,
    &STAMP_SEQ,
    &POSE_EXTRAS,
    &MAP_EXTRAS,
    &VOXEL_EXTRAS,
    &SONAR_READING,
    &SONAR_RING,
    &SMOKE_READING,
    &METRIC,
    &HEALTH,
];

#[cfg(test)]
mod tests {
    use super::*;

    /// `ros/smokenav_msgs` holds the same definitions, so a ROS 2 workspace can
    /// build the package and `ros2 bag play` can publish every channel.
    /// `SMOKENAV_BLESS=1 cargo test -p smokenav-platform-recording` rewrites the files.
    #[test]
    fn ros_package_messages_match_the_recorded_schemas() {
        let pkg = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("ros/smokenav_msgs");
        let cmake = std::fs::read_to_string(pkg.join("CMakeLists.txt")).unwrap();
        for def in SMOKENAV_MSGS {
            let ty = def.name.rsplit('/').next().unwrap();
            let path = pkg.join("msg").join(format!("{ty}.msg"));
            if std::env::var_os("SMOKENAV_BLESS").is_some() {
                std::fs::write(&path, def.text).unwrap();
            }
            let text = std::fs::read_to_string(&path)
                .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert_eq!(text, def.text, "{} differs from schema.rs", path.display());
            assert!(
                cmake.contains(&format!("\"msg/{ty}.msg\"")),
                "{ty} not in CMakeLists.txt"
            );
        }
        let files = std::fs::read_dir(pkg.join("msg")).unwrap().count();
        assert_eq!(files, SMOKENAV_MSGS.len(), "stray .msg files");
        for def in ALL.iter().filter(|d| d.name.starts_with("smokenav_msgs/")) {
            assert!(
                SMOKENAV_MSGS.iter().any(|m| m.name == def.name),
                "{}",
                def.name
            );
        }
    }

    const PRIMITIVES: &[&str] = &[
        "bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64",
        "uint64", "float32", "float64", "string",
    ];

    /// The type of each field line (constants and comments skipped), array suffix removed.
    fn field_types(text: &str) -> Vec<&str> {
        text.lines()
            .map(|l| l.split('#').next().unwrap_or("").trim())
            .filter(|l| !l.is_empty() && !l.contains('='))
            .map(|l| {
                let ty = l.split_whitespace().next().unwrap();
                ty.split('[').next().unwrap()
            })
            .collect()
    }

    #[test]
    fn every_referenced_type_is_declared_as_a_dependency() {
        for def in ALL {
            let text = def.schema_text();
            for ty in field_types(def.text) {
                if PRIMITIVES.contains(&ty) {
                    continue;
                }
                assert!(
                    text.contains(&format!("\nMSG: {ty}\n")),
                    "{}: field type {ty} has no MSG: section",
                    def.name
                );
            }
        }
    }

    #[test]
    fn dependency_sections_are_separated_by_80_equals_signs_and_appear_once() {
        let text = OCCUPANCY_GRID.schema_text();
        let sep = format!("{}\n", "=".repeat(80));
        let sections: Vec<&str> = text.split(&sep).collect();
        // OccupancyGrid, Header, Time, MapMetaData, Pose, Point, Quaternion.
        assert_eq!(sections.len(), 7, "{text}");
        assert!(sections[0].starts_with("std_msgs/Header header\n"));
        let mut names: Vec<&str> = sections[1..]
            .iter()
            .map(|s| s.lines().next().unwrap())
            .collect();
        names.sort();
        assert_eq!(
            names,
            [
                "MSG: builtin_interfaces/Time",
                "MSG: geometry_msgs/Point",
                "MSG: geometry_msgs/Pose",
                "MSG: geometry_msgs/Quaternion",
                "MSG: nav_msgs/MapMetaData",
                "MSG: std_msgs/Header",
            ]
        );
    }

    #[test]
    fn laser_scan_schema_is_the_ros2_definition() {
        let text = LASER_SCAN.schema_text();
        let fields: Vec<&str> = LASER_SCAN.text.lines().collect();
        assert_eq!(
            fields,
            [
                "std_msgs/Header header",
                "float32 angle_min",
                "float32 angle_max",
                "float32 angle_increment",
                "float32 time_increment",
                "float32 scan_time",
                "float32 range_min",
                "float32 range_max",
                "float32[] ranges",
                "float32[] intensities",
            ]
        );
        assert!(text.ends_with("MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"));
    }

    #[test]
    fn schema_names_are_package_msg_type() {
        for def in ALL {
            let parts: Vec<&str> = def.name.split('/').collect();
            assert_eq!(parts.len(), 3, "{}", def.name);
            assert_eq!(parts[1], "msg", "{}", def.name);
            assert!(def.text.ends_with('\n'), "{}", def.name);
        }
    }
}
