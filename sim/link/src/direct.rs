//! The world's sensor output as the drivers would publish it, without
//! emulators, PTYs or driver processes: for recordings made as fast as the CPU
//! allows (`smokenav-lab demo --fast`) and for tests of what comes after the drivers.
//!
//! Simulation replaces the device, never the driver: each world sample is put
//! into the device's own units the way its emulator does, and the drivers'
//! own pure cores turn it into messages, so no conversion rule exists twice:
//! * laser: the frame's millimetres through the Hokuyo driver's
//!   [`ScanConverter`] with the URG-04LX's PP geometry ([`Geometry::URG_04LX`]),
//!   stamped at the first beam as the driver does;
//! * Scout: a state reply in the robot's units (1/10 in, 1/10°, whole-inch
//!   sonar bytes) through the codec's [`DiffDrive::state_si`] and the Scout
//!   driver's `odometry` and `sonar_ring`;
//! * Pioneer: the emulated ARCOS controller's SIP for the world's pose and
//!   pings, through the driver's odometry integrator, `messages::odometry`
//!   and its `SonarAssembler`;
//! * smoke: the ADC counts through the smoke driver's own signal chain
//!   (`smokenav_smoke_driver::core::DriverCore`: baseline, filter, level, trend,
//!   state) at its publishing rate.
//!
//! Stamps are `t0_ns` + sim time. Each message comes with the time a driver
//! would have published it (a scan only once its sweep is complete).

use crate::base::{pioneer_config, pioneer_pose, pioneer_sonar_mm, scout_drive, scout_sonar_m};
use smokenav_hokuyo_codec::Geometry;
use smokenav_hokuyo_driver::{DriverConfig as LaserConfig, ScanConverter};
use smokenav_pioneer_codec::{Command as ArcosCommand, OdometryIntegrator, PacketBuf};
use smokenav_pioneer_driver::messages::{self, SonarAssembler, SonarGeometry};
use smokenav_pioneer_emulator::ArcosRobot;
use smokenav_platform_config::{Platform, RobotConfig};
use smokenav_scout_codec::units::{
    CPU_VOLTAGE_RANGE, MOTOR_VOLTAGE_RANGE, m_to_tenth_inches, rad_to_heading, sonar_byte,
    voltage_raw,
};
use smokenav_scout_codec::{Battery, DiffDrive, MotorStatus, StateReply, WheelSpeeds};
use smokenav_shared_types::{Header, LaserScan, MAX_SONARS, Odometry, SmokeReading, SonarRing};
use smokenav_sim_world::{LaserFrame, OdometrySample, SmokeSample, SonarSample, StepOutput};
use smokenav_smoke_driver::core::DriverCore;
use smokenav_smoke_driver::link::LinkEvent;
use smokenav_smoke_driver::settings::Settings;
use smokenav_smoke_emulator::AdcScale;

/// Sonar frame id, as both base drivers stamp their rings.
const SONAR_FRAME: &str = "base_link";
/// Battery of the emulated bases (the Scout model's defaults).
const SCOUT_CPU_V: f64 = 11.5;
const SCOUT_MOTOR_V: f64 = 12.3;

#[derive(Debug, thiserror::Error)]
pub enum DirectError {
    #[error("[smoke] section: {0}")]
    Smoke(String),
    #[error(transparent)]
    Base(#[from] crate::base::BaseError),
    #[error("Pioneer controller: {0}")]
    Pioneer(String),
}

/// One message as a driver would publish it.
#[derive(Debug, Clone)]
pub enum DirectMessage {
    Laser(Box<LaserScan>),
    Odometry(Odometry),
    Sonar(Box<SonarRing>),
    Smoke(SmokeReading),
}

impl DirectMessage {
    pub fn topic(&self) -> &'static str {
        match self {
            DirectMessage::Laser(_) => smokenav_shared_types::catalog::topic_names::LASER_SCAN,
            DirectMessage::Odometry(_) => smokenav_shared_types::catalog::topic_names::BASE_ODOM,
            DirectMessage::Sonar(_) => smokenav_shared_types::catalog::topic_names::BASE_SONAR,
            DirectMessage::Smoke(_) => smokenav_shared_types::catalog::topic_names::SMOKE_LEVEL,
        }
    }

    pub fn header(&self) -> &Header {
        match self {
            DirectMessage::Laser(m) => &m.header,
            DirectMessage::Odometry(m) => &m.header,
            DirectMessage::Sonar(m) => &m.header,
            DirectMessage::Smoke(m) => &m.header,
        }
    }
}

/// The base as its driver sees it.
enum Base {
    Scout {
        drive: DiffDrive,
        /// Latest ping per transducer as the emulator is fed it, m (NaN: no echo).
        sonar_m: [f64; MAX_SONARS],
        odom_frame: String,
        sonar_min_m: f32,
        sonar_max_m: f32,
        first: bool,
    },
    Pioneer {
        robot: Box<ArcosRobot>,
        max_mm: u16,
        odometry: OdometryIntegrator,
        sonar: Box<SonarAssembler>,
        odom_frame: String,
    },
}

