//! The world's sensor output as the drivers would publish it, without
//! emulators, PTYs or driver processes: for recordings made as fast as the CPU
//! allows (`smokenav-lab demo --fast`) and for tests of what comes after the drivers.
//!
//! What each driver does to its device's data is reproduced here:
//! * laser: the URG-04LX's millimetres classified against DMIN/DMAX (values
//!   below DMIN are error codes), angles and timing from the PP geometry,
//!   stamped at the first beam as the Hokuyo driver does;
//! * base: one odometry message and one sonar ring per controller cycle
//!   (the world's odometry rate), the sonar ranges in the device's own units
//!   (whole inches on the Scout, millimetres on the Pioneer) and classified
//!   as the drivers do (no echo ⇒ saturated at the maximum, below the minimum
//!   ⇒ invalid);
//! * smoke: the ADC counts through the smoke driver's own signal chain
//!   (`smokenav_smoke_driver::core::DriverCore`: baseline, filter, level, trend,
//!   state) at its publishing rate.
//!
//! Stamps are `t0_ns` + sim time. Each message comes with the time a driver
//! would have published it (a scan only once its sweep is complete).

use smokenav_hokuyo_codec::{Geometry, Reading};
use smokenav_platform_config::{Platform, RobotConfig};
use smokenav_scout_codec::units::{SONAR_MAX_RANGE_M, SONAR_NO_ECHO, sonar_byte};
use smokenav_shared_types::{
    BeamReading, Header, LaserScan, MAX_SONARS, Odometry, OdometryFlags, SmokeReading,
    SonarReading, SonarRing, SonarStatus,
};
use smokenav_sim_world::{LaserFrame, OdometrySample, SmokeSample, SonarSample, StepOutput};
use smokenav_smoke_driver::core::DriverCore;
use smokenav_smoke_driver::link::LinkEvent;
use smokenav_smoke_driver::settings::Settings;
use smokenav_smoke_emulator::AdcScale;

/// The URG-04LX as its PP reply describes it.
pub const URG_04LX: Geometry = Geometry {
    dmin_mm: 20,
    dmax_mm: 5600,
    ares: 1024,
    amin: 44,
    amax: 725,
    afrt: 384,
    scan_rpm: 600,
};

const METRES_PER_INCH: f64 = 0.0254;

