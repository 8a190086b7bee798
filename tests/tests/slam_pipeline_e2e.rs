//! Live == offline for SLAM: the same recording of fused scans and odometry
//! through the real `smokenav-slam` process over iceoryx2 and through the
//! offline path (`offline::replay` into a `SlamPipeline`, what the demo's
//! comparison runs) gives the same poses, bit for bit — the process with its
//! particles matched on a pool of two threads, the offline path on one.
//!
//! The recording is the first 200 scans of the MIT CSAIL log made into what
//! the robot's bus carries: each laser scan as a fused scan (a smoke level
//! rising from clear air to fog, so the smoke noise model changes the
//! matcher; some beams marked as painted from sonar), stamped 20 ms before the
//! odometry reading of its scan (so its odometry is interpolated), and an
//! odometry reset halfway (the frame jumps, flagged `RESET`).
//!
//! The test publisher replays in lock step (each pose comes back before the
//! next scan goes out), so the process never has two scans waiting and skips
//! none: every pose must be bit-identical. The first scan goes out before
//! the first odometry, as at start-up. `recording_e2e`'s replay of a
//! live run at full speed is the test that allows for skips under load.

use smokenav_algorithms_slam::carmen::LaserRecord;
use smokenav_algorithms_slam::offline::{Received, replay};
use smokenav_algorithms_slam::{BackendOptions, Pose2, SlamPipeline, SlamUpdate};
use smokenav_platform_bus::{Publisher, Waiter, topics};
use smokenav_platform_config::{MountPose, RobotConfig, SlamInput};
use smokenav_shared_types::{
    Clock, FusedScan, Header, MonotonicClock, Odometry, OdometryFlags, PoseEstimate, SectionSource,
};
use smokenav_tests::{
    Child, bin, csail_prefix, fill_carmen_scan, open_bus, pose_for_scan, profile, unique_instance,
};
use std::time::Duration;

/// The scan is stamped this long before the odometry reading of its record.
const SCAN_LEAD_NS: u64 = 20_000_000;
/// Record whose odometry starts a new frame.
const RESET_AT: usize = 100;

fn recording(records: &[LaserRecord], base_ns: u64) -> Vec<(Odometry, Box<FusedScan>)> {
    let ipc0 = records[0].ipc_timestamp_ns;
    let jump = Pose2::new(40.0, -12.0, 2.5);
    let reset_pose = records[RESET_AT].robot_pose;
    records
        .iter()
        .enumerate()
        .map(|(k, rec)| {
            let stamp = base_ns + SCAN_LEAD_NS + (rec.ipc_timestamp_ns - ipc0);
            // After the reset the wheels count from another origin.
            let pose = if k >= RESET_AT {
                jump.compose(&reset_pose.between(&rec.robot_pose))
            } else {
                rec.robot_pose
            };
            let odom = Odometry {
                header: Header::new(stamp, 0, "odom"),
                x: pose.x,
                y: pose.y,
                theta: pose.theta,
                flags: if k == RESET_AT {
                    OdometryFlags::RESET
                } else {
                    0
                },
                ..Default::default()
            };
            let mut f = Box::<FusedScan>::default();
            fill_carmen_scan(&mut f.scan, rec, stamp - SCAN_LEAD_NS);
            // Clear air to beyond SmokeNav's dense threshold over the log.
            f.smoke_level = 300.0 * k as f32 / records.len() as f32;
            if (60..140).contains(&k) {
                for i in (0..rec.ranges.len()).step_by(12) {
                    f.beam_source[i] = SectionSource::Sonar as u8;
                }
            }
            (odom, f)
        })
        .collect()
}