/// Converts the world's output into driver messages.
pub struct DirectDrivers {
    t0_ns: u64,
    laser: ScanConverter,
    geometry: Geometry,
    skip_scans: u8,
    base: Base,
    smoke: DriverCore,
    adc: AdcScale,
    odom_seq: u64,
    sonar_seq: u64,
    smoke_seq: u64,
    events: Vec<(u64, u8, usize)>,
}

impl DirectDrivers {
    /// `profile` is the robot the world simulates (its smoke section decides
    /// the signal chain, e.g. `warmup_s`); `t0_ns` is the stamp of sim time 0.
    pub fn new(profile: &RobotConfig, t0_ns: u64) -> Result<Self, DirectError> {
        let settings = Settings::new(&profile.smoke, Some("/dev/null"), None)
            .map_err(|e| DirectError::Smoke(e.to_string()))?;
        let mut smoke =
            DriverCore::new(&settings, t0_ns).map_err(|e| DirectError::Smoke(e.to_string()))?;
        let _ = smoke.on_event(&LinkEvent::Connected {
            stamp_ns: t0_ns,
            device: "simulated".into(),
        });
        let base = match profile.robot.platform {
            Platform::Scout => Base::Scout {
                drive: scout_drive(profile)?,
                sonar_m: [f64::NAN; MAX_SONARS],
                odom_frame: profile.base.odom_frame.clone(),
                sonar_min_m: profile.sonar.min_range_m as f32,
                sonar_max_m: smokenav_scout_codec::units::SONAR_MAX_RANGE_M as f32,
                first: true,
            },
            Platform::Pioneer => {
                let cfg = pioneer_config(profile);
                let max_mm = cfg.sonar_max_mm;
                let mut robot =
                    ArcosRobot::new(cfg).map_err(|e| DirectError::Pioneer(e.to_string()))?;
                // Connected, streaming, motors on: where the driver's handshake leaves it.
                robot.open_stale_session();
                robot.set_external_motion(true);
                let mut enable = PacketBuf::new();
                ArcosCommand::Enable(true)
                    .encode(&mut enable)
                    .map_err(|e| DirectError::Pioneer(e.to_string()))?;
                robot.on_packet(enable.payload(), 0, &mut |_| {});
                for i in 0..usize::from(profile.sonar.count) {
                    robot.set_sonar_range(i, max_mm);
                }
                let params = *robot.params();
                // The driver connects before the world runs: its baseline is the idle robot's SIP.
                robot.set_pose(pioneer_pose(&smokenav_sim_world::Pose2::default()));
                let mut odometry = OdometryIntegrator::new(params);
                odometry.update(&robot.sip());
                let geometry = SonarGeometry {
                    indices: profile.sonar.transducers.iter().map(|t| t.index).collect(),
                    max_range_m: profile.sonar.max_range_m as f32,
                    min_range_m: profile.sonar.min_range_m as f32,
                };
                Base::Pioneer {
                    robot: Box::new(robot),
                    max_mm,
                    odometry,
                    sonar: Box::new(SonarAssembler::new(geometry, params.range_conv)),
                    odom_frame: profile.base.odom_frame.clone(),
                }
            }
        };
        let laser_cfg = LaserConfig::from_section(&profile.laser, None);
        Ok(Self {
            t0_ns,
            laser: ScanConverter::new(&laser_cfg.frame_id),
            geometry: Geometry::URG_04LX,
            skip_scans: laser_cfg.stream.skip_scans,
            base,
            smoke,
            adc: settings.adc,
            odom_seq: 0,
            sonar_seq: 0,
            smoke_seq: 0,
            events: Vec::new(),
        })
    }

