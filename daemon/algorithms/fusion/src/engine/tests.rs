use super::*;
use crate::testkit::{self, Room, saturated_ring, smoke_reading, urg_scan};
use smokenav_shared_types::SmokeTrend;
use smokenav_shared_types::record::FusedScanRecord;
use std::path::PathBuf;

fn profile(name: &str) -> RobotConfig {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../config")
        .join(name);
    RobotConfig::load(&p).unwrap()
}

fn engine(method: FusionMethod) -> FusionEngine {
    FusionEngine::from_config(&profile("pioneer-3dx.toml"), Some(method)).unwrap()
}

fn room(x0: f64, y0: f64, theta: f64) -> f64 {
    Room::default().range(x0, y0, theta)
}

fn urg(stamp_ns: u64, range: impl Fn(usize, f64) -> f32) -> LaserScan {
    urg_scan(stamp_ns, 0, range)
}

fn clean_scan(stamp_ns: u64) -> LaserScan {
    Room::default().scan(stamp_ns, 0)
}

fn smoky_scan(stamp_ns: u64) -> LaserScan {
    testkit::smoky_scan(stamp_ns, 0)
}

/// Each sonar's true reading: the nearest wall within its (P3-DX 15°) cone.
fn true_sonar(e: &FusionEngine, stamp_ns: u64) -> SonarRing {
    Room::default().ring(e.geometry(), 7.5, stamp_ns, 0)
}

fn saturated_sonar(e: &FusionEngine, stamp_ns: u64) -> SonarRing {
    saturated_ring(e.geometry(), stamp_ns, 0)
}

fn smoke(stamp_ns: u64, level: f32, trend: SmokeTrend) -> SmokeReading {
    smoke_reading(stamp_ns, 0, level, trend)
}

fn bits(s: &LaserScan) -> (Vec<u32>, Vec<u16>, Vec<u32>) {
    let n = s.len();
    (
        s.ranges[..n].iter().map(|r| r.to_bits()).collect(),
        s.beam_error[..n].to_vec(),
        s.intensities[..n].iter().map(|r| r.to_bits()).collect(),
    )
}

fn fused() -> Box<FusedScan> {
    Box::default()
}

#[test]
fn clean_air_leaves_the_laser_bit_identical_for_both_methods() {
    for method in [FusionMethod::V1, FusionMethod::V2] {
        let mut e = engine(method);
        let laser = clean_scan(1_000_000_000);
        let sonar = true_sonar(&e, 1_000_000_000);
        let mut out = fused();
        let r = e
            .step(
                Some(&laser),
                Some(&sonar),
                Some(&smoke(1_000_000_000, 0.0, SmokeTrend::Steady)),
                &mut out,
            )
            .unwrap();
        assert_eq!(r.sync_state, SyncState::Complete);
        assert_eq!(out.scan.header, laser.header);
        assert_eq!(bits(&out.scan), bits(&laser), "{method:?}");
        assert!(
            out.sections()
                .iter()
                .all(|d| d.source() == SectionSource::Laser)
        );
        assert_eq!(out.sonar_usage(), 0.0);
        assert_eq!(
            r.sections, 8,
            "the P3-DX front ring: 8 sonars, all within ±120°"
        );
    }
}

