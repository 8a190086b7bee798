//! Publishes `COUNT` laser scans on `laser/scan` of bus instance `INSTANCE`, at 10 Hz.
//!
//! ```text
//! publish_scan INSTANCE COUNT
//! ```

use smokenav_platform_bus::{Bus, BusOptions, topics};
use smokenav_shared_types::{Header, LaserScan};
use std::time::Duration;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let instance = args.next().unwrap_or_else(|| "example".into());
    let count: u64 = args.next().map(|c| c.parse()).transpose()?.unwrap_or(10);
    let bus = Bus::open(&BusOptions::new(&instance, "publish_scan"))?;
    // The topic constant carries its type: publishing anything but a
    // LaserScan on it does not compile.
    let mut scans = bus.publisher(topics::LASER_SCAN)?;
    // Give a subscriber started at the same time a moment to connect.
    std::thread::sleep(Duration::from_millis(500));
    for seq in 0..count {
        // Fill the shared-memory sample in place: no copy of the 1081-beam arrays.
        scans.publish_with(|s: &mut LaserScan| {
            s.header = Header::new(seq * 100_000_000, seq, "laser");
            s.angle_min = -2.0;
            s.angle_increment = 0.01;
            s.range_min = 0.02;
            s.range_max = 5.6;
            s.count = 400;
            for (i, r) in s.ranges[..400].iter_mut().enumerate() {
                *r = 1.0 + seq as f32 + i as f32 * 0.001;
            }
        })?;
        std::thread::sleep(Duration::from_millis(100));
    }
    println!("published {count}");
    Ok(())
}
