//! A test scan source whose every beam is predictable, and the checker that
//! proves a published `LaserScan` carries exactly what was fed: the driver
//! tests and the workspace's end-to-end tests share both.
//!
//! Scan k: beam i = 300 + (7·i + 13·k) mod 5000 mm, except sensor error codes
//! 0 at beam 5 and 7 at beam 6, so beam 0 identifies k (mod 5000).

use smokenav_hokuyo_codec::Geometry;
use smokenav_shared_types::laser::{BeamReading, LaserScan};

/// Fills `ranges` with scan `k` of the pattern (a [`crate::ScanSource`] as a function).
pub fn pattern(k: u64, ranges: &mut [u16]) {
    for (i, r) in ranges.iter_mut().enumerate() {
        *r = match i {
            5 => 0,
            6 => 7,
            _ => 300 + ((7 * i as u64 + 13 * k) % 5000) as u16,
        };
    }
}

/// Checks every beam of a scan published from an emulated URG-04LX fed with
/// [`pattern`], and the layout its PP defines; returns k (mod 5000).
/// Panics, naming the beam, on any difference.
pub fn check_pattern_scan(scan: &LaserScan) -> u64 {
    assert_eq!(scan.count, 682, "URG-04LX PP: AMIN 44 .. AMAX 725");
    assert_eq!(scan.header.frame_id.as_str(), "laser");
    // Angles from PP: (44 − AFRT 384)·2π/ARES 1024, increment 2π/1024.
    let tau = std::f64::consts::TAU;
    assert!((f64::from(scan.angle_min) - (-340.0 * tau / 1024.0)).abs() < 1e-6);
    assert!((f64::from(scan.angle_increment) - tau / 1024.0).abs() < 1e-7);
    assert!((f64::from(scan.angle_max()) - (341.0 * tau / 1024.0)).abs() < 1e-5);
    // 600 rpm: 100 ms per scan, 97.66 µs per step; DMIN 20 mm, DMAX 5600 mm.
    assert!((scan.scan_time - 0.1).abs() < 1e-6);
    assert!((f64::from(scan.time_increment) - 0.1 / 1024.0).abs() < 1e-9);
    assert_eq!((scan.range_min, scan.range_max), (0.02, 5.6));
    let b0 = match scan.beam(0) {
        BeamReading::Range(r) => (r * 1000.0).round() as u64,
        other => panic!("beam 0 is {other:?}"),
    };
    // 13·k ≡ b0 − 300 (mod 5000) and 13⁻¹ ≡ 3077 (mod 5000).
    let k = ((b0 - 300) * 3077) % 5000;
    let mut fed = vec![0u16; Geometry::URG_04LX.step_count()];
    pattern(k, &mut fed);
    for (i, &mm) in fed.iter().enumerate() {
        let want = match mm {
            0 => BeamReading::SensorCode(0),
            7 => BeamReading::SensorCode(7),
            mm => BeamReading::Range(f32::from(mm) / 1000.0),
        };
        assert_eq!(scan.beam(i), want, "scan {k} beam {i}");
    }
    k
}
