//! The Scout driver's loop against the emulated robot on a real PTY, in
//! this test process: no bus, no driver process (the workspace's
//! tests/tests/scout_e2e.rs covers those).

use smokenav_scout_codec::{DiffDrive, StateSi, WheelOrder};
use smokenav_scout_driver::{
    CoreConfig, Driver, DriverConfig, DriverEvent, DriverSink, DriverStatus, PortSpec, ScoutCore,
};
use smokenav_scout_emulator::{EmulatorConfig, ScoutEmulator};
use smokenav_shared_types::clock::monotonic_now_ns;
use smokenav_shared_types::{Odometry, OdometryFlags, SonarRing, VelocityCommand};
use std::time::{Duration, Instant};

/// Records what the loop does; `step` decides, after each cycle, whether to stop.
struct Sink<'e> {
    emu: &'e ScoutEmulator,
    odoms: Vec<Odometry>,
    events: Vec<String>,
    command: Option<f64>,
    deadline: Instant,
    step: Box<dyn FnMut(&mut Sink<'e>) -> bool + 'e>,
}

impl DriverSink for Sink<'_> {
    fn wait_until(&mut self, until: Instant, core: &mut ScoutCore) -> anyhow::Result<()> {
        if let Some(v) = self.command {
            let cmd = VelocityCommand {
                linear: v,
                ..Default::default()
            };
            core.on_velocity(&cmd, monotonic_now_ns());
        }
        std::thread::sleep(until.saturating_duration_since(Instant::now()));
        Ok(())
    }

    fn publish(
        &mut self,
        odom: &Odometry,
        ring: &SonarRing,
        _si: &StateSi,
        _received: Instant,
    ) -> anyhow::Result<()> {
        assert_eq!(ring.len(), 16);
        self.odoms.push(*odom);
        Ok(())
    }

    fn event(&mut self, event: DriverEvent<'_>) {
        self.events.push(format!("{event:?}"));
    }

    fn idle(&mut self, _status: &DriverStatus<'_>) -> bool {
        let mut step = std::mem::replace(&mut self.step, Box::new(|_| true));
        let stop = step(self) || Instant::now() > self.deadline;
        self.step = step;
        stop
    }
}

fn driver(emu: &ScoutEmulator) -> Driver {
    let core = ScoutCore::new(CoreConfig::scout_defaults(DiffDrive::new(
        0.345,
        WheelOrder::RightLeft,
    )));
    Driver::new(
        core,
        DriverConfig {
            port: PortSpec::Serial(emu.path().to_string_lossy().into_owned()),
            baud: 38_400,
            period: Duration::from_millis(100),
            link_timeout: Duration::from_secs(1),
        },
    )
}

fn start() -> (tempfile::TempDir, ScoutEmulator) {
    let dir = tempfile::tempdir().unwrap();
    let emu = ScoutEmulator::start(EmulatorConfig::new(dir.path().join("scout"))).unwrap();
    (dir, emu)
}

#[test]
fn loop_configures_the_robot_drives_it_and_stops_it_on_exit() {
    let (_d, emu) = start();
    let mut drv = driver(&emu);
    let mut sink = Sink {
        emu: &emu,
        odoms: vec![],
        events: vec![],
        command: Some(0.254),
        deadline: Instant::now() + Duration::from_secs(10),
        step: Box::new(|s| s.odoms.len() >= 15),
    };
    drv.run(&mut sink).unwrap();
    assert_eq!(sink.odoms.len(), 15, "{:?}", sink.events);
    assert_eq!(sink.events[0], "Connected { first: true }");
    assert!(sink.odoms[0].flags & OdometryFlags::RESET != 0);
    assert!(
        sink.odoms[1..]
            .iter()
            .all(|o| o.flags & OdometryFlags::RESET == 0)
    );
    // 0.254 m/s = vm(100, 100): the robot reports it, and has moved.
    let last = sink.odoms.last().unwrap();
    assert!((last.linear - 0.254).abs() < 1e-9, "{last:?}");
    assert!(last.x > 0.1, "{last:?}");
    let stats = emu.stats();
    assert_eq!((stats.conf_timeout, stats.conf_sonar), (1, 1));
    assert!(stats.velocity >= 10);
    // `st` on the way out: the robot is left standing.
    assert_eq!(stats.stop, 1);
    assert_eq!(emu.snapshot().wheels.left, 0.0);
}

#[test]
fn unplugged_robot_is_reopened_and_odometry_resumes_flagged_reset() {
    let (_d, emu) = start();
    let mut drv = driver(&emu);
    let mut phase = 0;
    let mut sink = Sink {
        emu: &emu,
        odoms: vec![],
        events: vec![],
        command: None,
        deadline: Instant::now() + Duration::from_secs(15),
        step: Box::new(move |s| {
            match phase {
                0 if s.odoms.len() >= 5 => {
                    s.emu.disconnect();
                    phase = 1;
                }
                1 if s.events.iter().any(|e| e.starts_with("Lost")) => {
                    std::thread::sleep(Duration::from_millis(600));
                    s.emu.reconnect();
                    s.odoms.clear();
                    phase = 2;
                }
                2 if s.odoms.len() >= 3 => return true,
                _ => {}
            }
            false
        }),
    };
    drv.run(&mut sink).unwrap();
    assert_eq!(sink.odoms.len(), 3, "{:?}", sink.events);
    assert!(sink.odoms[0].flags & OdometryFlags::RESET != 0);
    assert!(
        sink.events
            .iter()
            .any(|e| e == "Connected { first: false }"),
        "{:?}",
        sink.events
    );
    let link = drv.link();
    assert!(link.is_up());
    assert_eq!(link.counters().reconnects(), 1);
    assert_eq!(link.counters().losses, 1);
    // Reconfigured after the replug (watchdog, sonar) but not re-zeroed.
    assert_eq!(emu.stats().conf_timeout, 2);
    assert_eq!(emu.stats().define, 2);
}