#[test]
fn dense_smoke_with_short_uniform_laser_uses_the_sonar() {
    // Smoke level 250 (≥ SMOKE_MAX_UP 200; alcoholized), laser 0.5 m ± 1 cm
    // everywhere (σ ≈ 6 mm, dense); the sonars see the real walls (< 2.5 m).
    for method in [FusionMethod::V1, FusionMethod::V2] {
        let mut e = engine(method);
        let laser = smoky_scan(1_000_000_000);
        let sonar = true_sonar(&e, 1_000_000_000);
        let mut out = fused();
        let r = e
            .step(
                Some(&laser),
                Some(&sonar),
                Some(&smoke(1_000_000_000, 250.0, SmokeTrend::Rising)),
                &mut out,
            )
            .unwrap();
        assert_eq!(r.smoke_state, SmokeState::Dense);
        for d in out.sections() {
            assert_eq!(d.source(), SectionSource::Sonar, "{method:?} section {d:?}");
            let pose = *e.geometry().pose(d.sonar_index).unwrap();
            // The beam along the sonar's axis now shows the wall, not the 0.5 m smoke.
            let axis = (d.first_beam..d.end_beam)
                .min_by(|&a, &b| {
                    let da = (f64::from(out.scan.angle(a as usize)) - pose.yaw).abs();
                    let db = (f64::from(out.scan.angle(b as usize)) - pose.yaw).abs();
                    da.total_cmp(&db)
                })
                .unwrap() as usize;
            // Its range lies on the sonar's arc (the nearest echo in the cone),
            // so it is at most the wall distance along that beam, and far from 0.5 m.
            let got = f64::from(out.scan.beam(axis).range().unwrap());
            let a = f64::from(out.scan.angle(axis));
            let on_arc = (got * a.cos() - pose.x).hypot(got * a.sin() - pose.y);
            assert!(
                (on_arc - f64::from(d.sonar_range)).abs() < 1e-3,
                "{method:?} {on_arc} vs {}",
                d.sonar_range
            );
            let wall = room(0.0, 0.0, a);
            assert!(
                got <= wall + 1e-3 && got > 1.2,
                "{method:?} sonar {}: {got} vs wall {wall}",
                d.sonar_index
            );
            assert_eq!(out.beam_source(axis), SectionSource::Sonar);
        }
        assert_eq!(out.sonar_usage(), 1.0);
        // Beams outside every cone carry the smoke: not accepted.
        let gap = (0..out.scan.len())
            .find(|&i| e.sections.owner(i).is_none())
            .unwrap();
        assert_eq!(out.scan.beam(gap), BeamReading::BeyondMax);
        assert_eq!(out.beam_source(gap), SectionSource::Neither);
    }
}

#[test]
fn smoke_with_saturated_sonars_trusts_neither() {
    for method in [FusionMethod::V1, FusionMethod::V2] {
        let mut e = engine(method);
        let laser = smoky_scan(1_000_000_000);
        let sonar = saturated_sonar(&e, 1_000_000_000);
        let mut out = fused();
        e.step(
            Some(&laser),
            Some(&sonar),
            Some(&smoke(1_000_000_000, 250.0, SmokeTrend::Rising)),
            &mut out,
        )
        .unwrap();
        assert!(
            out.sections()
                .iter()
                .all(|d| d.source() == SectionSource::Neither),
            "{method:?}"
        );
        for i in 0..out.scan.len() {
            assert_eq!(
                out.scan.beam(i),
                BeamReading::BeyondMax,
                "{method:?} beam {i}"
            );
            assert_eq!(out.beam_source(i), SectionSource::Neither);
        }
        if method == FusionMethod::V2 {
            assert!(
                out.sections()
                    .iter()
                    .all(|d| d.rho_sonar < 0.5 && d.rho_laser < 0.5)
            );
        }
    }
}

#[test]
fn laser_only_method_is_bit_identical_even_in_dense_smoke() {
    let mut e = engine(FusionMethod::LaserOnly);
    let laser = smoky_scan(7);
    let sonar = true_sonar(&e, 7);
    let mut out = fused();
    e.step(
        Some(&laser),
        Some(&sonar),
        Some(&smoke(7, 400.0, SmokeTrend::Rising)),
        &mut out,
    )
    .unwrap();
    assert_eq!(out.scan, laser);
    assert_eq!(out.method(), FusionMethod::LaserOnly);
    assert_eq!(out.sonar_usage(), 0.0);
}

#[test]
fn missing_sonar_passes_the_laser_through_marked_laser_only() {
    let mut e = engine(FusionMethod::V2);
    let laser = smoky_scan(7);
    let mut out = fused();
    let r = e
        .step(
            Some(&laser),
            None,
            Some(&smoke(7, 400.0, SmokeTrend::Rising)),
            &mut out,
        )
        .unwrap();
    assert_eq!(r.sync_state, SyncState::LaserOnly);
    assert_eq!(out.sync_state(), SyncState::LaserOnly);
    assert_eq!(out.scan, laser);
    assert_eq!(out.sonar_stamp_ns, 0);
}

