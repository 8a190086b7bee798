//! The serial emulator on a real PTY, read the way the driver reads it:
//! through the symlink with the `serialport` crate.

use smokenav_smoke_codec::{AdcScale, ChecksumPolicy, SampleValue, SerialDecoder, StreamError};
use smokenav_smoke_emulator::{
    BoardConfig, Fault, Profile, SerialConfig, SerialEmulator, ValueFormat,
};
use std::io::Read;
use std::path::Path;
use std::time::{Duration, Instant};

fn open(path: &Path) -> serialport::TTYPort {
    serialport::new(path.to_string_lossy(), 115_200)
        .timeout(Duration::from_millis(100))
        .open_native()
        .unwrap_or_else(|e| panic!("opening {}: {e}", path.display()))
}

#[derive(Default)]
struct Received {
    values: Vec<SampleValue>,
    errors: Vec<StreamError>,
    disconnected: bool,
}

/// Reads for `secs` (or until the port fails), decoding as the driver does.
fn read_for(port: &mut serialport::TTYPort, dec: &mut SerialDecoder, secs: f64) -> Received {
    let mut out = Received::default();
    let mut buf = [0u8; 256];
    let end = Instant::now() + Duration::from_secs_f64(secs);
    while Instant::now() < end {
        match port.read(&mut buf) {
            Ok(0) => {
                out.disconnected = true;
                break;
            }
            Ok(n) => dec.feed(&buf[..n], |item| match item {
                Ok(s) => out.values.push(s.value),
                Err(e) => out.errors.push(e),
            }),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(_) => {
                out.disconnected = true;
                break;
            }
        }
    }
    out
}

fn config(rate_hz: f64) -> SerialConfig {
    SerialConfig {
        rate_hz,
        ..SerialConfig::new(BoardConfig::bench(Profile::clean()))
    }
}

#[test]
fn pty_board_prints_clean_air_at_its_rate() {
    let dir = tempfile::tempdir().unwrap();
    let emu = SerialEmulator::start(dir.path().join("smoke-adc"), config(50.0)).unwrap();
    let mut port = open(emu.path());
    let mut dec = SerialDecoder::new(0, ChecksumPolicy::Optional);
    let got = read_for(&mut port, &mut dec, 1.0);
    assert!(got.errors.is_empty(), "{:?}", got.errors);
    // 50 Hz for 1 s, minus the line lost to resync.
    assert!(
        (40..=55).contains(&got.values.len()),
        "{} samples",
        got.values.len()
    );
    // Clean air: 3000 mV = 614 counts on the 10-bit 5 V ADC (±2 mV noise).
    for v in &got.values {
        let SampleValue::Counts(c) = v else {
            panic!("{v:?}")
        };
        assert!((611..=618).contains(c), "{c}");
    }
    let st = emu.stop();
    assert_eq!(st.connects, 1);
    assert_eq!(st.lines_dropped, 0);
}

#[test]
fn each_garbage_line_is_one_counted_error_and_out_of_range_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let emu = SerialEmulator::start(dir.path().join("smoke-adc"), config(50.0)).unwrap();
    let mut port = open(emu.path());
    let mut dec = SerialDecoder::new(0, ChecksumPolicy::Optional);
    read_for(&mut port, &mut dec, 0.2);
    let before = *dec.stats();
    // All six kinds of corruption, then three impossible values.
    emu.inject(Fault::Garbage { lines: 6 });
    emu.inject(Fault::OutOfRange { samples: 3 });
    let got = read_for(&mut port, &mut dec, 0.8);
    let after = *dec.stats();
    assert_eq!(
        after.parse_errors - before.parse_errors,
        6,
        "{:?}",
        got.errors
    );
    assert_eq!(after.checksum_errors - before.checksum_errors, 1);
    assert_eq!(after.overlong - before.overlong, 1);
    let adc = AdcScale::AVR_5V_10BIT;
    let refused = got
        .values
        .iter()
        .filter(|v| adc.measure(**v).is_err())
        .count();
    assert_eq!(refused, 3);
    // Good samples resume after the faults.
    assert!(got.values.len() > 20);
}