#[test]
fn slam_process_and_offline_pipeline_give_the_same_poses() -> anyhow::Result<()> {
    let instance = unique_instance("slam_pipeline_e2e");
    let dir = tempfile::tempdir()?;
    let cfg_path = profile(dir.path(), "pioneer-3dx.toml", |c| {
        c.slam.input = SlamInput::Fused;
        // Few particles keep a debug build quick.
        c.slam.particles = 10;
        // The process matches them on a pool; offline below on one thread.
        c.slam.threads = 2;
        // The CARMEN laser pose is the robot pose.
        c.laser.mount = MountPose {
            x: 0.0,
            y: 0.0,
            yaw_deg: 0.0,
        };
    });
    let mut slam = Child::spawn(
        &bin("smokenav-slam"),
        &["--config", cfg_path.to_str().unwrap(), "--backend", "rbpf"],
        &instance,
    )?;
    slam.wait_for_line(
        "rbpf with 10 particles on fusion/scan + base/odom, map every 1.0 s, particles matched on 2 threads",
        Duration::from_secs(30),
    )?;

    let bus = open_bus(&instance);
    let mut odom_pub: Publisher<Odometry> = bus.publisher(topics::BASE_ODOM)?;
    let mut scan_pub: Publisher<FusedScan> = bus.publisher(topics::FUSION_SCAN)?;
    let poses = bus.subscriber::<PoseEstimate>(topics::SLAM_POSE)?;
    let waiter = Waiter::new()?;
    let _g = waiter.attach(&poses)?;

    let records = csail_prefix();
    assert_eq!(records.len(), 200);
    let recorded = recording(&records, MonotonicClock.now_ns());
    // Live, in lock step; what was sent and when is the recording replayed offline.
    let mut received: Vec<(u64, Received<'_>)> = Vec::with_capacity(2 * recorded.len());
    let mut live = Vec::with_capacity(recorded.len());
    for (k, (odom, fused)) in recorded.iter().enumerate() {
        if k == 0 {
            // As at start-up, when the laser's first scan beats the base's
            // first odometry: the scan waits for it (it was once placed on
            // the origin, and the CSAIL odometry's x of 576 m taken as a drive).
            scan_pub.publish(fused)?;
            received.push((MonotonicClock.now_ns(), Received::Fused(fused)));
            std::thread::sleep(Duration::from_millis(30));
        }
        odom_pub.publish(odom)?;
        received.push((MonotonicClock.now_ns(), Received::Odometry(odom)));
        if k > 0 {
            scan_pub.publish(fused)?;
            received.push((MonotonicClock.now_ns(), Received::Fused(fused)));
        }
        live.push(
            pose_for_scan(&poses, &waiter, fused.scan.header.stamp_ns)
                .map_err(|e| anyhow::anyhow!("{e}; smokenav-slam said:\n{}", slam.output()))?,
        );
    }
    let status = slam.terminate(Duration::from_secs(10))?;
    assert!(status.success(), "{status:?}");
    assert_eq!(
        live.last().unwrap().scans_skipped,
        0,
        "lock step skips nothing"
    );

    // Offline: the profile the process read (but one thread), the pipeline the process runs.
    let mut cfg = RobotConfig::load(&cfg_path)?;
    cfg.slam.threads = 1;
    let m = &cfg.laser.mount;
    let mut pipeline = SlamPipeline::from_config(&cfg.slam, &BackendOptions::default())
        .with_sensor_pose(Pose2::new(m.x, m.y, m.yaw_rad()));
    let mut offline: Vec<SlamUpdate> = Vec::new();
    replay(&mut pipeline, received, |u| offline.push(*u));
    let stats = pipeline.stats();
    assert_eq!(stats.odom_resets, 1);
    assert_eq!(
        (stats.scans, stats.superseded, stats.no_odometry),
        (200, 0, 0)
    );

    assert_eq!(offline.len(), live.len());
    for (i, (o, l)) in offline.iter().zip(&live).enumerate() {
        assert_eq!(o.stamp_ns, l.header.stamp_ns, "scan {i}");
        assert_eq!(
            [o.pose.x, o.pose.y, o.pose.theta].map(f64::to_bits),
            [l.x, l.y, l.theta].map(f64::to_bits),
            "scan {i}: offline {:?}, live ({}, {}, {})",
            o.pose,
            l.x,
            l.y,
            l.theta
        );
        assert_eq!(
            o.covariance_row_major().map(f64::to_bits),
            l.covariance.map(f64::to_bits),
            "scan {i}"
        );
        assert_eq!((o.n_eff as f32).to_bits(), l.n_eff.to_bits(), "scan {i}");
    }
    // A trajectory, not one pose repeated, carried across the odometry reset:
    // the SLAM pose moves on smoothly where the odometry jumped 40 m.
    let (a, b) = (&offline[RESET_AT - 1].pose, &offline[RESET_AT].pose);
    assert!(
        (a.x - b.x).hypot(a.y - b.y) < 1.0,
        "the odometry jump leaked into SLAM: {a:?} → {b:?}"
    );
    // The first 200 scans of the CSAIL log lie within some 10 m.
    let far = offline
        .iter()
        .map(|u| u.pose.x.hypot(u.pose.y))
        .fold(0.0, f64::max);
    assert!(far < 25.0, "a pose {far:.0} m from the start");
    let (first, last) = (&offline[0].pose, &offline[offline.len() - 1].pose);
    assert!(
        (last.x - first.x).hypot(last.y - first.y) > 5.0,
        "{first:?} → {last:?}"
    );
    Ok(())
}