#[test]
fn silent_laser_gives_algorithm_1_in_the_last_laser_layout() {
    let mut e = engine(FusionMethod::V2);
    let mut out = fused();
    let laser = clean_scan(1_000);
    let sonar = true_sonar(&e, 2_000);
    e.step(
        Some(&laser),
        Some(&sonar),
        Some(&smoke(1_000, 0.0, SmokeTrend::Steady)),
        &mut out,
    )
    .unwrap();
    let r = e.step(None, Some(&sonar), None, &mut out).unwrap();
    assert_eq!(r.sync_state, SyncState::SonarOnly);
    assert_eq!(out.scan.header.stamp_ns, 2_000);
    assert_eq!(out.scan.len(), laser.len());
    assert_eq!(out.scan.angle_min, laser.angle_min);
    assert_eq!(out.sonar_usage(), 1.0);
    let painted = (0..out.scan.len())
        .filter(|&i| out.beam_source(i) == SectionSource::Sonar)
        .count();
    assert!(painted > 8 * 20, "8 cones of 15° at 0.35° steps: {painted}");
    for i in 0..out.scan.len() {
        match out.beam_source(i) {
            SectionSource::Sonar => assert!(out.scan.beam(i).range().is_some()),
            _ => assert_eq!(out.scan.beam(i), BeamReading::BeyondMax),
        }
    }
    assert_eq!(e.step(None, None, None, &mut out), Err(StepError::NoInput));
    let mut lo = engine(FusionMethod::LaserOnly);
    assert_eq!(
        lo.step(None, Some(&sonar), None, &mut out),
        Err(StepError::LaserRequired)
    );
}

#[test]
fn light_smoke_replaces_only_the_noisy_section() {
    // Level 160 rising (between SMOKE_MIN 130 and SMOKE_MAX_UP 200). The laser
    // sees the room, except a smoke plume in the section of sonar 3 (10°):
    // alternating 0.6 / 0.9 m returns.
    let mut e = engine(FusionMethod::V1);
    let laser0 = clean_scan(0);
    let mut out = fused();
    let sonar = true_sonar(&e, 0);
    e.step(
        Some(&laser0),
        Some(&sonar),
        Some(&smoke(0, 160.0, SmokeTrend::Rising)),
        &mut out,
    )
    .unwrap();
    let s3 = *e
        .sections
        .as_slice()
        .iter()
        .find(|s| s.sonar_index == 3)
        .unwrap();
    let laser = urg(0, |i, a| {
        if (s3.first..s3.end).contains(&i) {
            if i % 2 == 0 { 0.6 } else { 0.9 }
        } else {
            room(0.0, 0.0, a) as f32
        }
    });
    e.step(
        Some(&laser),
        Some(&sonar),
        Some(&smoke(0, 160.0, SmokeTrend::Rising)),
        &mut out,
    )
    .unwrap();
    let d3 = out.sections().iter().find(|d| d.sonar_index == 3).unwrap();
    assert_eq!(d3.source(), SectionSource::Sonar);
    for i in s3.first..s3.end {
        assert_ne!(out.scan.beam(i), BeamReading::Range(0.6));
    }
    // Sections whose laser agrees with their sonar are superimposed, not replaced.
    let others: Vec<SectionSource> = out
        .sections()
        .iter()
        .filter(|d| d.sonar_index != 3)
        .map(|d| d.source())
        .collect();
    assert!(
        others.iter().all(|s| *s != SectionSource::Neither),
        "{others:?}"
    );
    // The uncovered beams next to sonar 3's section are refused; far ones kept.
    assert_eq!(out.beam_source(s3.end), SectionSource::Neither);
    assert_eq!(out.beam_source(0), SectionSource::Laser);
}

/// v2 for the small test room (its scans' σ of ~0.4 m counts as
/// structured), after one clean scan at `level` so its sections are laid out;
/// with the room's true sonar ring and an output buffer.
fn v2_small_room(level: f32, trend: SmokeTrend) -> (FusionEngine, SonarRing, Box<FusedScan>) {
    v2_small_room_with(level, trend, |_| {})
}

