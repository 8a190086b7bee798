//! Prints the first `COUNT` laser scans arriving on `laser/scan` of bus
//! instance `INSTANCE`: sleeps until one arrives (no polling), then exits.
//!
//! ```text
//! echo_scan INSTANCE COUNT
//! ```

use smokenav_platform_bus::{Bus, BusOptions, WaitOutcome, Waiter, topics};
use std::time::{Duration, Instant};

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let instance = args.next().unwrap_or_else(|| "example".into());
    let count: usize = args.next().map(|c| c.parse()).transpose()?.unwrap_or(10);
    let bus = Bus::open(&BusOptions::new(&instance, "echo_scan"))?;
    let scans = bus.subscriber(topics::LASER_SCAN)?;
    let waiter = Waiter::new()?;
    let _attached = waiter.attach(&scans)?;
    println!("ready");
    let end = Instant::now() + Duration::from_secs(20);
    let mut seen = 0;
    while seen < count && Instant::now() < end {
        if waiter.wait(Some(Duration::from_millis(500)))? == WaitOutcome::Shutdown {
            break;
        }
        while let Some(scan) = scans.receive()? {
            println!(
                "scan seq {} with {} beams, first {:.3} m",
                scan.header.seq, scan.count, scan.ranges[0]
            );
            seen += 1;
        }
    }
    println!("received {seen}, lost {}", scans.stats().lost);
    anyhow::ensure!(seen >= count, "only {seen} of {count} scans arrived");
    Ok(())
}