#[derive(Debug, thiserror::Error)]
pub enum DirectError {
    #[error("[smoke] section: {0}")]
    Smoke(String),
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
            DirectMessage::Laser(_) => smokenav_platform_bus::topics::LASER_SCAN,
            DirectMessage::Odometry(_) => smokenav_platform_bus::topics::BASE_ODOM,
            DirectMessage::Sonar(_) => smokenav_platform_bus::topics::BASE_SONAR,
            DirectMessage::Smoke(_) => smokenav_platform_bus::topics::SMOKE_LEVEL,
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

/// Converts the world's output into driver messages.
pub struct DirectDrivers {
    t0_ns: u64,
    platform: Platform,
    laser_frame: String,
    odom_frame: String,
    geometry: Geometry,
    sonar_indices: Vec<u8>,
    sonar_min_m: f32,
    sonar_max_m: f32,
    /// Latest ping per transducer, in device units (Scout: inches, Pioneer: mm; 0 = none yet).
    latest: [Option<SonarSample>; MAX_SONARS],
    smoke: DriverCore,
    adc: AdcScale,
    laser_seq: u64,
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
        let mut sonar_indices: Vec<u8> = profile
            .sonar
            .transducers
            .iter()
            .map(|t| t.index)
            .filter(|&i| usize::from(i) < MAX_SONARS)
            .collect();
        sonar_indices.sort_unstable();
        Ok(Self {
            t0_ns,
            platform: profile.robot.platform,
            laser_frame: profile.laser.frame_id.clone(),
            odom_frame: profile.base.odom_frame.clone(),
            geometry: URG_04LX,
            sonar_indices,
            sonar_min_m: profile.sonar.min_range_m as f32,
            sonar_max_m: match profile.robot.platform {
                Platform::Scout => SONAR_MAX_RANGE_M as f32,
                Platform::Pioneer => profile.sonar.max_range_m as f32,
            },
            latest: [None; MAX_SONARS],
            smoke,
            adc: settings.adc,
            laser_seq: 0,
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
                0 => {
                    let s = out.sonar[i];
                    if let Some(slot) = self.latest.get_mut(usize::from(s.index)) {
                        *slot = Some(s);
                    }
                }
                1 => {
                    let o = out.odometry[i];
                    emit(self.t0_ns + t, DirectMessage::Odometry(self.odometry(&o)));
                    let ring = self.sonar_ring(o.t_ns);
                    emit(self.t0_ns + t, DirectMessage::Sonar(Box::new(ring)));
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
        let g = &self.geometry;
        let mut s: Box<LaserScan> = Box::default();
        // Step s of the frame was measured at t + s · step time; stamp the first beam.
        let first =
            self.t0_ns + f.t_ns + (f64::from(g.amin) * g.step_time_s() * 1e9).round() as u64;
        s.header = Header::new(first, self.laser_seq, &self.laser_frame);
        self.laser_seq += 1;
        s.angle_min = g.step_angle(g.amin) as f32;
        s.angle_increment = g.step_rad() as f32;
        s.time_increment = g.step_time_s() as f32;
        s.scan_time = g.scan_period_s() as f32;
        s.range_min = g.dmin_mm as f32 / 1000.0;
        s.range_max = g.dmax_mm as f32 / 1000.0;
        let n = f.ranges_mm.len().min(g.step_count());
        s.count = n as u32;
        for (i, &mm) in f.ranges_mm.iter().take(n).enumerate() {
            let reading = match g.classify(u32::from(mm)) {
                Reading::Range(mm) => BeamReading::Range(mm as f32 / 1000.0),
                Reading::BeyondMax(_) => BeamReading::BeyondMax,
                Reading::Code(c) => BeamReading::SensorCode(c as u16),
            };
            s.set_beam(i, reading);
        }
        s
    }

    fn odometry(&mut self, o: &OdometrySample) -> Odometry {
        // The controllers report in their own units: the Scout in 1/10 in and 1/10°,
        // the Pioneer in mm and 1/4096 of a turn.
        let (lin, ang) = match self.platform {
            Platform::Scout => (METRES_PER_INCH / 10.0, 0.1f64.to_radians()),
            Platform::Pioneer => (0.001, std::f64::consts::TAU / 4096.0),
        };
        let q = |v: f64, step: f64| (v / step).round() * step;
        let mut flags = OdometryFlags::MOTORS_ENABLED;
        if o.stalled {
            flags |= OdometryFlags::LEFT_STALL | OdometryFlags::RIGHT_STALL;
        }
        let msg = Odometry {
            header: Header::new(self.t0_ns + o.t_ns, self.odom_seq, &self.odom_frame),
            x: q(o.pose.x, lin),
            y: q(o.pose.y, lin),
            theta: smokenav_shared_types::odom::normalize_angle(q(o.pose.theta, ang)),
            linear: o.linear_mps,
            angular: o.angular_rps,
            flags,
            bumpers: 0,
            battery_v: 0.0,
            _reserved: 0,
        };
        self.odom_seq += 1;
        msg
    }

    fn sonar_ring(&mut self, t_ns: u64) -> SonarRing {
        let mut ring = SonarRing {
            header: Header::new(self.t0_ns + t_ns, self.sonar_seq, "base_link"),
            max_range: self.sonar_max_m,
            ..Default::default()
        };
        self.sonar_seq += 1;
        for &index in &self.sonar_indices {
            let ping = self.latest.get(usize::from(index)).copied().flatten();
            let reading = match (self.platform, ping) {
                (_, None) => SonarReading::new(index, self.sonar_max_m, SonarStatus::Saturated),
                (Platform::Scout, Some(p)) => {
                    let byte = if p.saturated {
                        SONAR_NO_ECHO
                    } else {
                        sonar_byte(p.range_m)
                    };
                    if byte == SONAR_NO_ECHO {
                        SonarReading::new(index, self.sonar_max_m, SonarStatus::Saturated)
                    } else {
                        let m = (f64::from(byte) * METRES_PER_INCH) as f32;
                        classify(index, m, self.sonar_min_m, self.sonar_max_m)
                    }
                }
                (Platform::Pioneer, Some(p)) => {
                    let mm = (p.range_m * 1000.0).round();
                    if p.saturated || mm >= f64::from(self.sonar_max_m) * 1000.0 {
                        SonarReading::new(index, self.sonar_max_m, SonarStatus::Saturated)
                    } else if mm <= 0.0 {
                        SonarReading::new(index, 0.0, SonarStatus::Invalid)
                    } else {
                        SonarReading::new(index, (mm / 1000.0) as f32, SonarStatus::Valid)
                    }
                }
            };
            ring.push(reading);
        }
        ring
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

/// The Scout driver's rule: below the Polaroid's minimum a byte is invalid, at the cap saturated.
fn classify(index: u8, m: f32, min: f32, max: f32) -> SonarReading {
    if m >= max {
        SonarReading::new(index, max, SonarStatus::Saturated)
    } else if m < min {
        SonarReading::new(index, m, SonarStatus::Invalid)
    } else {
        SonarReading::new(index, m, SonarStatus::Valid)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
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
            let inches = f64::from(r) / METRES_PER_INCH;
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