/// [`v2_small_room`] with `[fusion.v2]` edited.
fn v2_small_room_with(
    level: f32,
    trend: SmokeTrend,
    edit: impl FnOnce(&mut smokenav_platform_config::fusion::V2Params),
) -> (FusionEngine, SonarRing, Box<FusedScan>) {
    let cfg = profile("pioneer-3dx.toml");
    let mut v2 = cfg.fusion.v2.clone();
    v2.dense = smokenav_platform_config::fusion::PiShape::new(0.0, 0.0, 0.1, 0.2);
    edit(&mut v2);
    let geometry = SonarGeometry::from_config(&cfg.laser, &cfg.sonar, &cfg.fusion).unwrap();
    let mut e = FusionEngine::new(FusionMethod::V2, geometry, cfg.fusion.v1.clone(), v2);
    let mut out = fused();
    let sonar = true_sonar(&e, 0);
    e.step(
        Some(&clean_scan(0)),
        Some(&sonar),
        Some(&smoke(0, level, trend)),
        &mut out,
    )
    .unwrap();
    (e, sonar, out)
}

/// The room, except a smoke front 0.7 m ahead in sonar 3's section.
fn phantom_in_section(e: &FusionEngine, sonar_index: u8, front: f32) -> (LaserScan, Section) {
    let s = *e
        .sections
        .as_slice()
        .iter()
        .find(|s| s.sonar_index == sonar_index)
        .unwrap();
    let laser = urg(0, |i, a| {
        if (s.first..s.end).contains(&i) {
            front
        } else {
            room(0.0, 0.0, a) as f32
        }
    });
    (laser, s)
}

#[test]
fn v2_gives_a_section_the_sonar_contradicts_in_smoky_air_to_the_sonar() {
    // Smoke 60 (alcoholized, but far below v1's 130) and a structured scan
    // (not dense): the paper's rule alone trusts the whole laser.
    // Sonar 3 echoes from the wall, well beyond the laser's 0.7 m smoke front.
    let (mut e, sonar, mut out) = v2_small_room(60.0, SmokeTrend::Rising);
    let (laser, s3) = phantom_in_section(&e, 3, 0.7);
    assert!(spread(&laser) > 0.2, "{}", spread(&laser));
    e.step(
        Some(&laser),
        Some(&sonar),
        Some(&smoke(0, 60.0, SmokeTrend::Rising)),
        &mut out,
    )
    .unwrap();
    let d3 = out.sections().iter().find(|d| d.sonar_index == 3).unwrap();
    assert_eq!(d3.source(), SectionSource::Sonar, "{d3:?}");
    assert!(d3.rho_laser < 0.5);
    for i in s3.first..s3.end {
        assert_ne!(out.scan.beam(i), BeamReading::Range(0.7), "beam {i}");
    }
    // Every other section agrees with its sonar and keeps its laser untouched.
    for d in out.sections().iter().filter(|d| d.sonar_index != 3) {
        assert_eq!(d.source(), SectionSource::Laser, "{d:?}");
        for i in d.first_beam as usize..d.end_beam as usize {
            assert_eq!(out.scan.beam(i), laser.beam(i));
        }
    }
    // The uncovered beams bordering the contradicted section go with it.
    assert_eq!(out.beam_source(s3.end), SectionSource::Neither);
    assert_eq!(out.beam_source(0), SectionSource::Laser);

    // With the sonar silent (saturated) in that section the sensors conflict: neither.
    let mut quiet = sonar;
    let n = quiet.len();
    for r in &mut quiet.readings[..n] {
        if r.index == 3 {
            r.range = 5.0;
            r.status = smokenav_shared_types::SonarStatus::Saturated as u8;
        }
    }
    e.step(
        Some(&laser),
        Some(&quiet),
        Some(&smoke(0, 60.0, SmokeTrend::Rising)),
        &mut out,
    )
    .unwrap();
    let d3 = out.sections().iter().find(|d| d.sonar_index == 3).unwrap();
    assert_eq!(d3.source(), SectionSource::Neither, "{d3:?}");
}

