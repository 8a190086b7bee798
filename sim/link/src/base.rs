//! The robot base's emulator — an ARCOS controller (Pioneer 3-DX) or a Nomad
//! Scout, per the scenario's robot profile — fed from the world: the odometry
//! pose (with the world's wheel-odometry errors) and each sonar ping as it
//! happens; and read back: the velocity the driver commands.

use smokenav_pioneer_emulator as pioneer;
use smokenav_platform_config::{Platform, RobotConfig};
use smokenav_scout_codec::units::SONAR_MAX_RANGE_M;
use smokenav_scout_emulator as scout;
use smokenav_shared_types::Clock;
use smokenav_sim_world::Pose2;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Sonars of a Scout's ring (one state reply carries all of them).
const SCOUT_SONARS: usize = 16;

#[derive(Debug, thiserror::Error)]
pub enum BaseError {
    #[error("Pioneer emulator: {0}")]
    Pioneer(#[from] pioneer::EmulatorError),
    #[error("Scout emulator: {0}")]
    Scout(#[from] scout::EmulatorError),
    #[error("robot profile: platform scout needs a [base.scout] section")]
    ScoutOptions,
}

pub enum BaseEmulator {
    Pioneer {
        emu: pioneer::Emulator,
        handle: pioneer::EmulatorHandle,
        max_mm: u16,
    },
    Scout {
        emu: scout::ScoutEmulator,
        drive: scout::DiffDrive,
        ranges: [f64; SCOUT_SONARS],
    },
}

/// The ARCOS controller a profile's Pioneer is emulated as: its sonar count,
/// every transducer in every SIP (as AMRISim sends them), the profile's range cap.
pub fn pioneer_config(profile: &RobotConfig) -> pioneer::RobotConfig {
    let max_mm = (profile.sonar.max_range_m * 1000.0)
        .round()
        .clamp(1.0, f64::from(u16::MAX)) as u16;
    pioneer::RobotConfig {
        sonar_count: profile.sonar.count.min(16),
        sonar_mode: pioneer::SonarMode::All,
        sonar_max_mm: max_mm,
        ..pioneer::RobotConfig::default()
    }
}

/// The world's odometry pose as the controller's (mm).
pub fn pioneer_pose(pose: &Pose2) -> pioneer::Pose {
    pioneer::Pose::new(pose.x * 1000.0, pose.y * 1000.0, pose.theta)
}

/// A ping as the range a Pioneer transducer reports, mm (no echo: the cap).
pub fn pioneer_sonar_mm(range_m: f64, saturated: bool, max_mm: u16) -> u16 {
    if saturated || !range_m.is_finite() {
        max_mm
    } else {
        (range_m * 1000.0).round().clamp(1.0, f64::from(max_mm)) as u16
    }
}

/// The Scout's drive (track, `vm` argument order) from its profile.
pub fn scout_drive(profile: &RobotConfig) -> Result<scout::DiffDrive, BaseError> {
    let opts = profile.base.scout.as_ref().ok_or(BaseError::ScoutOptions)?;
    Ok(scout::DiffDrive::new(opts.track_m, opts.wheel_order))
}

/// A ping as the range the Scout emulator is fed, m (NaN: no echo).
pub fn scout_sonar_m(range_m: f64, saturated: bool) -> f64 {
    if saturated {
        f64::NAN
    } else {
        range_m.min(SONAR_MAX_RANGE_M)
    }
}

impl BaseEmulator {
    /// Starts the emulator of `profile`'s platform behind the symlink `link`.
    pub fn start(
        profile: &RobotConfig,
        link: &Path,
        clock: Arc<dyn Clock>,
        seed: u64,
    ) -> Result<Self, BaseError> {
        match profile.robot.platform {
            Platform::Pioneer => {
                let cfg = pioneer_config(profile);
                let max_mm = cfg.sonar_max_mm;
                let emu = pioneer::Emulator::pty_with_clock(link, cfg, clock)?;
                let handle = emu.handle();
                // The world integrates the motion (with its odometry errors); the controller only reports it.
                handle.set_external_motion(true);
                Ok(BaseEmulator::Pioneer {
                    emu,
                    handle,
                    max_mm,
                })
            }
            Platform::Scout => {
                let drive = scout_drive(profile)?;
                let cfg = scout::EmulatorConfig {
                    link_path: link.to_owned(),
                    drive,
                    kinematics: scout::Kinematics::External,
                    baud: Some(profile.base.baud),
                    seed: seed | 1,
                    clock,
                };
                let emu = scout::ScoutEmulator::start(cfg)?;
                Ok(BaseEmulator::Scout {
                    emu,
                    drive,
                    ranges: [f64::NAN; SCOUT_SONARS],
                })
            }
        }
    }

    pub fn platform(&self) -> Platform {
        match self {
            BaseEmulator::Pioneer { .. } => Platform::Pioneer,
            BaseEmulator::Scout { .. } => Platform::Scout,
        }
    }

    /// What a driver opens (the stable symlink).
    pub fn port(&self) -> String {
        match self {
            BaseEmulator::Pioneer { emu, .. } => emu.port_arg(),
            BaseEmulator::Scout { emu, .. } => emu.path().display().to_string(),
        }
    }

    /// The pseudo-terminal behind the symlink right now.
    pub fn device(&self) -> Option<PathBuf> {
        match self {
            BaseEmulator::Pioneer { handle, .. } => handle.status().link.device,
            BaseEmulator::Scout { emu, .. } => emu.device_path(),
        }
    }

    /// The controller's odometry pose (the world's odometry frame).
    pub fn set_odometry(&mut self, pose: &Pose2) {
        match self {
            BaseEmulator::Pioneer { handle, .. } => handle.set_pose(pioneer_pose(pose)),
            BaseEmulator::Scout { emu, .. } => {
                emu.set_pose(scout::Pose::new(pose.x, pose.y, pose.theta))
            }
        }
    }

    /// One sonar ping: transducer `index` read `range_m` (`saturated`: no echo).
    pub fn set_sonar(&mut self, index: u8, range_m: f64, saturated: bool) {
        match self {
            BaseEmulator::Pioneer { handle, max_mm, .. } => {
                handle.set_sonar_range(
                    usize::from(index),
                    pioneer_sonar_mm(range_m, saturated, *max_mm),
                );
            }
            BaseEmulator::Scout { emu, ranges, .. } => {
                if let Some(r) = ranges.get_mut(usize::from(index)) {
                    // NaN and ≥ 255 in read as "no echo" on the wire.
                    *r = scout_sonar_m(range_m, saturated);
                    emu.set_sonar_m(ranges);
                }
            }
        }
    }

    /// Every transducer reports no echo (before the world runs).
    pub fn clear_sonar(&mut self, count: u8) {
        for i in 0..count {
            self.set_sonar(i, f64::NAN, true);
        }
    }

    /// The body velocity (m/s, rad/s) the driver has the base running at now:
    /// zero with the motors off, after a watchdog stop or an e-stop.
    pub fn commanded(&self) -> (f64, f64) {
        match self {
            BaseEmulator::Pioneer { handle, .. } => {
                let st = handle.status().robot;
                if st.motors_enabled && !st.watchdog_tripped {
                    (st.commanded.trans / 1000.0, st.commanded.rot.to_radians())
                } else {
                    (0.0, 0.0)
                }
            }
            BaseEmulator::Scout { emu, drive, .. } => drive.body_for(emu.snapshot().wheels),
        }
    }
}
