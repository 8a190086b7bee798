//! The bus across real OS processes: 10 000 full laser scans from a publisher
//! process to a subscriber process, every one received in order and intact,
//! and a publisher killed with SIGKILL replaced without restarting the subscriber.
//!
//! The publisher and subscriber are this test binary re-executed in a child
//! role (the `#[ignore]`d `child_role` entry point), so no extra binaries are needed.

use iceoryx2_bb_derive_macros::ZeroCopySend;
use smokenav_platform_bus::{Message, Topic, WaitOutcome, Waiter};
use smokenav_shared_types::laser::{BEAM_NO_RETURN, BeamReading};
use smokenav_shared_types::{Header, LaserScan, ZeroCopySend};
use smokenav_tests::{Child, open_bus, unique_instance};
use std::time::{Duration, Instant};

const ROLE_ENV: &str = "SMOKENAV_TEST_ROLE";
const SCAN_TOPIC: Topic<LaserScan> = Topic::new("test/scan");
const ACK_TOPIC: Topic<Ack> = Topic::new("test/ack");
/// Unacknowledged scans a publisher may have in flight; below the topic's
/// queue of 64, so nothing can be overwritten however slow the subscriber is.
const WINDOW: u64 = 32;

/// Flow control from subscriber to publisher: how many scans of `batch` arrived.
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("smokenav_test::Ack")]
struct Ack {
    header: Header,
    batch: u64,
    count: u64,
}

impl Message for Ack {
    const NAME: &'static str = "Ack";
    fn header(&self) -> &Header {
        &self.header
    }
    fn header_mut(&mut self) -> &mut Header {
        &mut self.header
    }
}

/// The scan number `seq` of publisher `batch`: sizes, ranges, error codes and
/// intensities all vary so a corrupted or misordered sample cannot pass.
fn make_scan(batch: u64, seq: u64, scan: &mut LaserScan) {
    scan.header = Header::new(seq * 100_000_000 + batch, 0, &format!("batch-{batch}"));
    scan.count = if seq.is_multiple_of(2) { 1081 } else { 769 };
    scan.angle_min = -2.0 + seq as f32 * 1e-4;
    scan.angle_increment = 0.00613;
    scan.range_min = 0.02;
    scan.range_max = 5.6;
    scan.has_intensities = seq.is_multiple_of(3) as u32;
    for i in 0..scan.len() {
        let v = (seq * 31 + i as u64 * 7 + batch * 1000) % 5600;
        let reading = if (i as u64 + seq).is_multiple_of(97) {
            BeamReading::SensorCode((v % 20) as u16)
        } else {
            BeamReading::Range(0.02 + v as f32 / 1000.0)
        };
        scan.set_beam(i, reading);
        scan.intensities[i] = if scan.has_intensities == 1 {
            v as f32
        } else {
            0.0
        };
    }
    for i in scan.len()..scan.ranges.len() {
        scan.ranges[i] = 0.0;
        scan.beam_error[i] = BEAM_NO_RETURN;
        scan.intensities[i] = 0.0;
    }
}

/// Bitwise equality: sensor-code beams carry NaN ranges (REP 117), which `==` never equates.
fn identical(a: &LaserScan, b: &LaserScan) -> bool {
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    a.header == b.header
        && (a.angle_min, a.angle_increment, a.range_min, a.range_max)
            == (b.angle_min, b.angle_increment, b.range_min, b.range_max)
        && (a.count, a.has_intensities) == (b.count, b.has_intensities)
        && bits(&a.ranges) == bits(&b.ranges)
        && bits(&a.intensities) == bits(&b.intensities)
        && a.beam_error == b.beam_error
}

fn batch_of(scan: &LaserScan) -> Option<u64> {
    scan.header
        .frame_id
        .as_str()
        .strip_prefix("batch-")?
        .parse()
        .ok()
}

fn run_publisher(instance: &str, batch: u64, count: u64) {
    let bus = open_bus(instance);
    let mut scans = bus.publisher(SCAN_TOPIC).unwrap();
    let acks = bus.subscriber(ACK_TOPIC).unwrap();
    let waiter = Waiter::new().unwrap();
    let _g = waiter.attach(&acks).unwrap();
    let mut acked = 0u64;
    let mut heard = false;
    let mut sent = 0u64;
    let end = Instant::now() + Duration::from_secs(120);
    while acked < count {
        assert!(
            Instant::now() < end,
            "publisher {batch}: timed out at {sent} sent, {acked} acked"
        );
        if heard && sent < count && sent - acked < WINDOW {
            scans.publish_with(|s| make_scan(batch, sent, s)).unwrap();
            sent += 1;
            continue;
        }
        waiter.wait(Some(Duration::from_millis(100))).unwrap();
        while let Some(a) = acks.receive().unwrap() {
            heard = true;
            acked = if a.batch == batch { a.count } else { 0 };
        }
    }
    println!("sent {sent}");
    // Stay alive until the test kills us, like a driver that crashes later.
    std::thread::sleep(Duration::from_secs(600));
}

