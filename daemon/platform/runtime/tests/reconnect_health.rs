//! What [`Reconnect::report`] puts into the real `Health` a process
//! publishes, read back through the bus as `smokenav status` would.

use smokenav_platform_bus::{Bus, BusOptions, Subscriber, topics};
use smokenav_platform_runtime::{HealthReporter, Reconnect, ReconnectPolicy};
use smokenav_shared_types::{Health, HealthState};
use std::time::{Duration, Instant};

const MS: u64 = 1_000_000;

fn bus() -> Bus {
    let instance = format!("rt_reconnect_{}", std::process::id());
    Bus::open(&BusOptions::new(&instance, "test")).unwrap()
}

/// Publishes and reads back the report just made (the newest sample).
fn published(sub: &Subscriber<Health>, h: &mut HealthReporter) -> Health {
    h.publish_now(Instant::now()).unwrap();
    let mut last = None;
    while let Some(s) = sub.receive().unwrap() {
        last = Some(*s);
    }
    last.expect("the health just published")
}

#[test]
fn outage_shows_as_degraded_with_its_reason_and_clears_once_back() {
    let bus = bus();
    let mut h = HealthReporter::new(&bus, "drv", Duration::from_secs(1)).unwrap();
    let sub = bus.subscriber::<Health>(topics::health("drv")).unwrap();
    let policy = ReconnectPolicy::new(Duration::from_millis(100), Duration::from_millis(400));
    let mut link = Reconnect::new(policy, 0);
    link.open_failed(0, "No such file or directory");
    link.report(&mut h, "/dev/x", 0);
    let never = published(&sub, &mut h);
    assert_eq!(never.state(), HealthState::Error, "never up");
    assert_eq!(
        never.last_error.as_str(),
        "/dev/x: No such file or directory; reconnecting"
    );
    assert_eq!(never.metric("connect_failures"), Some(1.0));
    assert_eq!(never.metric("link_up"), Some(0.0));

    link.opened(100 * MS);
    h.set_state(HealthState::Ok);
    link.report(&mut h, "/dev/x", 100 * MS);
    let up = published(&sub, &mut h);
    assert_eq!(up.state(), HealthState::Ok);
    assert_eq!(up.last_error.as_str(), "", "the outage's error is cleared");
    assert_eq!(up.metric("link_up"), Some(1.0));

    link.lost(500 * MS, "device closed the link");
    link.report(&mut h, "/dev/x", 500 * MS);
    let lost = published(&sub, &mut h);
    assert_eq!(lost.state(), HealthState::Degraded);
    assert!(lost.last_error.as_str().contains("device closed the link"));
    assert_eq!(lost.metric("device_losses"), Some(1.0));

    // A driver's own error after the reconnect is not wiped.
    link.opened(700 * MS);
    h.error("sensor STAT: laser malfunction");
    link.report(&mut h, "/dev/x", 700 * MS);
    let back = published(&sub, &mut h);
    assert_eq!(back.last_error.as_str(), "sensor STAT: laser malfunction");
    assert_eq!(back.metric("reconnects"), Some(1.0));
    assert_eq!(back.metric("port_opens"), Some(2.0));
}