#[test]
fn v2_keeps_the_laser_beams_the_sonar_does_not_contradict_in_a_section_it_gives_the_sonar() {
    // Smoke 60 and a smoke front 0.7 m ahead on every other beam of sonar
    // 3's section (half its beams contradicted: the section goes to the
    // sonar); the other beams reach the room's walls, at or beyond the
    // sonar's nearest echo.
    let run = |keep: bool| {
        let (mut e, sonar, mut out) = v2_small_room_with(60.0, SmokeTrend::Rising, |v2| {
            v2.keep_uncontradicted_laser = keep;
        });
        let (smoky, s3) = phantom_in_section(&e, 3, 0.7);
        let laser = urg(0, |i, a| {
            if (s3.first..s3.end).contains(&i) && i % 2 == 1 {
                room(0.0, 0.0, a) as f32
            } else {
                smoky.beam(i).range().unwrap()
            }
        });
        let report = e
            .step(
                Some(&laser),
                Some(&sonar),
                Some(&smoke(0, 60.0, SmokeTrend::Rising)),
                &mut out,
            )
            .unwrap();
        let d3 = *out.sections().iter().find(|d| d.sonar_index == 3).unwrap();
        assert_eq!(d3.source(), SectionSource::Sonar, "keep {keep}: {d3:?}");
        // Where each beam meets the sonar's arc (infinite where it misses it).
        let arc = e.paint.clone();
        (laser, s3, out, arc, report.vouched_beams)
    };
    let (laser, s3, out, arc, vouched) = run(true);
    let mut kept = 0;
    for i in s3.first..s3.end {
        if i % 2 == 1 && arc[i].is_finite() {
            // Reached the wall: the laser's range, marked both.
            assert_eq!(out.beam_source(i), SectionSource::Both, "beam {i}");
            assert_eq!(out.scan.beam(i), laser.beam(i), "beam {i}");
            kept += 1;
        } else if i % 2 == 1 {
            // Outside the sonar's arc: nothing, as before.
            assert_eq!(out.beam_source(i), SectionSource::Sonar, "beam {i}");
            assert_eq!(out.scan.beam(i), BeamReading::BeyondMax, "beam {i}");
        } else {
            // Caught by the smoke: the sonar's arc (or nothing), never 0.7 m.
            assert_eq!(out.beam_source(i), SectionSource::Sonar, "beam {i}");
            assert_ne!(out.scan.beam(i), BeamReading::Range(0.7), "beam {i}");
        }
    }
    assert!(kept >= 5, "{kept} beams kept");
    assert_eq!(vouched, kept, "the report counts the beams kept");
    // Off: the whole section is the sonar's arc, as in the paper.
    let (_, s3, out, _, vouched) = run(false);
    assert_eq!(vouched, 0);
    for i in s3.first..s3.end {
        assert_eq!(out.beam_source(i), SectionSource::Sonar, "beam {i}");
    }
}

#[test]
fn v2_ignores_a_contradicting_sonar_in_clean_air() {
    // The same phantom-looking section without smoke: sonars miss walls by
    // specular reflection far more often than the laser invents one, so the
    // output stays the input, bit for bit.
    let (mut e, sonar, mut out) = v2_small_room(0.0, SmokeTrend::Steady);
    let (laser, _) = phantom_in_section(&e, 3, 0.7);
    e.step(
        Some(&laser),
        Some(&sonar),
        Some(&smoke(0, 0.0, SmokeTrend::Steady)),
        &mut out,
    )
    .unwrap();
    assert_eq!(bits(&out.scan), bits(&laser));
    assert_eq!(out.sonar_usage(), 0.0);
}

#[test]
fn v2_drops_single_contradicted_beams_of_a_kept_section() {
    // Patchy smoke: every fourth beam of sonar 3's section reads 0.5 m, the rest
    // the wall. Too few to give the section away, but those beams go.
    let (mut e, sonar, mut out) = v2_small_room(60.0, SmokeTrend::Rising);
    let s3 = *e
        .sections
        .as_slice()
        .iter()
        .find(|s| s.sonar_index == 3)
        .unwrap();
    let laser = urg(0, |i, a| {
        if (s3.first..s3.end).contains(&i) && i % 12 == 0 {
            0.5
        } else {
            room(0.0, 0.0, a) as f32
        }
    });
    e.step(
        Some(&laser),
        Some(&sonar),
        Some(&smoke(0, 60.0, SmokeTrend::Rising)),
        &mut out,
    )
    .unwrap();
    let d3 = out.sections().iter().find(|d| d.sonar_index == 3).unwrap();
    assert_eq!(d3.source(), SectionSource::Laser, "{d3:?}");
    for i in s3.first..s3.end {
        if i % 12 == 0 {
            assert_eq!(out.beam_source(i), SectionSource::Neither, "beam {i}");
        } else {
            assert_eq!(out.scan.beam(i), laser.beam(i), "beam {i}");
        }
    }
}

