//! The Pioneer driver's loop against the emulated ARCOS controller on a real
//! PTY, in this test process: no bus, no driver process (the workspace's
//! tests/tests/pioneer_e2e.rs covers those).

use smokenav_pioneer_driver::link::parse_port;
use smokenav_pioneer_driver::messages::SonarGeometry;
use smokenav_pioneer_driver::motion::{MotionGuard, MotionLimits};
use smokenav_pioneer_driver::session::{Session, SessionConfig, SessionEvent};
use smokenav_pioneer_driver::{CoreCounters, Driver, DriverSink, Output, PioneerCore};
use smokenav_pioneer_emulator::{Emulator, RobotConfig};
use smokenav_platform_runtime::Reconnect;
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_shared_types::{Odometry, OdometryFlags};
use std::time::{Duration, Instant};

struct Sink<'e> {
    emu: &'e Emulator,
    odoms: Vec<(Instant, Odometry)>,
    rings: usize,
    running: bool,
    /// (linear m/s) sent every turn until this instant.
    drive_until: Option<Instant>,
    step: Box<dyn FnMut(&mut Sink<'e>) -> bool + 'e>,
    deadline: Instant,
}

impl DriverSink for Sink<'_> {
    fn commands(&mut self, core: &mut PioneerCore) -> anyhow::Result<()> {
        if self.drive_until.is_some_and(|t| Instant::now() < t) {
            core.on_velocity(0.3, 0.0, monotonic_now_ns());
        }
        Ok(())
    }

    fn output(&mut self, out: Output) -> anyhow::Result<()> {
        match out {
            Output::Odometry(o) => self.odoms.push((Instant::now(), o)),
            Output::Sonar(r) => {
                assert_eq!(r.len(), 8, "the profile's front ring");
                self.rings += 1;
            }
            Output::Event(e) => self.running |= *e == SessionEvent::Running,
        }
        Ok(())
    }

    fn lost(&mut self, _why: &str) {}

    fn idle(&mut self, _c: &CoreCounters, _l: &Reconnect) -> bool {
        let mut step = std::mem::replace(&mut self.step, Box::new(|_| true));
        let stop = step(self) || Instant::now() > self.deadline;
        self.step = step;
        stop
    }
}

fn driver(emu: &Emulator) -> Driver {
    let core = PioneerCore::new(
        Session::new(SessionConfig::default()),
        MotionGuard::new(
            Duration::from_millis(500),
            MotionLimits {
                max_linear_mps: 0.5,
                max_angular_dps: 60.0,
            },
        ),
        SonarGeometry {
            indices: (0..8).collect(),
            max_range_m: 5.0,
            min_range_m: 0.1,
        },
        "odom",
    );
    Driver::new(parse_port(&emu.port_arg(), 9600).unwrap(), core)
}

#[test]
fn loop_drives_the_robot_stops_it_when_commands_stop_and_closes_on_exit() {
    let dir = tempfile::tempdir().unwrap();
    let emu = Emulator::pty(&dir.path().join("pioneer"), RobotConfig::default()).unwrap();
    let h = emu.handle();
    let mut drv = driver(&emu);
    let stopped_after = std::rc::Rc::new(std::cell::Cell::new(None::<Duration>));
    let stopped = stopped_after.clone();
    let mut phase = 0;
    let mut sink = Sink {
        emu: &emu,
        odoms: vec![],
        rings: 0,
        running: false,
        drive_until: None,
        deadline: Instant::now() + Duration::from_secs(15),
        step: Box::new(move |s| {
            match phase {
                0 if s.running && s.odoms.len() >= 3 => {
                    s.drive_until = Some(Instant::now() + Duration::from_secs(1));
                    phase = 1;
                }
                1 if s.drive_until.is_some_and(|t| Instant::now() >= t) => phase = 2,
                2 => {
                    let quiet = s.drive_until.map(|t| t.elapsed()).unwrap_or_default();
                    if s.emu.handle().status().robot.commanded.trans == 0.0 {
                        stopped.set(Some(quiet));
                        phase = 3;
                    } else if quiet > Duration::from_secs(2) {
                        return true;
                    }
                }
                3 => return true,
                _ => {}
            }
            false
        }),
    };
    drv.run(&mut sink).unwrap();
    let stopped = stopped_after.get().expect("the robot was stopped");
    // The controller died (commands stopped): stopped within 500 ms (+ one turn).
    assert!(
        stopped < Duration::from_millis(600),
        "stopped after {stopped:?}"
    );
    assert!(sink.odoms[0].1.flags & OdometryFlags::RESET != 0);
    assert!(sink.rings >= 3);
    let last = sink.odoms.last().unwrap().1;
    assert!(last.x > 0.1, "drove 0.3 m/s for a second: {last:?}");
    assert_eq!(drv.link().counters().opens, 1);
    // CLOSE on the way out.
    std::thread::sleep(Duration::from_millis(100));
    assert!(h.status().robot.counters.closes >= 1);
    assert!(!h.status().robot.streaming);
}