#[test]
fn unplug_removes_the_link_and_replug_moves_it_to_a_fresh_pty() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("smoke-adc");
    let emu = SerialEmulator::start(&link, config(50.0)).unwrap();
    let mut port = open(&link);
    let mut dec = SerialDecoder::new(0, ChecksumPolicy::Optional);
    assert!(!read_for(&mut port, &mut dec, 0.2).values.is_empty());

    emu.inject(Fault::BoardUnplugged { secs: 1.0 });
    let got = read_for(&mut port, &mut dec, 1.0);
    assert!(got.disconnected, "reads must fail once the board is gone");
    assert!(
        std::fs::symlink_metadata(&link).is_err(),
        "link must be gone while unplugged"
    );
    drop(port);

    let deadline = Instant::now() + Duration::from_secs(3);
    while std::fs::metadata(&link).is_err() {
        assert!(Instant::now() < deadline, "link did not come back");
        std::thread::sleep(Duration::from_millis(20));
    }
    let mut port = open(&link);
    dec.reset();
    let got = read_for(&mut port, &mut dec, 0.3);
    assert!(got.values.len() > 5, "{:?}", got.values);
    let st = emu.stop();
    assert_eq!(st.connects, 2);
    assert_eq!(st.board.unplugs, 1);
    assert!(st.device.is_some());
    assert!(
        std::fs::symlink_metadata(&link).is_err(),
        "stop removes the link"
    );
}

#[test]
fn millivolt_lines_with_checksums_decode_under_a_strict_policy() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = SerialConfig {
        format: ValueFormat::Millivolts,
        checksum: true,
        ..config(50.0)
    };
    let emu = SerialEmulator::start(dir.path().join("smoke-adc"), cfg).unwrap();
    let mut port = open(emu.path());
    let mut dec = SerialDecoder::new(0, ChecksumPolicy::Required);
    let got = read_for(&mut port, &mut dec, 0.5);
    assert!(got.errors.is_empty(), "{:?}", got.errors);
    assert!(got.values.len() > 15);
    for v in &got.values {
        let SampleValue::Millivolts(mv) = v else {
            panic!("{v:?}")
        };
        assert!((*mv - 3000.0).abs() < 10.0, "{mv}");
    }
}

#[test]
fn two_emulators_run_side_by_side_on_distinct_ptys() {
    // Parallel tests each get their own board.
    let dir = tempfile::tempdir().unwrap();
    let a = SerialEmulator::start(dir.path().join("a"), config(20.0)).unwrap();
    let b = SerialEmulator::start(dir.path().join("b"), config(20.0)).unwrap();
    assert_ne!(a.stats().device, b.stats().device);
}

#[test]
fn unplug_still_hangs_up_when_the_embedding_process_has_spawned_children() {
    // A test that embeds the emulator then spawns the driver: the child
    // must not inherit the PTY master, or closing it would not hang up.
    let dir = tempfile::tempdir().unwrap();
    let emu = SerialEmulator::start(dir.path().join("smoke-adc"), config(50.0)).unwrap();
    let mut bystander = std::process::Command::new("sleep")
        .arg("10")
        .spawn()
        .unwrap();
    let mut port = open(emu.path());
    let mut dec = SerialDecoder::new(0, ChecksumPolicy::Optional);
    assert!(!read_for(&mut port, &mut dec, 0.2).values.is_empty());
    emu.inject(Fault::BoardUnplugged { secs: 2.0 });
    let got = read_for(&mut port, &mut dec, 1.0);
    let _ = bystander.kill();
    let _ = bystander.wait();
    assert!(got.disconnected, "the reader must see the hang-up");
}
