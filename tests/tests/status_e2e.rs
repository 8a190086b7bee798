//! `smokenav status` against real processes: a process killed with SIGKILL is
//! reported down with a non-zero exit status, and up again once restarted.
//!
//! The process under watch is the real `smokenav-smoke` driver reading a fake
//! IIO ADC (the smoke emulator's sysfs tree), the cheapest real process to run.

use smokenav_smoke_emulator::{AdcScale, BoardConfig, FakeIio, IioConfig, Profile, SensorParams};
use smokenav_tests::{Child, bin, profile, unique_instance};
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

fn start_driver(config: &Path, device: &Path, instance: &str) -> Child {
    Child::spawn(
        &bin("smokenav-smoke"),
        &[
            "--config",
            &config.to_string_lossy(),
            "--port",
            &device.to_string_lossy(),
            "--warmup",
            "0",
        ],
        instance,
    )
    .unwrap()
}

/// Runs `smokenav status --json` for the smoke role; returns (exit ok, status of `smoke`).
fn status(instance: &str) -> (bool, String, serde_json::Value) {
    let out = Command::new(bin("smokenav"))
        .args([
            "status",
            "--json",
            "--roles",
            "smoke",
            "--stale-after",
            "1.5",
        ])
        .env("SMOKENAV_INSTANCE", instance)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    let v: serde_json::Value = serde_json::from_str(text.trim())
        .unwrap_or_else(|e| panic!("{e}: {text} {}", String::from_utf8_lossy(&out.stderr)));
    let smoke = v["processes"][0]["status"]
        .as_str()
        .unwrap_or("")
        .to_owned();
    (out.status.success(), smoke, v)
}

/// Polls status until `want` (up to `timeout`), returning the last answer.
fn status_until(
    instance: &str,
    want: &str,
    timeout: Duration,
) -> (bool, String, serde_json::Value) {
    let end = Instant::now() + timeout;
    loop {
        let s = status(instance);
        if s.1 == want || Instant::now() >= end {
            return s;
        }
    }
}

#[test]
fn status_reports_a_killed_process_down_and_a_restarted_one_up() {
    let dir = tempfile::tempdir().unwrap();
    let device = dir.path().join("iio:device0");
    let board = BoardConfig {
        adc: AdcScale::new(5000.0, 12).unwrap(),
        sensor: SensorParams {
            warmup_s: 0.0,
            ..SensorParams::default()
        },
        ..BoardConfig::bench(Profile::clean())
    };
    let _adc = FakeIio::start_at(&device, IioConfig::new(board)).unwrap();
    let config = profile(dir.path(), "pioneer-3dx.toml", |c| {
        c.smoke.adc_bits = 12;
        c.smoke.baseline_mv = Some(1000.0);
    });
    let instance = unique_instance("status");

    let driver = start_driver(&config, &device, &instance);
    let (ok, smoke, v) = status_until(&instance, "up", Duration::from_secs(20));
    assert_eq!(smoke, "up", "{v}\n{}", driver.output());
    assert!(ok, "exit status must be 0 when everything is up: {v}");
    assert_eq!(v["processes"][0]["pid"].as_u64(), Some(driver.pid() as u64));

    driver.signal(nix::sys::signal::Signal::SIGKILL);
    drop(driver);
    let (ok, smoke, v) = status_until(&instance, "down", Duration::from_secs(10));
    assert_eq!(smoke, "down", "{v}");
    assert!(
        !ok,
        "exit status must be non-zero when a process is down: {v}"
    );

    let restarted = start_driver(&config, &device, &instance);
    let (ok, smoke, v) = status_until(&instance, "up", Duration::from_secs(20));
    assert_eq!(smoke, "up", "{v}\n{}", restarted.output());
    assert!(ok, "{v}");
    assert_eq!(
        v["processes"][0]["pid"].as_u64(),
        Some(restarted.pid() as u64)
    );
}
