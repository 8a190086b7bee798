//! The fake IIO directory, read with the codec's attribute parsers as the
//! driver reads it.

use smokenav_smoke_codec::iio::{IioCalibration, parse_offset, parse_raw, parse_scale};
use smokenav_smoke_codec::{AdcScale, IioError};
use smokenav_smoke_emulator::{BoardConfig, FakeIio, Fault, IioConfig, Profile};
use std::path::Path;
use std::time::{Duration, Instant};

fn twelve_bit() -> IioConfig {
    IioConfig {
        rate_hz: 50.0,
        ..IioConfig::new(BoardConfig {
            adc: AdcScale::new(5000.0, 12).unwrap(),
            ..BoardConfig::bench(Profile::clean())
        })
    }
}

fn read_raw(dir: &Path) -> std::io::Result<Result<i64, IioError>> {
    std::fs::read(dir.join("in_voltage0_raw")).map(|t| parse_raw(&t))
}

#[test]
fn device_has_the_abi_attributes_and_clean_air_reads_3000_mv() {
    let emu = FakeIio::start(twelve_bit()).unwrap();
    let dir = emu.device_path();
    assert!(dir.ends_with("iio:device0"));
    assert_eq!(
        std::fs::read_to_string(dir.join("name")).unwrap(),
        "smokenav-fake-adc\n"
    );
    // 5000 mV / 4096 counts.
    let scale = parse_scale(&std::fs::read(dir.join("in_voltage0_scale")).unwrap()).unwrap();
    assert_eq!(scale, 1.220703125);
    std::thread::sleep(Duration::from_millis(100));
    let raw = read_raw(dir).unwrap().unwrap();
    let mv = IioCalibration {
        scale_mv: scale,
        offset: 0.0,
    }
    .measure(raw, smokenav_smoke_codec::IioRange::Counts { bits: 12 })
    .unwrap()
    .raw_mv;
    assert!((mv - 3000.0).abs() < 10.0, "{raw} counts = {mv} mV");
}

#[test]
fn shared_scale_and_offset_give_the_same_millivolts() {
    let cfg = IioConfig {
        shared_scale: true,
        offset: Some(-100),
        ..twelve_bit()
    };
    let emu = FakeIio::start(cfg).unwrap();
    let dir = emu.device_path();
    assert!(!dir.join("in_voltage0_scale").exists());
    let scale = parse_scale(&std::fs::read(dir.join("in_voltage_scale")).unwrap()).unwrap();
    let offset = parse_offset(&std::fs::read(dir.join("in_voltage0_offset")).unwrap()).unwrap();
    assert_eq!(offset, -100.0);
    std::thread::sleep(Duration::from_millis(100));
    let raw = read_raw(dir).unwrap().unwrap();
    let mv = IioCalibration {
        scale_mv: scale,
        offset,
    }
    .measure(raw, smokenav_smoke_codec::IioRange::Counts { bits: 12 })
    .unwrap()
    .raw_mv;
    assert!((mv - 3000.0).abs() < 10.0, "{mv}");
}

#[test]
fn vanished_device_is_gone_then_comes_back_whole() {
    let emu = FakeIio::start(twelve_bit()).unwrap();
    let dir = emu.device_path().to_owned();
    emu.inject(Fault::BoardUnplugged { secs: 0.5 });
    let deadline = Instant::now() + Duration::from_secs(2);
    while dir.exists() {
        assert!(Instant::now() < deadline, "device never vanished");
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(
        read_raw(&dir).unwrap_err().kind(),
        std::io::ErrorKind::NotFound
    );
    while !dir.join("in_voltage0_scale").exists() {
        assert!(Instant::now() < deadline, "device never came back");
        std::thread::sleep(Duration::from_millis(5));
    }
    std::thread::sleep(Duration::from_millis(60));
    assert!(read_raw(&dir).unwrap().is_ok());
    let st = emu.stop();
    assert_eq!(st.appearances, 2);
    assert_eq!(st.board.unplugs, 1);
    assert!(!dir.exists(), "stop removes the device");
}

#[test]
fn garbage_and_out_of_range_show_up_in_raw() {
    let emu = FakeIio::start(twelve_bit()).unwrap();
    let dir = emu.device_path();
    std::thread::sleep(Duration::from_millis(50));
    // A long run of each, so polling at 200 Hz sees both.
    emu.inject(Fault::Garbage { lines: 12 });
    emu.inject(Fault::OutOfRange { samples: 10 });
    let (mut bad_text, mut out_of_range) = (0, 0);
    let end = Instant::now() + Duration::from_millis(800);
    while Instant::now() < end {
        match read_raw(dir).unwrap() {
            Err(_) => bad_text += 1,
            Ok(raw) if raw > 4095 => out_of_range += 1,
            Ok(_) => {}
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(
        bad_text > 0 && out_of_range > 0,
        "{bad_text} {out_of_range}"
    );
    assert_eq!(emu.stats().board.garbage, 12);
}

#[test]
fn existing_directory_is_not_overwritten() {
    let dir = tempfile::tempdir().unwrap();
    let err = FakeIio::start_at(dir.path(), twelve_bit()).err().unwrap();
    assert_eq!(err.kind(), std::io::ErrorKind::AlreadyExists);
}