/// The room with specks of thin smoke: beam 100 alone, 200–201 and 300–302
/// read 0.5 m.
fn specks(i: usize, a: f64) -> f32 {
    if i == 100 || (200..=201).contains(&i) || (300..=302).contains(&i) {
        0.5
    } else {
        room(0.0, 0.0, a) as f32
    }
}

#[test]
fn v2_drops_the_specks_of_thin_smoke_the_sonar_cannot_judge() {
    // Smoke level 15: measured (μ Alcoholized > 0) but too thin for the
    // sonar witness (it needs 0.5), so only the speck filter acts.
    let laser = urg(0, specks);
    let fuse = |level: f32, edit: fn(&mut smokenav_platform_config::fusion::V2Params)| {
        let trend = if level > 0.0 {
            SmokeTrend::Rising
        } else {
            SmokeTrend::Steady
        };
        let (mut e, sonar, mut out) = v2_small_room_with(level, trend, edit);
        let report = e
            .step(
                Some(&laser),
                Some(&sonar),
                Some(&smoke(0, level, trend)),
                &mut out,
            )
            .unwrap();
        (out, report.speck_beams)
    };
    // Runs of one and two beams go; three (more than the default
    // `speck_max_beams`, 2) stay.
    let (out, specks) = fuse(15.0, |_| {});
    assert_eq!(specks, 3, "the report counts the beams dropped");
    for i in 0..laser.len() {
        if i == 100 || (200..=201).contains(&i) {
            assert_eq!(out.beam_source(i), SectionSource::Neither, "beam {i}");
            assert_eq!(out.scan.beam(i).range(), None, "beam {i}");
        } else {
            assert_eq!(out.scan.beam(i), laser.beam(i), "beam {i}");
        }
    }
    // In clean air the scan is the laser's, specks and all: a thin pole is
    // more likely than smoke the smoke sensor does not smell.
    let (clean, specks) = fuse(0.0, |_| {});
    assert_eq!((bits(&clean.scan), specks), (bits(&laser), 0));
    // `speck_max_beams = 0` turns the filter off.
    let (off, specks) = fuse(15.0, |v2| v2.speck_max_beams = 0);
    assert_eq!((bits(&off.scan), specks), (bits(&laser), 0));
}

#[test]
fn same_inputs_give_the_same_outputs() {
    let run = || {
        let mut e = engine(FusionMethod::V2);
        let mut out = fused();
        let mut lines = Vec::new();
        for k in 0..20u64 {
            let t = k * 100_000_000;
            let laser = if k % 3 == 0 {
                smoky_scan(t)
            } else {
                clean_scan(t)
            };
            let sonar = if k % 5 == 0 {
                saturated_sonar(&e, t)
            } else {
                true_sonar(&e, t)
            };
            let level = (k * 17 % 300) as f32;
            e.step(
                Some(&laser),
                Some(&sonar),
                Some(&smoke(t, level, SmokeTrend::Rising)),
                &mut out,
            )
            .unwrap();
            lines.push(serde_json::to_string(&FusedScanRecord::from(&*out)).unwrap());
        }
        lines
    };
    assert_eq!(run(), run());
}

#[test]
fn output_does_not_depend_on_what_the_buffer_held() {
    let mut a = engine(FusionMethod::V1);
    let mut b = engine(FusionMethod::V1);
    let laser = smoky_scan(5);
    let sonar = true_sonar(&a, 5);
    let sm = smoke(5, 180.0, SmokeTrend::Rising);
    let mut clean_out = fused();
    let mut dirty_out = fused();
    // Leave a sonar-only scan with different sections in the second buffer first.
    b.step(None, Some(&saturated_sonar(&b, 1)), None, &mut dirty_out)
        .unwrap();
    a.step(Some(&laser), Some(&sonar), Some(&sm), &mut clean_out)
        .unwrap();
    b.step(Some(&laser), Some(&sonar), Some(&sm), &mut dirty_out)
        .unwrap();
    assert_eq!(
        FusedScanRecord::from(&*clean_out),
        FusedScanRecord::from(&*dirty_out)
    );
}