fn run_subscriber(instance: &str, expected: u64) {
    let bus = open_bus(instance);
    let scans = bus.subscriber(SCAN_TOPIC).unwrap();
    let mut acks = bus.publisher(ACK_TOPIC).unwrap();
    let waiter = Waiter::new().unwrap();
    let _g = waiter.attach(&scans).unwrap();
    println!("subscriber ready");
    let mut want = LaserScan::default();
    let (mut batch, mut in_batch, mut total) = (0u64, 0u64, 0u64);
    let end = Instant::now() + Duration::from_secs(120);
    while total < expected {
        assert!(
            Instant::now() < end,
            "subscriber: timed out after {total} scans"
        );
        let outcome = waiter.wait(Some(Duration::from_millis(50))).unwrap();
        assert_ne!(outcome, WaitOutcome::Shutdown);
        while let Some(s) = scans.receive().unwrap() {
            let got_batch = batch_of(&s).expect("frame id names the batch");
            if got_batch != batch {
                assert!(
                    got_batch > batch,
                    "batch went back: {got_batch} after {batch}"
                );
                batch = got_batch;
                in_batch = 0;
            }
            make_scan(batch, in_batch, &mut want);
            let mut got = *s;
            got.header.seq = 0; // set by the bus; checked separately below
            assert_eq!(s.header.seq, in_batch, "out of order in batch {batch}");
            assert!(
                identical(&got, &want),
                "scan {in_batch} of batch {batch} differs from what was sent"
            );
            in_batch += 1;
            total += 1;
        }
        acks.publish_with(|a| {
            a.batch = batch;
            a.count = in_batch;
        })
        .unwrap();
    }
    let stats = scans.stats();
    println!(
        "RESULT received={} lost={} restarts={} batch={batch}",
        stats.received, stats.lost, stats.publisher_restarts
    );
}

/// Entry point of the child processes; does nothing unless started by the test below.
#[test]
#[ignore = "child process entry point, run by bus_delivers_every_scan_across_processes"]
fn child_role() {
    let instance = std::env::var("SMOKENAV_INSTANCE").unwrap();
    let num = |k: &str| std::env::var(k).unwrap().parse::<u64>().unwrap();
    match std::env::var(ROLE_ENV).as_deref() {
        Ok("publisher") => run_publisher(&instance, num("BATCH"), num("COUNT")),
        Ok("subscriber") => run_subscriber(&instance, num("EXPECTED")),
        other => panic!("unknown role {other:?}"),
    }
}

fn spawn_role(instance: &str, env: &[(&str, &str)]) -> Child {
    let exe = std::env::current_exe().unwrap();
    Child::spawn_env(
        &exe,
        &[
            "child_role",
            "--exact",
            "--ignored",
            "--nocapture",
            "--test-threads=1",
        ],
        instance,
        env,
    )
    .unwrap()
}

#[test]
fn bus_delivers_every_scan_across_processes_and_survives_publisher_sigkill() {
    let instance = unique_instance("bus2proc");
    let timeout = Duration::from_secs(120);
    let mut sub = spawn_role(
        &instance,
        &[(ROLE_ENV, "subscriber"), ("EXPECTED", "10000")],
    );
    sub.wait_for_line("subscriber ready", timeout).unwrap();

    let first = spawn_role(
        &instance,
        &[(ROLE_ENV, "publisher"), ("BATCH", "1"), ("COUNT", "5000")],
    );
    first.wait_for_line("sent 5000", timeout).unwrap();
    // A crash: no destructor runs, the node's resources are left behind.
    first.signal(nix::sys::signal::Signal::SIGKILL);
    drop(first);

    let second = spawn_role(
        &instance,
        &[(ROLE_ENV, "publisher"), ("BATCH", "2"), ("COUNT", "5000")],
    );
    second.wait_for_line("sent 5000", timeout).unwrap();
    let result = sub.wait_for_line("RESULT", timeout).unwrap();
    let status = sub.wait_exit(timeout).unwrap();
    assert!(status.success(), "subscriber failed:\n{}", sub.output());
    assert!(
        result.contains("received=10000 lost=0") && result.contains("batch=2"),
        "{result}"
    );
}