    /// Converts one step's output, in the order the drivers would publish it;
    /// `emit` gets (publish time, message).
    pub fn convert(&mut self, out: &StepOutput, mut emit: impl FnMut(u64, DirectMessage)) {
        let period = (self.geometry.scan_period_s() * 1e9) as u64;
        // (time, kind, index): kinds in the order a tie is resolved.
        let mut events = std::mem::take(&mut self.events);
        events.clear();
        events.extend(out.sonar.iter().enumerate().map(|(i, s)| (s.t_ns, 0, i)));
        events.extend(out.odometry.iter().enumerate().map(|(i, s)| (s.t_ns, 1, i)));
        events.extend(out.smoke.iter().enumerate().map(|(i, s)| (s.t_ns, 2, i)));
        events.extend(
            out.laser
                .iter()
                .enumerate()
                .map(|(i, f)| (f.t_ns + period, 3, i)),
        );
        events.sort_unstable();
        for &(t, kind, i) in &events {
            match kind {
                0 => self.ping(&out.sonar[i]),
                1 => {
                    let (odom, ring) = self.base_cycle(&out.odometry[i]);
                    if let Some(o) = odom {
                        emit(self.t0_ns + t, DirectMessage::Odometry(o));
                    }
                    if let Some(r) = ring {
                        emit(self.t0_ns + t, DirectMessage::Sonar(Box::new(r)));
                    }
                }
                2 => {
                    if let Some(r) = self.smoke(&out.smoke[i]) {
                        emit(self.t0_ns + t, DirectMessage::Smoke(r));
                    }
                }
                _ => {
                    let scan = self.laser(&out.laser[i]);
                    emit(self.t0_ns + t, DirectMessage::Laser(scan));
                }
            }
        }
        self.events = events;
    }
    /// The Hokuyo driver's `LaserScan` for one frame.
    pub fn laser(&mut self, f: &LaserFrame) -> Box<LaserScan> {
        let g = self.geometry;
        for (slot, &mm) in self.laser.buffers().0.iter_mut().zip(f.ranges_mm.iter()) {
            *slot = u32::from(mm);
        }
        // The frame starts at step 0; the sensor stamps the rear of its sweep.
        let rear_to_step0 = (g.time_from_rear_s(0) * 1e9).round() as u64;
        let rear = (self.t0_ns + f.t_ns).saturating_sub(rear_to_step0);
        Box::new(*self.laser.convert_streamed(&g, self.skip_scans, rear))
    }

    /// One ping reaches the device (it reports the latest per transducer).
    fn ping(&mut self, s: &SonarSample) {
        match &mut self.base {
            Base::Scout { sonar_m, .. } => {
                if let Some(slot) = sonar_m.get_mut(usize::from(s.index)) {
                    *slot = scout_sonar_m(s.range_m, s.saturated);
                }
            }
            Base::Pioneer { robot, max_mm, .. } => robot.set_sonar_range(
                usize::from(s.index),
                pioneer_sonar_mm(s.range_m, s.saturated, *max_mm),
            ),
        }
    }

    /// One controller cycle at the world's odometry sample: what the base
    /// reports, through its driver's conversion.
    fn base_cycle(&mut self, o: &OdometrySample) -> (Option<Odometry>, Option<SonarRing>) {
        let stamp = self.t0_ns + o.t_ns;
        let (odom, ring) = match &mut self.base {
            Base::Scout {
                drive,
                sonar_m,
                odom_frame,
                sonar_min_m,
                sonar_max_m,
                first,
            } => {
                let wheels = WheelSpeeds {
                    left: o.left_mps,
                    right: o.right_mps,
                };
                let mut sonar_in = [0u8; 16];
                for (b, m) in sonar_in.iter_mut().zip(sonar_m.iter()) {
                    *b = sonar_byte(*m);
                }
                let reply = StateReply {
                    sonar_in,
                    x: m_to_tenth_inches(o.pose.x),
                    y: m_to_tenth_inches(o.pose.y),
                    heading: rad_to_heading(o.pose.theta),
                    velocity: drive.vm_args(wheels),
                    motor: MotorStatus::new(
                        wheels.left != 0.0,
                        wheels.right != 0.0,
                        Battery::High,
                        false,
                        false,
                        false,
                    ),
                    cpu_voltage_raw: voltage_raw(SCOUT_CPU_V, CPU_VOLTAGE_RANGE),
                    motor_voltage_raw: voltage_raw(SCOUT_MOTOR_V, MOTOR_VOLTAGE_RANGE),
                    ..Default::default()
                };
                let si = drive.state_si(&reply);
                let reset = std::mem::take(first);
                let odom = smokenav_scout_driver::core::odometry(
                    &si,
                    Header::new(stamp, self.odom_seq, odom_frame),
                    reset,
                );
                let ring = smokenav_scout_driver::core::sonar_ring(
                    &si,
                    Header::new(stamp, self.sonar_seq, SONAR_FRAME),
                    *sonar_min_m,
                    *sonar_max_m,
                );
                (Some(odom), Some(ring))
            }
            Base::Pioneer {
                robot,
                odometry,
                sonar,
                odom_frame,
                ..
            } => {
                robot.set_pose(pioneer_pose(&o.pose));
                let sip = robot.sip();
                let est = odometry.update(&sip);
                let odom =
                    messages::odometry(&est, &sip, stamp, self.odom_seq, odom_frame, est.baseline);
                let mut ring = None;
                sonar.add(sip.sonars.as_slice(), stamp, &mut |mut r: SonarRing| {
                    r.header = Header::new(r.header.stamp_ns, 0, SONAR_FRAME);
                    ring = Some(r);
                });
                if let Some(r) = &mut ring {
                    r.header.seq = self.sonar_seq;
                }
                (Some(odom), ring)
            }
        };
        self.odom_seq += u64::from(odom.is_some());
        self.sonar_seq += u64::from(ring.is_some());
        (odom, ring)
    }