#[test]
fn unusable_laser_layout_is_passed_through_without_sections() {
    let mut e = engine(FusionMethod::V2);
    let mut laser = smoky_scan(5);
    laser.angle_increment = 0.0;
    let sonar = true_sonar(&e, 5);
    let mut out = fused();
    let r = e
        .step(
            Some(&laser),
            Some(&sonar),
            Some(&smoke(5, 300.0, SmokeTrend::Rising)),
            &mut out,
        )
        .unwrap();
    assert!(r.bad_layout);
    assert_eq!(out.section_count, 0);
    assert_eq!(out.scan, laser);
}

#[test]
fn scout_rear_sonars_outside_the_laser_view_get_no_section() {
    // Scout: 16 sonars at 22.5° steps, 20° cones; the URG-04LX sees ±119.5°.
    let e = FusionEngine::from_config(&profile("nomad-scout.toml"), None).unwrap();
    let mut e = e;
    let mut out = fused();
    let laser = clean_scan(0);
    let sonar = true_sonar(&e, 0);
    e.step(
        Some(&laser),
        Some(&sonar),
        Some(&smoke(0, 0.0, SmokeTrend::Steady)),
        &mut out,
    )
    .unwrap();
    let idx: Vec<u8> = out.sections().iter().map(|d| d.sonar_index).collect();
    assert_eq!(
        idx,
        vec![11, 12, 13, 14, 15, 0, 1, 2, 3, 4, 5],
        "right to left in beam order"
    );
}

mod hostile_input {
    use super::*;
    use proptest::prelude::*;
    use smokenav_shared_types::{SmokeSensorState, SonarStatus};

    fn any_f32() -> impl Strategy<Value = f32> {
        prop_oneof![
            -10.0f32..10.0,
            Just(f32::NAN),
            Just(f32::INFINITY),
            Just(f32::NEG_INFINITY),
            Just(0.0),
            Just(f32::MAX),
            any::<f32>(),
        ]
    }

    prop_compose! {
        fn any_scan()(
            angle_min in any_f32(),
            inc in prop_oneof![Just(0.006_135_9f32), any_f32()],
            count in prop_oneof![Just(682u32), 0u32..2000, any::<u32>()],
            range_min in any_f32(),
            beams in prop::collection::vec((any_f32(), prop_oneof![Just(0u16), any::<u16>()]), 0..64),
        ) -> LaserScan {
            let mut s = LaserScan { angle_min, angle_increment: inc, count, range_min, range_max: 5.6, ..Default::default() };
            for i in 0..s.len() {
                let (r, e) = beams.get(i % beams.len().max(1)).copied().unwrap_or((1.0, 0));
                s.ranges[i] = r;
                s.beam_error[i] = e;
            }
            s
        }
    }

    prop_compose! {
        fn any_ring()(
            max_range in any_f32(),
            count in prop_oneof![0u32..40, any::<u32>()],
            readings in prop::collection::vec((any::<u8>(), any_f32(), any::<u8>()), 0..40),
        ) -> SonarRing {
            let mut r = SonarRing { max_range, count, ..Default::default() };
            for (k, &(index, range, status)) in readings.iter().take(r.readings.len()).enumerate() {
                r.readings[k] = SonarReading { range, index, status, _reserved: [0; 2] };
            }
            r
        }
    }

