//! The scan the filter consumes, built from a `LaserScan`, a `FusedScan` or a
//! log record, with a noise level per beam.

use smokenav_platform_config::SlamSection;
use smokenav_shared_types::geometry::{Pose2, Sweep, Twist2};
use smokenav_shared_types::{BeamReading, FusedScan, LaserScan, SectionDecision, SectionSource};

/// Where a beam's range came from, which sets its noise.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BeamKind {
    Laser,
    Sonar,
}

/// One beam: its angle in the sensor frame and its range, or `None` when the
/// sensor saw nothing usable (no return, beyond max, error code, NaN).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Beam {
    pub angle: f32,
    pub range: Option<f32>,
    pub kind: BeamKind,
}

/// A planar range scan in the form the filter uses. Reused between messages
/// (`clear` keeps the capacity) so the hot path does not allocate.
#[derive(Debug, Clone, Default)]
pub struct RangeScan {
    /// Measurement time, ns (used for ordering and for the update thresholds).
    pub stamp_ns: u64,
    /// Pose of the sensor in the robot frame.
    pub sensor_pose: Pose2,
    pub beams: Vec<Beam>,
    /// Multiplier of the laser endpoint noise for the obscurant the scan was
    /// taken in (1 in clear air; see [`crate::noise`]).
    pub laser_noise_factor: f64,
    /// Share (0–1) of the scan's beams the fusion did not leave to the laser
    /// (sections it painted from the sonar or dropped as smoke); 0 for a laser scan.
    pub withheld_share: f64,
    /// The sonar ring's readings the fusion paired with the scan, used or
    /// rejected, as `(transducer index, range m)`; empty for a laser scan.
    /// Only a back-end that maps out of the laser plane reads them.
    pub sonar: Vec<(u8, f64)>,
    /// Per beam (empty for a laser scan): for a beam painted from a sonar,
    /// how far it lies from where on its section's painted arc the echo
    /// most likely came from, in half-widths of the arc, 0 (there) to 1 (an
    /// end, or beyond); for any other beam, `f32::NAN`. That is the arc's
    /// middle, or the centre of its third towards a neighbouring transducer
    /// that reads shorter (see `reflector_side`).
    pub arc_offset: Vec<f32>,
    /// Time between consecutive beams, s (0 where unknown, as in a CARMEN
    /// log): a laser that sweeps takes its beams while the robot moves.
    pub time_increment_s: f64,
    /// Per beam (empty for a laser scan): the transducer whose echo the
    /// fusion painted the beam from, or [`NO_SONAR`].
    pub sonar_of: Vec<u8>,
    /// Stamp of the sonar ring the fusion paired with the scan, ns (0 without).
    pub sonar_stamp_ns: u64,
    /// Per beam (empty for a laser scan): for a laser beam the fusion kept
    /// although its section's sonar heard its first echo more than
    /// [`CONTRADICTION_MARGIN_M`] further (the sonar contradicts it), how
    /// much its range jitters from beam to beam: the median |second
    /// difference| of the ranges over ±2 beams, m, a second difference
    /// over a beam without a return counting as unbounded (so a return next
    /// to a dropout is rough: a cloud's come between dropouts). `f32::NAN`
    /// for every other beam and within three beams of the scan's ends. A
    /// wall's ranges run smoothly however obliquely it is met; the returns
    /// of a smoke cloud seen from clean air, which the fusion keeps while
    /// the smoke sensor reads clean, scatter by tenths of a metre.
    pub laser_roughness: Vec<f32>,
}

/// How much nearer than its section's sonar echo a laser range must be for
/// the sonar to contradict it, m, unless told otherwise: v2's
/// `contradiction_margin_m` default ([`RangeScan::fill_from_fused`] takes
/// the profile's).
pub const CONTRADICTION_MARGIN_M: f32 = 0.3;

/// [`RangeScan::laser_roughness`] of `beams`: `echo(i)` is the sonar range
/// of the section beam `i` lies in, if any; a laser range more than
/// `margin` nearer is contradicted.
fn contradicted_roughness(
    beams: &[Beam],
    echo: impl Fn(usize) -> Option<f32>,
    margin: f32,
    out: &mut Vec<f32>,
) {
    out.clear();
    out.resize(beams.len(), f32::NAN);
    let range = |i: usize| beams.get(i).and_then(|b| b.range);
    for (i, rough) in out.iter_mut().enumerate() {
        let (Some(r), Some(e)) = (range(i), echo(i)) else {
            continue;
        };
        if beams[i].kind != BeamKind::Laser || r >= e - margin || i < 3 || i + 3 >= beams.len() {
            continue;
        }
        let mut d = [0.0f32; 5];
        let second = |j: usize| Some((range(j - 1)? - 2.0 * range(j)? + range(j + 1)?).abs());
        // A laser that returns nothing next door is no smoother for it: a
        // dropout counts as a jump without end.
        for (j, dj) in (i - 2..=i + 2).zip(d.iter_mut()) {
            *dj = second(j).unwrap_or(f32::INFINITY);
        }
        d.sort_by(f32::total_cmp);
        *rough = d[2];
    }
}

