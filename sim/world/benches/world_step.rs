//! How much faster than real time the world runs (issue 7: ≥ 50× for the
//! R3.2 arena), and where the time goes. Times are this thread's CPU time
//! (CLOCK_THREAD_CPUTIME_ID), so other processes on the machine do not count;
//! wall time is printed beside it.
//!
//!     CARGO_TARGET_DIR=... cargo bench -p smokenav-sim-world --bench world_step
//!
//! Prints, for each bundled scenario, the real-time factor over its whole
//! run; then the R3.2 dense-smoke run's worst window (the robot inside the
//! smoke, where every laser beam integrates the field); then the cost of one
//! laser scan in clean air and in smoke, one sonar ring and one smoke-field
//! update.

use smokenav_shared_types::Rng;
use smokenav_sim_world::laser::{LaserModel, LaserParams, URG_STEPS};
use smokenav_sim_world::smoke::{SmokeField, SmokeParams};
use smokenav_sim_world::sonar::{SonarModel, SonarParams};
use smokenav_sim_world::{BuiltinArena, Pose2, Scenario, StepOutput, Vec2, World};
use std::hint::black_box;
use std::time::{Duration, Instant};

/// This thread's CPU time, s.
fn cpu_s() -> f64 {
    let t = nix::time::clock_gettime(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID)
        .expect("thread CPU clock");
    t.tv_sec() as f64 + t.tv_nsec() as f64 * 1e-9
}

/// Steps a bundled scenario to its end in 1 s steps; reports the real-time
/// factor over the whole run and over its slowest 10 s window.
fn whole_run(name: &str) {
    let scenario = Scenario::builtin(name).unwrap();
    let sim_s = scenario.duration_s;
    let mut world = World::new(scenario).unwrap();
    let mut out = StepOutput::default();
    let mut per_second = Vec::new();
    let (wall0, cpu0) = (Instant::now(), cpu_s());
    let (mut scans, mut pings) = (0usize, 0usize);
    while !world.is_finished() {
        out.clear();
        let c = cpu_s();
        world.step_into(Duration::from_secs(1), &mut out);
        per_second.push(cpu_s() - c);
        scans += out.laser.len();
        pings += out.sonar.len();
    }
    let (wall, cpu) = (wall0.elapsed().as_secs_f64(), cpu_s() - cpu0);
    let worst10 = per_second
        .windows(10)
        .map(|w| w.iter().sum::<f64>())
        .fold(0.0, f64::max);
    println!(
        "{name:20} {sim_s:4.0} s in {cpu:6.3} s CPU ({wall:6.3} s wall): {:5.0}× real time overall, \
         {:5.0}× in its slowest 10 s ({scans} scans, {pings} pings)",
        sim_s / cpu,
        10.0 / worst10
    );
}

fn per_call(label: &str, n: usize, mut f: impl FnMut()) {
    f();
    let c0 = cpu_s();
    for _ in 0..n {
        f();
    }
    let us = (cpu_s() - c0) / n as f64 * 1e6;
    println!("{label:44} {us:9.1} µs CPU");
}

fn main() {
    println!("== real-time factor per bundled scenario (1 s steps) ==");
    for (name, _) in smokenav_sim_world::BUILTIN_SCENARIOS {
        whole_run(name);
    }

    println!("== single models, R3.2 arena ==");
    let arena = BuiltinArena::R32.load().unwrap();
    let clean = SmokeField::new(&arena, SmokeParams::default(), vec![]).unwrap();
    let mut smoky = SmokeField::new(&arena, SmokeParams::default(), vec![]).unwrap();
    // The whole middle bay full of smoke of varying density, robot inside it.
    smoky.add_rect(Vec2::new(4.5, 0.0), Vec2::new(9.0, 9.87), 0.05);
    smoky.add_patch(Vec2::new(6.5, 6.3), 2.0, 0.5);
    let pose = Pose2::new(5.7, 5.0, 1.0);
    let mut laser = LaserModel::new(
        LaserParams::default(),
        Pose2::new(0.05, 0.0, 0.0),
        Rng::new(1, 1),
    );
    let mut out = [0u16; URG_STEPS];
    per_call("laser scan (682 beams), clean air", 2000, || {
        laser.scan(&arena, &clean, &pose, &pose, &mut out);
        black_box(&out);
    });
    per_call("laser scan (682 beams), robot in dense smoke", 2000, || {
        laser.scan(&arena, &smoky, &pose, &pose, &mut out);
        black_box(&out);
    });
    let light = {
        let mut f = SmokeField::new(&arena, SmokeParams::default(), vec![]).unwrap();
        f.add_rect(Vec2::new(0.0, 0.0), Vec2::new(13.63, 9.87), 0.01);
        f
    };
    per_call("laser scan (682 beams), whole arena hazy", 2000, || {
        laser.scan(&arena, &light, &pose, &pose, &mut out);
        black_box(&out);
    });
    let mut sonar = SonarModel::new(SonarParams::scout(), Rng::new(1, 2));
    per_call("sonar ring (16 pings × 9 rays)", 2000, || {
        for k in 0..16 {
            let m = Pose2::new(0.19, 0.0, (k as f64 * 22.5).to_radians());
            black_box(sonar.ping(&arena, &pose, &m));
        }
    });
    let mut field = smoky.clone();
    let mut t = 0.0;
    per_call("smoke field update (50 ms, smoke in a third)", 200, || {
        field.advance(t, 0.05);
        t += 0.05;
    });
    let mut hazy = light.clone();
    per_call("smoke field update (50 ms, smoke everywhere)", 200, || {
        hazy.advance(t, 0.05);
        t += 0.05;
    });
}
