//! A low rate and a process's own condition at once: the condition's
//! reason is what `health/<role>` says, and the rate coming back does not
//! wipe it (both once did: the SLAM process's "no odometry on base/odom"
//! never showed while its pose rate was low too, which a base driver gone
//! silent makes it).

use smokenav_platform_bus::{Bus, BusOptions, Subscriber, topics};
use smokenav_platform_runtime::HealthReporter;
use smokenav_shared_types::{Health, HealthState};
use std::time::{Duration, Instant};

fn published(sub: &Subscriber<Health>, h: &mut HealthReporter, at: Instant) -> Health {
    h.publish_now(at).unwrap();
    let mut last = None;
    while let Some(s) = sub.receive().unwrap() {
        last = Some(*s);
    }
    last.expect("the health just published")
}

/// What the SLAM process does each loop: its condition, as its own state.
fn flag(h: &mut HealthReporter, reason: &str) {
    h.error(reason);
    if h.own_state() == HealthState::Ok {
        h.set_state(HealthState::Degraded);
    }
}

#[test]
fn a_condition_is_named_while_a_rate_is_low_and_stays_when_the_rate_returns() {
    let instance = format!("rt_rate_cond_{}", std::process::id());
    let bus = Bus::open(&BusOptions::new(&instance, "test")).unwrap();
    let mut h = HealthReporter::new(&bus, "slam", Duration::from_secs(1)).unwrap();
    let sub = bus.subscriber::<Health>(topics::health("slam")).unwrap();
    let rate = h.add_rate("pose_hz", Some(10.0));
    h.set_state(HealthState::Ok);
    let t0 = Instant::now();
    let sec = |k: u64| t0 + Duration::from_secs(k);
    published(&sub, &mut h, sec(1));
    // No poses for a second: the low rate is published as Degraded.
    let low = published(&sub, &mut h, sec(2));
    assert_eq!(low.state(), HealthState::Degraded);
    assert!(low.last_error.as_str().starts_with("pose_hz 0.0 Hz"));
    assert_eq!(h.own_state(), HealthState::Ok, "the process set Ok");
    // The process's own condition now: its reason, not the rate's.
    flag(&mut h, "no odometry on base/odom");
    let both = published(&sub, &mut h, sec(3));
    assert_eq!(both.state(), HealthState::Degraded);
    assert_eq!(both.last_error.as_str(), "no odometry on base/odom");
    // The rate is back, the condition stays: still named.
    for _ in 0..20 {
        h.mark(rate);
    }
    flag(&mut h, "no odometry on base/odom");
    let back = published(&sub, &mut h, sec(4));
    assert_eq!(back.state(), HealthState::Degraded);
    assert_eq!(back.last_error.as_str(), "no odometry on base/odom");
}