    fn smoke(&mut self, s: &SmokeSample) -> Option<SmokeReading> {
        let stamp_ns = self.t0_ns + s.t_ns;
        let ev = match self.adc.measure_counts(i64::from(s.adc_counts)) {
            Ok(measurement) => LinkEvent::Sample {
                stamp_ns,
                measurement,
            },
            Err(error) => LinkEvent::OutOfRange { stamp_ns, error },
        };
        let mut r = self.smoke.on_event(&ev)?;
        r.header.seq = self.smoke_seq;
        self.smoke_seq += 1;
        Some(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_shared_types::SonarStatus;
    use smokenav_sim_world::{Scenario, World};
    use std::time::Duration;

    fn run(name: &str, secs: u64) -> Vec<(u64, DirectMessage)> {
        let scenario = Scenario::builtin(name).unwrap();
        let mut profile = scenario.profile.clone();
        profile.smoke.warmup_s = 0.0;
        let mut d = DirectDrivers::new(&profile, 1_000_000_000).unwrap();
        let mut w = World::new(scenario).unwrap();
        let mut msgs = Vec::new();
        let out = w.step(Duration::from_secs(secs));
        d.convert(&out, |t, m| msgs.push((t, m)));
        msgs
    }

    #[test]
    fn a_second_of_the_scout_world_gives_10_scans_rings_odometry_and_smoke() {
        let msgs = run("r32-light-puff", 1);
        let count = |topic: &str| msgs.iter().filter(|(_, m)| m.topic() == topic).count();
        // 100 ms scans: the one starting at 0.9 s completes at 1.0 s.
        assert_eq!(count("laser/scan"), 10);
        assert_eq!(count("base/odom"), 10);
        assert_eq!(count("base/sonar"), 10);
        assert_eq!(count("smoke/level"), 10);
        // Publish times never go back.
        assert!(msgs.windows(2).all(|w| w[0].0 <= w[1].0));
        let DirectMessage::Laser(scan) = &msgs
            .iter()
            .find(|(_, m)| m.topic() == "laser/scan")
            .unwrap()
            .1
        else {
            unreachable!()
        };
        assert_eq!(scan.count, 682);
        // Stamp of the first beam: t0 + 44 steps of 97.66 µs.
        assert_eq!(scan.header.stamp_ns, 1_000_000_000 + 4_296_875);
        assert!(
            scan.valid_ranges().count() > 300,
            "the R3.2 walls are in range"
        );
        let rings: Vec<&SonarRing> = msgs
            .iter()
            .filter_map(|(_, m)| match m {
                DirectMessage::Sonar(r) => Some(&**r),
                _ => None,
            })
            .collect();
        assert!(rings.iter().all(|r| r.len() == 16));
        // Scout ranges are whole inches.
        let last = rings.last().unwrap();
        for r in last.readings().iter().filter_map(|r| r.valid_range()) {
            let inches = f64::from(r) / 0.0254;
            assert!((inches - inches.round()).abs() < 1e-3, "{r}");
        }
    }

    #[test]
    fn pioneer_rings_carry_the_eight_front_sonars_in_millimetres() {
        let msgs = run("corridor", 2);
        let ring = msgs
            .iter()
            .rev()
            .find_map(|(_, m)| match m {
                DirectMessage::Sonar(r) => Some(&**r),
                _ => None,
            })
            .unwrap();
        assert_eq!(ring.len(), 8);
        assert_eq!(ring.max_range, 5.0);
        // In the corridor the ±90° sonars see the walls; the oblique ones saturate (SmokeNav (Santos et al. 2015), Fig. 5).
        assert_eq!(ring.by_index(0).unwrap().status(), SonarStatus::Valid);
        assert_eq!(ring.by_index(7).unwrap().status(), SonarStatus::Valid);
    }

    #[test]
    fn smoke_goes_through_the_driver_chain_and_becomes_ready() {
        let msgs = run("mrl-clean", 8);
        let smoke: Vec<&SmokeReading> = msgs
            .iter()
            .filter_map(|(_, m)| match m {
                DirectMessage::Smoke(r) => Some(r),
                _ => None,
            })
            .collect();
        assert_eq!(smoke.len(), 80);
        // Baseline calibrated over the first 5 s of clean air, then ready at level ≈ 0.
        let last = smoke.last().unwrap();
        assert!(last.is_ready(), "{:?}", last.state());
        assert!(
            (last.baseline_mv - 3000.0).abs() < 10.0,
            "{}",
            last.baseline_mv
        );
        assert!(last.level.abs() < 10.0, "{}", last.level);
    }
}