/// Which side of section `k`'s arc its echo most likely came from: a
/// sonar hears the nearest surface anywhere in its cone, so a wall met
/// obliquely echoes from the cone's edge nearest the wall's normal, not
/// from its axis. That edge faces the neighbouring transducer that reads
/// a shorter range (the normal lies in or towards its cone): `Less` for the
/// neighbour at lower beam indices, `Greater` for the one above, `None`
/// when neither or both read shorter (the axis is as good a guess as any).
fn reflector_side(sections: &[SectionDecision], k: usize) -> Option<std::cmp::Ordering> {
    let centre = |d: &SectionDecision| u32::from(d.first_beam) + u32::from(d.end_beam);
    let me = sections.get(k)?;
    let r = me.sonar_range;
    if !(r.is_finite() && r > 0.0) {
        return None;
    }
    let c = centre(me);
    let below = sections
        .iter()
        .filter(|d| centre(d) < c)
        .max_by_key(|d| centre(d));
    let above = sections
        .iter()
        .filter(|d| centre(d) > c)
        .min_by_key(|d| centre(d));
    let shorter = |d: Option<&SectionDecision>| {
        d.is_some_and(|d| d.sonar_range.is_finite() && d.sonar_range > 0.0 && d.sonar_range < r)
    };
    match (shorter(below), shorter(above)) {
        (true, false) => Some(std::cmp::Ordering::Less),
        (false, true) => Some(std::cmp::Ordering::Greater),
        _ => None,
    }
}

/// [`RangeScan::sonar_of`] of a beam not painted from a sonar.
pub const NO_SONAR: u8 = u8::MAX;

/// Which beams' endpoints the scan matchers use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EndpointLimits {
    /// Readings at or beyond this are no return, m.
    pub max_range: f64,
    /// Readings beyond this only clear free space, m.
    pub max_urange: f64,
    /// Use every (lskip+1)-th usable beam.
    pub lskip: usize,
    /// Endpoints closer than this to the last one kept are dropped, m.
    pub min_spacing: f64,
}

impl EndpointLimits {
    pub fn from_config(c: &SlamSection) -> Self {
        Self {
            max_range: c.max_range_m,
            max_urange: c.max_urange_m,
            lskip: c.lskip as usize,
            min_spacing: c.resolution_m,
        }
    }
}

/// A beam's endpoint in the robot frame, with the beam's direction and range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Endpoint {
    pub x: f64,
    pub y: f64,
    pub range: f64,
    /// Direction of the beam in the robot frame.
    pub cos: f64,
    pub sin: f64,
    pub kind: BeamKind,
    /// The range is the laser's: a laser beam, or one in a section the
    /// fusion gave to the sonar whose echo did not contradict it (`Both`;
    /// `kind` is then [`BeamKind::Sonar`]).
    pub laser_range: bool,
}

impl RangeScan {
    /// The endpoints a scan matcher uses, into `out` (cleared first): beams with
    /// a range inside `max_urange`, every `lskip+1`-th, at least `min_spacing`
    /// from the previous endpoint kept (closer ones add cost but no information,
    /// and would count the same evidence twice in a likelihood).
    pub fn endpoints(&self, lim: &EndpointLimits, out: &mut Vec<Endpoint>) {
        out.clear();
        let min_spacing2 = lim.min_spacing * lim.min_spacing;
        let sensor = &self.sensor_pose;
        let mut used = 0usize;
        for (i, beam) in self.beams.iter().enumerate() {
            let Some(r) = beam.range else { continue };
            let r = r as f64;
            if !(r > 0.0 && r < lim.max_range && beam.angle.is_finite()) || r > lim.max_urange {
                continue;
            }
            let skip = !used.is_multiple_of(lim.lskip + 1);
            used += 1;
            if skip {
                continue;
            }
            let (sin, cos) = (sensor.theta + beam.angle as f64).sin_cos();
            let (x, y) = (sensor.x + cos * r, sensor.y + sin * r);
            if let Some(last) = out.last()
                && (last.x - x).powi(2) + (last.y - y).powi(2) < min_spacing2
            {
                continue;
            }
            out.push(Endpoint {
                x,
                y,
                range: r,
                cos,
                sin,
                kind: beam.kind,
                laser_range: beam.kind == BeamKind::Laser
                    || self.sonar_of.get(i).is_some_and(|&s| s == NO_SONAR),
            });
        }
    }

