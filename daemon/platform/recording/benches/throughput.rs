//! Encode + write and read + decode throughput of the recording library.
//!
//! `cargo bench -p smokenav-platform-recording --bench throughput`
//!
//! The message mix is one robot second at 10 Hz: a URG-04LX scan (682
//! beams), odometry, an 8-sonar ring, a smoke reading and a fused scan, plus
//! a health report per second. Written to a real file in a temporary directory.

use smokenav_platform_recording::{
    AnyMessageRef, Compression, Playback, Recorder, SinkOptions, SinkStats,
};
use smokenav_shared_types::{
    BeamReading, FusedScan, Header, Health, LaserScan, Odometry, SmokeReading, SonarReading,
    SonarRing, SonarStatus,
};
use std::collections::BTreeMap;
use std::io::BufWriter;
use std::time::Instant;

fn scan(seq: u64) -> LaserScan {
    let mut s = LaserScan {
        header: Header::new(seq * 100_000_000, seq, "laser"),
        angle_min: -2.094,
        angle_increment: 0.006_136,
        range_min: 0.02,
        range_max: 5.6,
        count: 682,
        ..Default::default()
    };
    for i in 0..682 {
        let k = i as u64 + seq;
        let r = if k.is_multiple_of(17) {
            BeamReading::SensorCode((k % 20) as u16)
        } else {
            BeamReading::Range(0.5 + ((k * 37) % 4000) as f32 / 1000.0)
        };
        s.set_beam(i, r);
    }
    s
}

fn ring(seq: u64) -> SonarRing {
    let mut r = SonarRing {
        header: Header::new(seq * 100_000_000 + 1, seq, "base_link"),
        max_range: 5.0,
        ..Default::default()
    };
    for i in 0..8 {
        r.push(SonarReading::new(
            i,
            1.0 + f32::from(i) * 0.1,
            SonarStatus::Valid,
        ));
    }
    r
}

fn record(path: &std::path::Path, seconds: u64, compression: Compression) -> (SinkStats, f64) {
    let f = BufWriter::new(std::fs::File::create(path).unwrap());
    let opts = SinkOptions {
        compression,
        ..Default::default()
    };
    let mut rec = Recorder::create(f, opts, None, &BTreeMap::new(), 0).unwrap();
    let mut fused = Box::<FusedScan>::default();
    let mut health = Health::new("hokuyo", 1);
    health.set_metric("scan_hz", 10.0, Some(10.0));
    let t0 = Instant::now();
    for seq in 0..seconds * 10 {
        let now = seq * 100_000_000;
        let s = scan(seq);
        rec.record("laser/scan", AnyMessageRef::LaserScan(&s), now)
            .unwrap();
        let o = Odometry {
            header: Header::new(now, seq, "odom"),
            x: seq as f64 * 0.01,
            ..Default::default()
        };
        rec.record("base/odom", AnyMessageRef::Odometry(&o), now)
            .unwrap();
        let r = ring(seq);
        rec.record("base/sonar", AnyMessageRef::SonarRing(&r), now)
            .unwrap();
        let k = SmokeReading {
            header: Header::new(now, seq, "smoke"),
            level: 12.0,
            ..Default::default()
        };
        rec.record("smoke/level", AnyMessageRef::SmokeReading(&k), now)
            .unwrap();
        fused.scan = s;
        fused.scan.header.seq = seq;
        fused.section_count = 8;
        rec.record("fusion/scan", AnyMessageRef::FusedScan(&fused), now)
            .unwrap();
        if seq.is_multiple_of(10) {
            health.header = Header::new(now, seq / 10, "");
            rec.record("health/hokuyo", AnyMessageRef::Health(&health), now)
                .unwrap();
        }
    }
    let (_, stats) = rec.finish(None).unwrap();
    (stats, t0.elapsed().as_secs_f64())
}

fn main() {
    let dir = tempfile::tempdir().unwrap();
    let seconds = 600; // ten robot minutes
    let bus_messages = (seconds * 10 * 5 + seconds) as f64;
    println!("recording {seconds} s of a 10 Hz robot ({bus_messages} bus messages)");
    for (name, c) in [("zstd", Compression::Zstd), ("none", Compression::None)] {
        let path = dir.path().join(format!("{name}.mcap"));
        let (stats, secs) = record(&path, seconds, c);
        let size = std::fs::metadata(&path).unwrap().len();
        println!(
            "write {name:>4}: {:>9.0} bus msg/s ({:>9.0} MCAP msg/s), {:>6.1} MB/s of payload, \
             {:.2} ms per robot second, file {:.1} MB ({:.0} kB per robot second), {} chunks",
            bus_messages / secs,
            stats.messages as f64 / secs,
            stats.bytes as f64 / secs / 1e6,
            secs * 1e3 / seconds as f64,
            size as f64 / 1e6,
            size as f64 / 1e3 / seconds as f64,
            stats.chunks
        );
        let t0 = Instant::now();
        let mut p = Playback::open(&path).unwrap();
        let mut n = 0u64;
        while p.read_next().unwrap().is_some() {
            n += 1;
        }
        let secs = t0.elapsed().as_secs_f64();
        assert_eq!(n as f64, bus_messages);
        println!(
            "read  {name:>4}: {:>9.0} bus msg/s decoded and joined",
            n as f64 / secs
        );
    }
}