    prop_compose! {
        fn any_smoke()(level in any_f32(), trend in any::<u8>(), state in any::<u8>()) -> SmokeReading {
            SmokeReading { level, trend, state, ..Default::default() }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

        #[test]
        fn arbitrary_messages_never_panic_and_give_json_safe_output(
            method in prop_oneof![Just(FusionMethod::LaserOnly), Just(FusionMethod::V1), Just(FusionMethod::V2)],
            laser in proptest::option::of(any_scan()),
            sonar in proptest::option::of(any_ring()),
            smoke in proptest::option::of(any_smoke()),
        ) {
            let mut e = engine(method);
            let mut out = fused();
            if let Ok(r) = e.step(laser.as_ref(), sonar.as_ref(), smoke.as_ref(), &mut out) {
                prop_assert!(r.sonar_sections <= r.sections);
                for d in out.sections() {
                    prop_assert!(d.rho_sonar.is_finite() && d.rho_laser.is_finite() && d.sonar_range.is_finite());
                    prop_assert!(d.first_beam <= d.end_beam && usize::from(d.end_beam) <= out.scan.len());
                }
                prop_assert!(out.smoke_level.is_finite() && out.laser_spread.is_finite());
                // The scan's own scalars are the laser's, passed through: JSON
                // cannot carry a NaN angle_min (a shared-types limit), so only
                // what the engine adds is checked for those.
                let s = &out.scan;
                let scalars = [s.angle_min, s.angle_increment, s.time_increment, s.scan_time, s.range_min, s.range_max];
                if scalars.iter().any(|x| !x.is_finite()) {
                    return Ok(());
                }
                let rec = FusedScanRecord::from(&*out);
                let json = serde_json::to_string(&rec).unwrap();
                let back: FusedScanRecord = serde_json::from_str(&json).unwrap();
                prop_assert_eq!(back.sections.len(), rec.sections.len());
            }
        }
    }

    #[test]
    fn unknown_sonar_indices_and_statuses_are_ignored() {
        let mut e = engine(FusionMethod::V2);
        let mut ring = SonarRing::default();
        ring.push(SonarReading::new(200, 1.0, SonarStatus::Valid));
        ring.push(SonarReading {
            range: 1.0,
            index: 3,
            status: 77,
            _reserved: [0; 2],
        });
        let mut out = fused();
        let mut smoke = smoke(0, 250.0, SmokeTrend::Rising);
        smoke.state = SmokeSensorState::Ready as u8;
        e.step(Some(&smoky_scan(0)), Some(&ring), Some(&smoke), &mut out)
            .unwrap();
        // Status 77 is not a valid echo: no section may use the sonar.
        assert!(
            out.sections()
                .iter()
                .all(|d| d.source() != SectionSource::Sonar)
        );
    }
}

#[test]
fn before_any_scan_sonar_only_takes_the_configured_laser_layout_bit_for_bit() {
    for name in ["pioneer-3dx.toml", "nomad-scout.toml"] {
        let cfg = profile(name);
        let mut e = FusionEngine::from_config(&cfg, Some(FusionMethod::V2)).unwrap();
        let mut out = fused();
        e.step(None, Some(&saturated_sonar(&e, 7)), None, &mut out)
            .unwrap();
        // `[laser] scan` is the URG-04LX's PP: the same layout its scans carry.
        let urg = urg_scan(0, 0, |_, _| 1.0);
        let s = &out.scan;
        assert_eq!(s.len(), 682, "{name}");
        assert_eq!(
            (s.angle_min.to_bits(), s.angle_increment.to_bits()),
            (urg.angle_min.to_bits(), urg.angle_increment.to_bits())
        );
        assert_eq!(
            (s.range_min, s.range_max, s.scan_time, s.time_increment),
            (
                urg.range_min,
                urg.range_max,
                urg.scan_time,
                urg.time_increment
            )
        );
        assert_eq!(s.header.frame_id.as_str(), cfg.laser.frame_id);
    }
}

#[test]
fn without_a_configured_layout_sonar_only_waits_for_the_first_scan() {
    let mut cfg = profile("pioneer-3dx.toml");
    cfg.laser.scan = None;
    let mut e = FusionEngine::from_config(&cfg, Some(FusionMethod::V2)).unwrap();
    let mut out = fused();
    let sonar = true_sonar(&e, 5);
    assert_eq!(
        e.step(None, Some(&sonar), None, &mut out),
        Err(StepError::NoLayout)
    );
    // A 360-beam laser: its layout, not a URG's, shapes what follows.
    let mut wide = clean_scan(1);
    wide.angle_min = -std::f32::consts::PI;
    wide.angle_increment = std::f32::consts::TAU / 360.0;
    wide.count = 360;
    e.step(Some(&wide), Some(&sonar), None, &mut out).unwrap();
    e.step(None, Some(&sonar), None, &mut out).unwrap();
    assert_eq!(out.scan.len(), 360);
    assert_eq!(out.scan.angle_min, -std::f32::consts::PI);
}