    pub fn clear(&mut self) {
        self.beams.clear();
        self.laser_noise_factor = 1.0;
        self.withheld_share = 0.0;
        self.sonar.clear();
        self.arc_offset.clear();
        self.sonar_of.clear();
        self.laser_roughness.clear();
        self.sonar_stamp_ns = 0;
        self.time_increment_s = 0.0;
        self.sensor_pose = Pose2::default();
        self.stamp_ns = 0;
    }

    /// Puts every laser beam where it would have been had the whole sweep
    /// been taken at the scan's stamp (its first beam), the robot moving at
    /// `twist` meanwhile ([`Sweep`]). A scan matched as if taken at once
    /// bends every wall, so the tracked pose and each wall drawn from it are
    /// off by centimetres. No-op without a time increment.
    pub fn deskew(&mut self, twist: Twist2) {
        let Some(sweep) = Sweep::new(self.sensor_pose, twist, self.time_increment_s) else {
            return;
        };
        for (i, beam) in self.beams.iter_mut().enumerate() {
            let Some(r) = beam.range.filter(|_| beam.kind == BeamKind::Laser) else {
                continue;
            };
            let (angle, range) = sweep.beam(i, f64::from(beam.angle), f64::from(r));
            beam.angle = angle as f32;
            beam.range = Some(range as f32);
        }
    }

    /// Moves every beam painted from a sonar to where its echo was: the
    /// transducer heard it from the robot's pose `shift(index)` (that pose
    /// in the robot frame at the scan's stamp; `None` leaves its beams),
    /// not from where the robot is now ([`crate::sonar_age`]).
    pub fn compensate_sonar(&mut self, mut shift: impl FnMut(u8) -> Option<Pose2>) {
        let s = self.sensor_pose;
        let mut current: Option<(u8, Option<Pose2>)> = None;
        for (beam, &index) in self.beams.iter_mut().zip(&self.sonar_of) {
            if index == NO_SONAR {
                continue;
            }
            let Some(r) = beam.range else { continue };
            let t = match current {
                Some((i, t)) if i == index => t,
                _ => {
                    let t = shift(index);
                    current = Some((index, t));
                    t
                }
            };
            let Some(t) = t else { continue };
            // The endpoint as painted (robot frame), then where it was heard.
            let a = s.theta + f64::from(beam.angle);
            let (px, py) = (s.x + f64::from(r) * a.cos(), s.y + f64::from(r) * a.sin());
            let (st, ct) = t.theta.sin_cos();
            let (qx, qy) = (t.x + ct * px - st * py, t.y + st * px + ct * py);
            let (dx, dy) = (qx - s.x, qy - s.y);
            let range = dx.hypot(dy);
            if range > 1e-3 {
                beam.range = Some(range as f32);
                beam.angle = smokenav_shared_types::normalize_angle(dy.atan2(dx) - s.theta) as f32;
            }
        }
    }

    /// Beams that carry a range.
    pub fn valid_count(&self) -> usize {
        self.beams.iter().filter(|b| b.range.is_some()).count()
    }

    /// Fills from a laser scan; `sensor_pose` is the laser's mount on the robot.
    pub fn fill_from_laser(&mut self, scan: &LaserScan, sensor_pose: Pose2) {
        self.clear();
        self.stamp_ns = scan.header.stamp_ns;
        self.sensor_pose = sensor_pose;
        let range_min = if scan.range_min.is_finite() {
            scan.range_min
        } else {
            0.0
        };
        let range_max = if scan.range_max.is_finite() && scan.range_max > 0.0 {
            scan.range_max
        } else {
            f32::INFINITY
        };
        self.time_increment_s = scan.sweep_time_increment().unwrap_or(0.0);
        for (angle, reading) in scan.beams() {
            let range = match reading {
                BeamReading::Range(r) if r.is_finite() && r >= range_min && r < range_max => {
                    Some(r)
                }
                _ => None,
            };
            self.beams.push(Beam {
                angle,
                range,
                kind: BeamKind::Laser,
            });
        }
    }

    /// Fills from a fused scan: beams whose source is sonar get the sonar's
    /// noise; `Neither` beams carry no range; the laser's noise follows the
    /// smoke level. `contradiction_margin_m` is the fusion's (`[fusion.v2]
    /// contradiction_margin_m`): a laser range that much nearer than its
    /// section's echo is one the sonar contradicts.
    pub fn fill_from_fused(
        &mut self,
        fused: &FusedScan,
        sensor_pose: Pose2,
        laser_noise_factor: f64,
        contradiction_margin_m: f32,
    ) {
        self.fill_from_laser(&fused.scan, sensor_pose);
        self.laser_noise_factor = if laser_noise_factor.is_finite() && laser_noise_factor > 0.0 {
            laser_noise_factor
        } else {
            1.0
        };
        let mut withheld = 0usize;
        self.sonar_stamp_ns = fused.sonar_stamp_ns;
        self.sonar_of.clear();
        self.sonar_of.resize(self.beams.len(), NO_SONAR);
        for (i, beam) in self.beams.iter_mut().enumerate() {
            match fused.beam_source(i) {
                // Both: a laser range the sonar did not contradict in a
                // section smoke gave to the sonar. Mapped, but not matched:
                // a part view through smoke slides the matcher.
                SectionSource::Sonar | SectionSource::Both => {
                    beam.kind = BeamKind::Sonar;
                    withheld += 1;
                }
                SectionSource::Neither => {
                    beam.range = None;
                    withheld += 1;
                }
                SectionSource::Laser => {}
            }
        }
        self.withheld_share = withheld as f64 / self.beams.len().max(1) as f64;
        let used = (fused.section_count as usize).min(fused.sections.len());
        let n = self.beams.len();
        self.arc_offset.resize(n, f32::NAN);
        let sections = &fused.sections[..used];
        for (k, d) in sections.iter().enumerate() {
            let (a, b) = ((d.first_beam as usize).min(n), (d.end_beam as usize).min(n));
            let painted = |i: &usize| fused.beam_source(*i) == SectionSource::Sonar;
            let (Some(first), Some(last)) = ((a..b).find(painted), (a..b).rev().find(painted))
            else {
                continue;
            };
            let half = ((last - first) as f32 / 2.0).max(0.5);
            let middle = (first + last) as f32 / 2.0;
            // Where on the arc the echo came from (see `reflector_side`):
            // the middle, or the centre of the third towards the neighbour.
            let reflector = match reflector_side(sections, k) {
                Some(std::cmp::Ordering::Less) => first as f32 + half / 3.0,
                Some(std::cmp::Ordering::Greater) => last as f32 - half / 3.0,
                _ => middle,
            };
            for i in first..=last {
                if painted(&i) {
                    self.arc_offset[i] = ((i as f32 - reflector).abs() / half).min(1.0);
                    self.sonar_of[i] = d.sonar_index;
                }
            }
        }
        let echo = |i: usize| {
            let d = sections
                .iter()
                .find(|d| (usize::from(d.first_beam)..usize::from(d.end_beam)).contains(&i))?;
            (d.sonar_range.is_finite() && d.sonar_range > 0.0).then_some(d.sonar_range)
        };
        contradicted_roughness(
            &self.beams,
            echo,
            contradiction_margin_m,
            &mut self.laser_roughness,
        );
        self.sonar.extend(
            fused.sections[..used]
                .iter()
                .filter(|d| d.sonar_range.is_finite() && d.sonar_range > 0.0)
                .map(|d| (d.sonar_index, f64::from(d.sonar_range))),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_shared_types::Header;

    #[test]
    fn invalid_beams_carry_no_range() {
        let mut s = LaserScan {
            header: Header::new(5, 0, "laser"),
            angle_min: -1.0,
            angle_increment: 0.5,
            range_min: 0.02,
            range_max: 5.6,
            count: 5,
            ..Default::default()
        };
        s.set_beam(0, BeamReading::Range(1.0));
        s.set_beam(1, BeamReading::NoReturn);
        s.set_beam(2, BeamReading::Range(0.01));
        s.set_beam(3, BeamReading::Range(f32::NAN));
        s.set_beam(4, BeamReading::SensorCode(7));
        let mut r = RangeScan::default();
        r.fill_from_laser(&s, Pose2::default());
        assert_eq!(r.beams.len(), 5);
        assert_eq!(r.valid_count(), 1);
        assert_eq!(r.beams[0].range, Some(1.0));
        assert_eq!(r.beams[2].angle, 0.0);
        assert_eq!(r.stamp_ns, 5);
    }

    #[test]
    fn fused_sonar_and_both_beams_are_marked_and_neither_beams_dropped() {
        let mut f = FusedScan::default();
        f.scan.count = 4;
        f.scan.range_max = 5.6;
        for i in 0..4 {
            f.scan.set_beam(i, BeamReading::Range(2.0));
        }
        f.beam_source[1] = SectionSource::Sonar as u8;
        f.beam_source[2] = SectionSource::Neither as u8;
        // A laser range v2 kept in a section it gave to the sonar.
        f.beam_source[3] = SectionSource::Both as u8;
        // Two sections: sonar 3 heard 1.2 m, sonar 4 gave no reading (0).
        f.section_count = 2;
        f.sections[0].sonar_index = 3;
        f.sections[0].sonar_range = 1.2;
        f.sections[1].sonar_index = 4;
        f.sections[5].sonar_range = 2.0; // beyond section_count: not read
        let mut r = RangeScan::default();
        r.fill_from_fused(&f, Pose2::default(), 1.3, CONTRADICTION_MARGIN_M);
        assert_eq!(r.sonar.len(), 1);
        assert_eq!(r.sonar[0].0, 3);
        assert!((r.sonar[0].1 - 1.2).abs() < 1e-6);
        assert_eq!(r.beams[0].kind, BeamKind::Laser);
        assert_eq!(r.beams[1].kind, BeamKind::Sonar);
        assert_eq!(r.beams[2].range, None);
        // Mapped with its range, but not matched as the laser.
        assert_eq!(
            (r.beams[3].kind, r.beams[3].range),
            (BeamKind::Sonar, Some(2.0))
        );
        assert_eq!(r.laser_noise_factor, 1.3);
        assert!(
            (r.withheld_share - 3.0 / 4.0).abs() < 1e-12,
            "{}",
            r.withheld_share
        );
        r.clear();
        assert_eq!(r.withheld_share, 0.0);
        assert!(r.sonar.is_empty());
        assert!(r.arc_offset.is_empty());
    }

    /// A fused scan of `count` beams, every one at 2 m, no section yet.
    fn every_beam_at_2m(count: usize) -> FusedScan {
        let mut f = FusedScan::default();
        f.scan.count = count as u32;
        f.scan.range_max = 5.6;
        for i in 0..count {
            f.scan.set_beam(i, BeamReading::Range(2.0));
        }
        f
    }

    /// Lays out `f`'s sections as `(first beam, end beam, sonar index)`.
    fn set_sections(f: &mut FusedScan, sections: &[(u16, u16, u8)]) {
        f.section_count = sections.len() as u32;
        for (d, &(first, end, sonar)) in f.sections.iter_mut().zip(sections) {
            d.first_beam = first;
            d.end_beam = end;
            d.sonar_index = sonar;
        }
    }

    #[test]
    fn a_painted_arc_s_beams_know_how_far_they_lie_from_its_middle() {
        let mut f = every_beam_at_2m(30);
        // Section 0 (beams 0..20) painted from its sonar over beams 5..=15,
        // one of them (10) kept from the laser (`Both`); section 1 the laser's.
        set_sections(&mut f, &[(0, 20, 0), (20, 30, 1)]);
        for i in 5..=15 {
            f.beam_source[i] = SectionSource::Sonar as u8;
        }
        f.beam_source[10] = SectionSource::Both as u8;
        let mut r = RangeScan::default();
        r.fill_from_fused(&f, Pose2::default(), 1.0, CONTRADICTION_MARGIN_M);
        assert_eq!(r.arc_offset.len(), 30);
        assert_eq!(r.arc_offset[5], 1.0);
        assert_eq!(r.arc_offset[15], 1.0);
        assert!((r.arc_offset[8] - 0.4).abs() < 1e-6);
        assert!((r.arc_offset[12] - 0.4).abs() < 1e-6);
        for i in [0, 4, 10, 16, 25] {
            assert!(r.arc_offset[i].is_nan(), "beam {i}: not painted");
        }
    }

    #[test]
    fn a_laser_return_the_sonar_contradicts_carries_how_rough_it_is() {
        // Four sections of 15 beams, every beam kept from the laser. 0: a
        // smooth oblique wall at 1.0–1.7 m, its sonar heard 2.5 m (contradicted,
        // smooth). 1: a scatter at 1.0/1.3 m (a smoke cloud), sonar 2.5 m
        // (contradicted, rough). 2: the same scatter with the sonar at 1.2 m
        // (not contradicted). 3: the scatter painted from the sonar.
        let mut f = every_beam_at_2m(60);
        set_sections(&mut f, &[(0, 15, 0), (15, 30, 1), (30, 45, 2), (45, 60, 3)]);
        for (d, r) in f.sections.iter_mut().zip([2.5, 2.5, 1.2, 2.5]) {
            d.sonar_range = r;
        }
        for i in 0..15 {
            f.scan
                .set_beam(i, BeamReading::Range(1.0 + 0.003 * (i * i) as f32));
        }
        for i in 15..60 {
            f.scan
                .set_beam(i, BeamReading::Range(if i % 2 == 0 { 1.0 } else { 1.3 }));
        }
        for i in 45..60 {
            f.beam_source[i] = SectionSource::Sonar as u8;
        }
        let mut r = RangeScan::default();
        r.fill_from_fused(&f, Pose2::default(), 1.0, CONTRADICTION_MARGIN_M);
        assert_eq!(r.laser_roughness.len(), 60);
        for i in 3..12 {
            let rough = r.laser_roughness[i];
            assert!(
                (rough - 0.006).abs() < 1e-4,
                "beam {i}: a smooth wall, got {rough}"
            );
        }
        for i in 18..27 {
            let rough = r.laser_roughness[i];
            assert!(
                (rough - 0.6).abs() < 1e-4,
                "beam {i}: a scatter, got {rough}"
            );
        }
        for i in (0..3).chain(30..60) {
            assert!(r.laser_roughness[i].is_nan(), "beam {i}");
        }
        // A plain laser scan has none.
        r.fill_from_laser(&f.scan, Pose2::default());
        assert!(r.laser_roughness.is_empty());
    }

    #[test]
    fn the_sonar_contradicts_by_the_fusions_margin() {
        // One section, a smooth wall at 1.0–1.6 m, its sonar heard 2.5 m.
        let mut f = every_beam_at_2m(15);
        set_sections(&mut f, &[(0, 15, 0)]);
        f.sections[0].sonar_range = 2.5;
        for i in 0..15 {
            f.scan
                .set_beam(i, BeamReading::Range(1.0 + 0.003 * (i * i) as f32));
        }
        let mut r = RangeScan::default();
        // 0.9 m or more nearer than the echo: contradicted at 0.3 m...
        r.fill_from_fused(&f, Pose2::default(), 1.0, 0.3);
        assert!((3..12).all(|i| r.laser_roughness[i].is_finite()));
        // ...but not with a fusion told to keep laser ranges within 1.6 m.
        r.fill_from_fused(&f, Pose2::default(), 1.0, 1.6);
        assert!(r.laser_roughness.iter().all(|x| x.is_nan()));
    }

    #[test]
    fn a_contradicted_return_next_to_a_dropout_is_rough() {
        // Two sections of 30 beams, both sonars heard 2.5 m. 0: a smooth
        // wall at 1.0–3.5 m with one dropout (beam 15). 1: a smoke cloud
        // the laser returns from at an even 2 m, every third beam nothing.
        let mut f = every_beam_at_2m(60);
        set_sections(&mut f, &[(0, 30, 0), (30, 60, 1)]);
        for d in f.sections.iter_mut() {
            d.sonar_range = 2.5;
        }
        for i in 0..30 {
            f.scan
                .set_beam(i, BeamReading::Range(1.0 + 0.003 * (i * i) as f32));
        }
        f.scan.set_beam(15, BeamReading::NoReturn);
        for i in (30..60).step_by(3) {
            f.scan.set_beam(i, BeamReading::NoReturn);
        }
        let mut r = RangeScan::default();
        r.fill_from_fused(&f, Pose2::default(), 1.0, CONTRADICTION_MARGIN_M);
        let rough = &r.laser_roughness;
        // Once without a return, the wall is still smooth two beams away
        // (the median of five second differences has two unbounded ones).
        for i in (3..14).chain(17..20) {
            assert!((rough[i] - 0.006).abs() < 1e-4, "beam {i}: {}", rough[i]);
        }
        // Before, a neighbour without a return left every one of these
        // unmeasured (NaN), and the cloud was drawn as a wall.
        for i in [14, 16].into_iter().chain((31..57).filter(|i| i % 3 != 0)) {
            assert_eq!(rough[i], f32::INFINITY, "beam {i}");
        }
        // Where the sonar does not contradict the wall (from beam 20 it is
        // 2.2 m away or more) and within three beams of the scan's ends
        // nothing is measured.
        for i in (0..3).chain(20..30).chain(57..60) {
            assert!(rough[i].is_nan(), "beam {i}: {}", rough[i]);
        }
    }

    /// Three adjacent sections of ten beams, all painted from their sonars,
    /// which read `ranges`; the beams of the middle one drawn as its echo
    /// (within a third of the arc's half-width of where the echo came from).
    fn middle_section_s_echo(ranges: [f32; 3]) -> Vec<usize> {
        let mut f = every_beam_at_2m(30);
        set_sections(&mut f, &[(0, 10, 0), (10, 20, 1), (20, 30, 2)]);
        for (d, r) in f.sections.iter_mut().zip(ranges) {
            d.sonar_range = r;
        }
        f.beam_source[..30].fill(SectionSource::Sonar as u8);
        let mut r = RangeScan::default();
        r.fill_from_fused(&f, Pose2::default(), 1.0, CONTRADICTION_MARGIN_M);
        (10..20).filter(|&i| r.arc_offset[i] <= 1.0 / 3.0).collect()
    }

    #[test]
    fn an_echo_is_drawn_on_the_third_of_its_arc_towards_a_neighbour_that_reads_shorter() {
        // A wall whose normal lies in the lower neighbour's cone: the middle
        // sonar heard it at its cone's lower edge.
        assert_eq!(
            middle_section_s_echo([1.0, 1.05, 1.2]),
            vec![10, 11, 12, 13]
        );
        assert_eq!(
            middle_section_s_echo([1.2, 1.05, 1.0]),
            vec![16, 17, 18, 19]
        );
        // Both neighbours farther (the wall faces it) or nearer (no telling),
        // or a neighbour without an echo: the middle third.
        let middle = vec![13, 14, 15, 16];
        assert_eq!(middle_section_s_echo([1.2, 1.05, 1.2]), middle);
        assert_eq!(middle_section_s_echo([1.0, 1.05, 1.0]), middle);
        assert_eq!(middle_section_s_echo([f32::INFINITY, 1.05, 1.2]), middle);
        assert_eq!(middle_section_s_echo([f32::NAN, 1.05, 1.2]), middle);
    }

    #[test]
    fn echoes_painted_from_a_sonar_move_by_the_motion_since_it_fired_and_nothing_else_does() {
        // Beams every 10° from −90° to 90°; the sonar of section 0 (index 3)
        // painted the beams at −10°..10° (one of them `Both`: the laser's
        // range), the sonar of section 1 (index 4) the one at 90°.
        let mut f = every_beam_at_2m(19);
        f.scan.angle_min = -std::f32::consts::FRAC_PI_2;
        f.scan.angle_increment = 10f32.to_radians();
        set_sections(&mut f, &[(0, 15, 3), (15, 19, 4)]);
        for i in 8..=10 {
            f.beam_source[i] = SectionSource::Sonar as u8;
        }
        f.beam_source[8] = SectionSource::Both as u8;
        f.beam_source[18] = SectionSource::Sonar as u8;
        let mount = Pose2::new(0.1, 0.0, 0.0);
        let mut r = RangeScan::default();
        r.fill_from_fused(&f, mount, 1.0, CONTRADICTION_MARGIN_M);
        assert_eq!(r.sonar_of[9], 3);
        assert_eq!(r.sonar_of[8], NO_SONAR, "Both: the laser's range");
        assert_eq!(r.sonar_of[18], 4);
        let before = r.beams.clone();
        // Both heard from 0.3 m further back (the robot drove on since).
        r.compensate_sonar(|_| Some(Pose2::new(-0.3, 0.0, 0.0)));
        // Straight ahead the wall is 0.3 m nearer, same bearing.
        assert!((r.beams[9].range.unwrap() - 1.7).abs() < 1e-5);
        assert!(r.beams[9].angle.abs() < 1e-6);
        // Off to the side at 10°: the endpoint moved 0.3 m back, not the range.
        let (x, y) = (
            0.1 + 2.0 * 10f64.to_radians().cos() - 0.3,
            2.0 * 10f64.to_radians().sin(),
        );
        let b = r.beams[10];
        assert!((f64::from(b.range.unwrap()) - (x - 0.1).hypot(y)).abs() < 1e-5);
        assert!((f64::from(b.angle) - y.atan2(x - 0.1)).abs() < 1e-5);
        // Abeam (90°): the same range, the bearing turned back.
        let b = r.beams[18];
        assert!((f64::from(b.range.unwrap()) - 2.0f64.hypot(0.3)).abs() < 1e-5);
        assert!(f64::from(b.angle) > std::f64::consts::FRAC_PI_2);
        // Laser beams, the `Both` beam and beams whose sonar has no age stay.
        for i in (0..8).chain([8, 11, 12, 17]) {
            assert_eq!(r.beams[i], before[i], "beam {i}");
        }
        let mut again = RangeScan::default();
        again.fill_from_fused(&f, mount, 1.0, CONTRADICTION_MARGIN_M);
        again.compensate_sonar(|index| (index == 4).then(|| Pose2::new(-0.3, 0.0, 0.0)));
        assert_eq!(again.beams[9], before[9], "sonar 3 without an age");
        assert_ne!(again.beams[18], before[18]);
    }

    /// Distance from `(x, y)` to the nearest wall of the test room.
    fn off_the_walls(x: f64, y: f64) -> f64 {
        crate::testkit::WALLS
            .iter()
            .map(|&(x1, y1, x2, y2)| {
                let (ex, ey) = (x2 - x1, y2 - y1);
                let t = (((x - x1) * ex + (y - y1) * ey) / (ex * ex + ey * ey)).clamp(0.0, 1.0);
                (x - x1 - t * ex).hypot(y - y1 - t * ey)
            })
            .fold(f64::INFINITY, f64::min)
    }

    /// A 361-beam, 180° sweep of the test room, beam `i` taken `i × dt`
    /// after the first while the robot moves from `start` at `twist`; the
    /// laser 0.2 m ahead of the robot's centre.
    fn swept(start: &Pose2, twist: Twist2, dt: f64) -> RangeScan {
        let sensor = Pose2::new(0.2, 0.0, 0.0);
        let mut s = RangeScan {
            sensor_pose: sensor,
            time_increment_s: dt,
            ..Default::default()
        };
        for i in 0..361 {
            let a = -std::f64::consts::FRAC_PI_2 + i as f64 * std::f64::consts::PI / 360.0;
            let t = i as f64 * dt;
            let at = start.compose(&twist.motion(t)).compose(&sensor);
            s.beams.push(Beam {
                angle: a as f32,
                range: crate::testkit::cast(at.x, at.y, at.theta + a).map(|r| r as f32),
                kind: BeamKind::Laser,
            });
        }
        s
    }

    /// The farthest any beam's end lies off the room's walls, drawn from `start`.
    fn worst_end(s: &RangeScan, start: &Pose2) -> f64 {
        let at = start.compose(&s.sensor_pose);
        s.beams
            .iter()
            .filter_map(|b| {
                let r = f64::from(b.range?);
                let a = at.theta + f64::from(b.angle);
                Some(off_the_walls(at.x + r * a.cos(), at.y + r * a.sin()))
            })
            .fold(0.0, f64::max)
    }

    #[test]
    fn a_sweep_taken_while_the_robot_turns_is_put_back_at_its_first_beam() {
        // The URG-04LX's 67 ms for 240° (0.1 ms a step of 0.35°); here
        // 0.5° steps over 180° in the same 67 ms.
        let dt = 67e-3 / 360.0;
        let start = Pose2::new(-3.5, -1.5, 0.3);
        let twist = Twist2::new(0.5, 0.0, 1.0);
        let mut s = swept(&start, twist, dt);
        let skewed = worst_end(&s, &start);
        assert!(skewed > 0.05, "the sweep bends the walls by {skewed} m");
        s.deskew(twist);
        let deskewed = worst_end(&s, &start);
        assert!(
            deskewed < 1e-3,
            "{deskewed} m off the walls after deskewing"
        );
    }

    #[test]
    fn a_scan_without_a_time_increment_or_sonar_beams_are_left_as_they_are() {
        let start = Pose2::new(-3.5, -1.5, 0.3);
        let mut s = swept(&start, Twist2::default(), 0.0);
        let before = s.beams.clone();
        s.deskew(Twist2::new(0.5, 0.0, 1.0));
        assert_eq!(s.beams, before, "no time increment: nothing to correct");
        s.time_increment_s = 1e-4;
        for b in s.beams.iter_mut().step_by(2) {
            b.kind = BeamKind::Sonar;
        }
        let before = s.beams.clone();
        s.deskew(Twist2::new(0.5, 0.0, 1.0));
        for (b, a) in s.beams.iter().zip(&before) {
            assert_eq!(b == a, b.kind == BeamKind::Sonar, "{b:?} {a:?}");
        }
    }

    #[test]
    fn the_time_increment_is_read_from_the_laser_and_kept_only_when_plausible() {
        let mut l = LaserScan {
            count: 10,
            time_increment: 1e-4,
            ..Default::default()
        };
        let mut r = RangeScan::default();
        r.fill_from_laser(&l, Pose2::default());
        assert!((r.time_increment_s - 1e-4).abs() < 1e-9);
        for bad in [f32::NAN, -1e-4, 0.1] {
            l.time_increment = bad;
            r.fill_from_laser(&l, Pose2::default());
            assert_eq!(r.time_increment_s, 0.0, "{bad}");
        }
    }
}
