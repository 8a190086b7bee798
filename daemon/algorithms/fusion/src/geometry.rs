//! Sonar geometry in the laser frame, sonar sections τ, and Algorithm 1
//! (sonar readings painted into a laser-scan-shaped array).
//!
//! Each transducer pose comes from the robot profile (base frame) and is
//! moved into the laser frame once. A reading `r` means "an echo somewhere on
//! the arc of radius `r` around the transducer, within its cone". Algorithm 1
//! of SmokeNav (Santos et al. 2015) paints ±cone/2 around the bearing of the axis point at
//! that point's distance; here every beam of the laser (at its own angular
//! resolution) is intersected with the true arc, which is the same thing when
//! the sonar sits at the laser origin and stays right when it does not (a
//! P3-DX side sonar is 16 cm from the laser).
//!
//! The section τ of a sonar is the set of beams whose ray meets its cone arc
//! at the section range (by default the 2.5 m sonar cap); a beam claimed by
//! two cones goes to the one whose centre bearing is nearer.

use smokenav_platform_config::{LaserSection, MountPose, SonarSection, Transducer};
use smokenav_shared_types::{
    LaserScan, MAX_BEAMS, MAX_SONARS, SonarReading, SonarRing, SonarStatus,
};
use std::f64::consts::{PI, TAU};

/// Beam owner value of a beam outside every section.
pub const NO_SECTION: u8 = u8::MAX;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GeometryError {
    #[error("sonar index {index} is outside 0..{max}")]
    IndexTooLarge { index: u8, max: usize },
    #[error("sonar cone must be within (0, 180) degrees, got {0}")]
    BadCone(f64),
    #[error("{what} must be a positive finite number, got {value}")]
    BadRange { what: &'static str, value: f64 },
}

/// One transducer in the laser frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SonarPose {
    pub index: u8,
    /// Position, m.
    pub x: f64,
    pub y: f64,
    /// Axis direction, rad.
    pub yaw: f64,
}

/// The sonar ring as the laser sees it.
#[derive(Debug, Clone)]
pub struct SonarGeometry {
    poses: [Option<SonarPose>; MAX_SONARS],
    half_cone: f64,
    cos_half: f64,
    cap_m: f64,
    min_range_m: f64,
    section_range_m: f64,
}

impl SonarGeometry {
    /// `mount` is the laser's pose in the base frame; transducers are in the base frame.
    pub fn new(
        mount: &MountPose,
        transducers: &[Transducer],
        cone_deg: f64,
        cap_m: f64,
        min_range_m: f64,
        section_range_m: f64,
    ) -> Result<Self, GeometryError> {
        if !(cone_deg > 0.0 && cone_deg < 180.0) {
            return Err(GeometryError::BadCone(cone_deg));
        }
        for (what, value) in [("sonar cap", cap_m), ("section range", section_range_m)] {
            if !(value.is_finite() && value > 0.0) {
                return Err(GeometryError::BadRange { what, value });
            }
        }
        let (s, c) = mount.yaw_rad().sin_cos();
        let mut poses = [None; MAX_SONARS];
        for t in transducers {
            let slot = poses
                .get_mut(t.index as usize)
                .ok_or(GeometryError::IndexTooLarge {
                    index: t.index,
                    max: MAX_SONARS,
                })?;
            // base → laser: rotate the offset by −yaw of the laser.
            let (dx, dy) = (t.x - mount.x, t.y - mount.y);
            *slot = Some(SonarPose {
                index: t.index,
                x: c * dx + s * dy,
                y: -s * dx + c * dy,
                yaw: wrap(t.yaw_deg.to_radians() - mount.yaw_rad()),
            });
        }
        let half_cone = cone_deg.to_radians() / 2.0;
        Ok(Self {
            poses,
            half_cone,
            cos_half: half_cone.cos(),
            cap_m,
            min_range_m: min_range_m.max(0.0),
            section_range_m,
        })
    }

    /// From the robot profile's `[laser]`, `[sonar]` and `[fusion]` sections.
    pub fn from_config(
        laser: &LaserSection,
        sonar: &SonarSection,
        fusion: &smokenav_platform_config::FusionSection,
    ) -> Result<Self, GeometryError> {
        Self::new(
            &laser.mount,
            &sonar.transducers,
            sonar.cone_deg,
            fusion.sonar_cap_m,
            sonar.min_range_m,
            fusion.section_range(),
        )
    }

    pub fn pose(&self, index: u8) -> Option<&SonarPose> {
        self.poses.get(index as usize).and_then(Option::as_ref)
    }

    pub fn poses(&self) -> impl Iterator<Item = &SonarPose> {
        self.poses.iter().flatten()
    }

    pub fn cap_m(&self) -> f64 {
        self.cap_m
    }

    /// What a reading says, after the cap: an echo, free space, or nothing.
    pub fn classify(&self, reading: Option<&SonarReading>, ring_max_range: f32) -> SonarEcho {
        let Some(r) = reading else {
            return SonarEcho::Missing;
        };
        match r.status() {
            SonarStatus::Invalid => SonarEcho::Missing,
            SonarStatus::Saturated => SonarEcho::Saturated,
            SonarStatus::Valid => {
                let range = f64::from(r.range);
                if !range.is_finite() || range < self.min_range_m {
                    SonarEcho::Missing
                } else if range > self.cap_m || (ring_max_range > 0.0 && r.range >= ring_max_range)
                {
                    SonarEcho::Saturated
                } else {
                    SonarEcho::Echo(range)
                }
            }
        }
    }

    /// Calls `hit(beam, distance)` for each beam of `shape` whose ray meets
    /// the cone arc of radius `r` of `pose`, nearest crossing first.
    pub fn for_each_arc_beam(
        &self,
        shape: &ScanShape,
        pose: &SonarPose,
        r: f64,
        mut hit: impl FnMut(usize, f64),
    ) {
        if !(r.is_finite() && r > 0.0) {
            return;
        }
        // Bearing extent of the arc seen from the laser, sampled.
        const SAMPLES: usize = 8;
        let mid = arc_point(pose, 0.0, r);
        let mid_bearing = mid.1.atan2(mid.0);
        let (mut lo, mut hi) = (0.0f64, 0.0f64);
        for k in 0..=SAMPLES {
            let off = self.half_cone * (2.0 * k as f64 / SAMPLES as f64 - 1.0);
            let p = arc_point(pose, off, r);
            let rel = wrap(p.1.atan2(p.0) - mid_bearing);
            lo = lo.min(rel);
            hi = hi.max(rel);
        }
        let margin = 2.0 * shape.inc.abs() + self.half_cone / SAMPLES as f64;
        // The laser close to the arc's circle sees the arc over a wide, fast-changing
        // bearing range that 9 samples may miss: test every beam then.
        let near_origin = (pose.x.hypot(pose.y) - r).abs() < 2.0 * r * self.half_cone.sin() + 1e-6;
        if near_origin || hi - lo + 2.0 * margin >= PI {
            for i in 0..shape.count {
                if let Some(t) = ray_arc(pose, self.cos_half, shape.angle(i), r) {
                    hit(i, t);
                }
            }
            return;
        }
        for shift in [-TAU, 0.0, TAU] {
            let a = mid_bearing + lo - margin + shift;
            let b = mid_bearing + hi + margin + shift;
            for i in shape.beams_between(a, b) {
                if let Some(t) = ray_arc(pose, self.cos_half, shape.angle(i), r) {
                    hit(i, t);
                }
            }
        }
    }

    /// Algorithm 1: paints every usable reading of `ring` into `ranges`
    /// (one entry per beam of `shape`, `INFINITY` = no sonar return), keeping
    /// the nearer range where cones overlap. Returns the readings painted.
    pub fn paint_ring(
        &self,
        ring: &SonarRing,
        shape: &ScanShape,
        range_min: f64,
        ranges: &mut [f32],
    ) -> usize {
        let n = shape.count.min(ranges.len());
        ranges[..n].fill(f32::INFINITY);
        let mut painted = 0;
        for reading in ring.readings() {
            let (Some(pose), SonarEcho::Echo(r)) = (
                self.pose(reading.index),
                self.classify(Some(reading), ring.max_range),
            ) else {
                continue;
            };
            painted += 1;
            self.for_each_arc_beam(shape, pose, r, |i, t| {
                if i < n && t >= range_min {
                    let t = t as f32;
                    if t < ranges[i] {
                        ranges[i] = t;
                    }
                }
            });
        }
        painted
    }
}

/// What one sonar says about its section.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SonarEcho {
    /// An echo at this range (m, within the cap).
    Echo(f64),
    /// No echo within the cap: free space or a specular miss; never an obstacle.
    Saturated,
    /// No reading this cycle, or an unusable one.
    Missing,
}

impl SonarEcho {
    pub fn range(self) -> Option<f64> {
        match self {
            SonarEcho::Echo(r) => Some(r),
            _ => None,
        }
    }
}

fn arc_point(pose: &SonarPose, off: f64, r: f64) -> (f64, f64) {
    let (s, c) = (pose.yaw + off).sin_cos();
    (pose.x + r * c, pose.y + r * s)
}

/// Angle wrapped into (−π, π].
pub fn wrap(a: f64) -> f64 {
    let w = a.rem_euclid(TAU);
    if w > PI { w - TAU } else { w }
}

/// Distance along the beam at `theta` from the laser origin to the cone arc of
/// radius `r` around `pose`, if the beam meets it.
fn ray_arc(pose: &SonarPose, cos_half: f64, theta: f64, r: f64) -> Option<f64> {
    let (dy, dx) = theta.sin_cos();
    let b = dx * pose.x + dy * pose.y;
    let c2 = pose.x * pose.x + pose.y * pose.y;
    let disc = b * b - (c2 - r * r);
    if disc < 0.0 {
        return None;
    }
    let sq = disc.sqrt();
    let (uy, ux) = pose.yaw.sin_cos();
    [b - sq, b + sq].into_iter().find(|&t| {
        t > 1e-9 && {
            let (vx, vy) = (t * dx - pose.x, t * dy - pose.y);
            vx * ux + vy * uy >= r * cos_half - 1e-9
        }
    })
}

/// The angular layout of a scan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanShape {
    pub angle_min: f64,
    pub inc: f64,
    pub count: usize,
}

impl ScanShape {
    /// The layout of `scan`, or `None` if it is unusable (no beams, increment
    /// zero, not finite or above 1 rad: a scan from a broken or hostile peer).
    pub fn of(scan: &LaserScan) -> Option<Self> {
        Self::new(
            f64::from(scan.angle_min),
            f64::from(scan.angle_increment),
            scan.len(),
        )
    }

    pub fn new(angle_min: f64, inc: f64, count: usize) -> Option<Self> {
        let ok = count > 0
            && count <= MAX_BEAMS
            && angle_min.is_finite()
            && inc.is_finite()
            && inc.abs() > 1e-6
            && inc.abs() <= 1.0;
        ok.then_some(Self {
            angle_min,
            inc,
            count,
        })
    }

    pub fn angle(&self, i: usize) -> f64 {
        self.angle_min + i as f64 * self.inc
    }

    /// Beams whose angle lies within `[a, b]`.
    pub fn beams_between(&self, a: f64, b: f64) -> std::ops::Range<usize> {
        let (ia, ib) = (
            (a - self.angle_min) / self.inc,
            (b - self.angle_min) / self.inc,
        );
        let (lo, hi) = if ia <= ib { (ia, ib) } else { (ib, ia) };
        let lo = lo.ceil().max(0.0);
        let hi = (hi.floor() + 1.0).min(self.count as f64);
        if lo.partial_cmp(&hi) != Some(std::cmp::Ordering::Less) {
            return 0..0;
        }
        lo as usize..hi as usize
    }
}

/// One sonar section τ: a contiguous run of beams.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Section {
    pub sonar_index: u8,
    pub first: usize,
    pub end: usize,
}

/// The sections of one scan layout, in beam order, and which section each beam is in.
#[derive(Debug, Clone)]
pub struct Sections {
    shape: Option<ScanShape>,
    count: usize,
    items: [Section; MAX_SONARS],
    owner: Box<[u8; MAX_BEAMS]>,
}

impl Default for Sections {
    fn default() -> Self {
        Self {
            shape: None,
            count: 0,
            items: [Section::default(); MAX_SONARS],
            owner: Box::new([NO_SECTION; MAX_BEAMS]),
        }
    }
}

impl Sections {
    /// Recomputes the sections if `shape` differs from the last one (no allocation).
    pub fn update(&mut self, geometry: &SonarGeometry, shape: &ScanShape) {
        if self.shape.as_ref() == Some(shape) {
            return;
        }
        self.shape = Some(*shape);
        let n = shape.count;
        // Pass 1: owner = sonar index (nearest centre bearing wins overlaps).
        self.owner.fill(NO_SECTION);
        let mut centre = [0.0f64; MAX_SONARS];
        for pose in geometry.poses() {
            let p = arc_point(pose, 0.0, geometry.section_range_m);
            centre[pose.index as usize] = p.1.atan2(p.0);
        }
        for pose in geometry.poses() {
            let k = pose.index as usize;
            geometry.for_each_arc_beam(shape, pose, geometry.section_range_m, |i, _| {
                if i >= n {
                    return;
                }
                let a = shape.angle(i);
                let cur = self.owner[i];
                let take = cur == NO_SECTION
                    || wrap(a - centre[k]).abs() < wrap(a - centre[cur as usize]).abs();
                if take {
                    self.owner[i] = pose.index;
                }
            });
        }
        // Pass 2: sections in beam order; owner = position in that order.
        self.count = 0;
        let mut i = 0;
        while i < n {
            let idx = self.owner[i];
            if idx == NO_SECTION {
                i += 1;
                continue;
            }
            let first = i;
            while i < n && self.owner[i] == idx {
                i += 1;
            }
            // A cone split by a neighbour's (odd geometry) keeps its first run only.
            let seen = self.items[..self.count]
                .iter()
                .any(|s| s.sonar_index == idx);
            if seen || self.count == MAX_SONARS {
                self.owner[first..i].fill(NO_SECTION);
                continue;
            }
            self.items[self.count] = Section {
                sonar_index: idx,
                first,
                end: i,
            };
            self.count += 1;
        }
        for (k, s) in self.items[..self.count].iter().enumerate() {
            self.owner[s.first..s.end].fill(k as u8);
        }
    }

    pub fn as_slice(&self) -> &[Section] {
        &self.items[..self.count]
    }

    /// Position (in [`Self::as_slice`]) of the section beam `i` belongs to.
    pub fn owner(&self, i: usize) -> Option<usize> {
        match self.owner.get(i) {
            Some(&o) if o != NO_SECTION => Some(o as usize),
            _ => None,
        }
    }

    /// The sections bordering the uncovered run `[first, end)`: the one ending
    /// at `first` and the one starting at `end`.
    pub fn neighbours(&self, first: usize, end: usize) -> (Option<usize>, Option<usize>) {
        let left = first.checked_sub(1).and_then(|i| self.owner(i));
        let right = self.owner(end);
        (left, right)
    }

    /// The maximal runs of the first `count` beams that no section covers.
    pub fn gaps(&self, count: usize) -> impl Iterator<Item = Gap> + '_ {
        let mut i = 0;
        std::iter::from_fn(move || {
            while i < count && self.owner(i).is_some() {
                i += 1;
            }
            if i >= count {
                return None;
            }
            let first = i;
            while i < count && self.owner(i).is_none() {
                i += 1;
            }
            let (left, right) = self.neighbours(first, i);
            Some(Gap {
                first,
                end: i,
                left,
                right,
            })
        })
    }
}

/// A run of beams `[first, end)` between sections, with the sections (their
/// positions in [`Sections::as_slice`]) on either side, if any.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Gap {
    pub first: usize,
    pub end: usize,
    pub left: Option<usize>,
    pub right: Option<usize>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(index: u8, x: f64, y: f64, yaw_deg: f64) -> Transducer {
        Transducer {
            index,
            x,
            y,
            yaw_deg,
        }
    }

    fn at_laser(cone: f64) -> SonarGeometry {
        // One sonar at the laser origin, facing forward.
        SonarGeometry::new(
            &MountPose::default(),
            &[t(0, 0.0, 0.0, 0.0)],
            cone,
            2.5,
            0.1,
            2.5,
        )
        .unwrap()
    }

    /// 1° beams from −90° to +90°.
    fn degree_scan() -> ScanShape {
        ScanShape::new(-90f64.to_radians(), 1f64.to_radians(), 181).unwrap()
    }

    fn ring(readings: &[(u8, f32, SonarStatus)]) -> SonarRing {
        let mut r = SonarRing {
            max_range: 5.0,
            ..Default::default()
        };
        for &(i, range, st) in readings {
            r.push(SonarReading::new(i, range, st));
        }
        r
    }

    #[test]
    fn sonar_at_laser_origin_paints_plus_minus_half_cone_at_its_range() {
        // Algorithm 1 with the sonar at the laser: a 20° cone, 1.5 m echo →
        // beams −10°..+10° (21 beams at 1°) all at 1.5 m, nothing else.
        let g = at_laser(20.0);
        let shape = degree_scan();
        let mut ranges = [0.0f32; 181];
        let n = g.paint_ring(
            &ring(&[(0, 1.5, SonarStatus::Valid)]),
            &shape,
            0.0,
            &mut ranges,
        );
        assert_eq!(n, 1);
        let painted: Vec<usize> = (0..181).filter(|&i| ranges[i].is_finite()).collect();
        assert_eq!(painted, (80..=100).collect::<Vec<_>>());
        assert!(painted.iter().all(|&i| (ranges[i] - 1.5).abs() < 1e-6));
    }

    #[test]
    fn reading_beyond_the_cap_is_saturated_and_not_painted() {
        // The paper limited sonar range to 2.5 m.
        let g = at_laser(20.0);
        let mut ranges = [0.0f32; 181];
        let n = g.paint_ring(
            &ring(&[(0, 2.6, SonarStatus::Valid)]),
            &degree_scan(),
            0.0,
            &mut ranges,
        );
        assert_eq!(n, 0);
        assert!(ranges.iter().all(|r| r.is_infinite()));
        let r = SonarReading::new(0, 2.6, SonarStatus::Valid);
        assert_eq!(g.classify(Some(&r), 5.0), SonarEcho::Saturated);
        let r = SonarReading::new(0, 2.4, SonarStatus::Valid);
        assert_eq!(
            g.classify(Some(&r), 5.0),
            SonarEcho::Echo(f64::from(2.4f32))
        );
        assert_eq!(g.classify(None, 5.0), SonarEcho::Missing);
    }

    #[test]
    fn offset_sonar_is_painted_on_its_true_arc() {
        // Sonar 0.5 m left of the laser, facing forward, echo at 1 m: the arc
        // centre is at (1.0, 0.5) in the laser frame → bearing 26.6°, distance 1.118 m.
        let g = SonarGeometry::new(
            &MountPose::default(),
            &[t(0, 0.0, 0.5, 0.0)],
            10.0,
            2.5,
            0.1,
            2.5,
        )
        .unwrap();
        let shape = degree_scan();
        let mut ranges = [0.0f32; 181];
        g.paint_ring(
            &ring(&[(0, 1.0, SonarStatus::Valid)]),
            &shape,
            0.0,
            &mut ranges,
        );
        let b27 = 90 + 27;
        assert!((ranges[b27] - 1.118).abs() < 0.02, "{}", ranges[b27]);
        // Every painted point lies on the arc: |q − sonar| = 1 m.
        for (i, &r) in ranges.iter().enumerate() {
            if r.is_finite() {
                let a = shape.angle(i);
                let (x, y) = (f64::from(r) * a.cos(), f64::from(r) * a.sin());
                assert!(((x).hypot(y - 0.5) - 1.0).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn laser_mount_moves_sonars_into_the_laser_frame() {
        // P3-DX sonar 3 at (0.166, 0.027, 10°), laser at (0.16, 0, 0°).
        let mount = MountPose {
            x: 0.16,
            y: 0.0,
            yaw_deg: 0.0,
        };
        let g =
            SonarGeometry::new(&mount, &[t(3, 0.166, 0.027, 10.0)], 15.0, 2.5, 0.1, 2.5).unwrap();
        let p = g.pose(3).unwrap();
        assert!((p.x - 0.006).abs() < 1e-9 && (p.y - 0.027).abs() < 1e-9);
        assert!((p.yaw - 10f64.to_radians()).abs() < 1e-12);
        // A laser turned 90° left sees the same sonar to its right.
        let mount = MountPose {
            x: 0.0,
            y: 0.0,
            yaw_deg: 90.0,
        };
        let g = SonarGeometry::new(&mount, &[t(0, 1.0, 0.0, 0.0)], 15.0, 2.5, 0.1, 2.5).unwrap();
        let p = g.pose(0).unwrap();
        assert!(p.x.abs() < 1e-9 && (p.y + 1.0).abs() < 1e-9);
        assert!((p.yaw + 90f64.to_radians()).abs() < 1e-12);
    }

    #[test]
    fn sections_follow_the_cones_and_leave_gaps_between_them() {
        // Two sonars at the origin, ±30°, 20° cones → beams −40..−20 and 20..40.
        let g = SonarGeometry::new(
            &MountPose::default(),
            &[t(0, 0.0, 0.0, 30.0), t(1, 0.0, 0.0, -30.0)],
            20.0,
            2.5,
            0.1,
            2.5,
        )
        .unwrap();
        let mut s = Sections::default();
        s.update(&g, &degree_scan());
        let got: Vec<(u8, usize, usize)> = s
            .as_slice()
            .iter()
            .map(|x| (x.sonar_index, x.first, x.end))
            .collect();
        assert_eq!(got, vec![(1, 50, 71), (0, 110, 131)]);
        assert_eq!(s.owner(60), Some(0));
        assert_eq!(s.owner(90), None);
        assert_eq!(s.neighbours(71, 110), (Some(0), Some(1)));
        assert_eq!(s.neighbours(0, 50), (None, Some(0)));
        let gaps: Vec<Gap> = s.gaps(181).collect();
        let gap = |first, end, left, right| Gap {
            first,
            end,
            left,
            right,
        };
        assert_eq!(
            gaps,
            vec![
                gap(0, 50, None, Some(0)),
                gap(71, 110, Some(0), Some(1)),
                gap(131, 181, Some(1), None),
            ]
        );
        assert_eq!(s.gaps(60).count(), 1, "a scan ending inside a section");
    }

    #[test]
    fn overlapping_cones_split_at_the_nearer_centre() {
        // Cones of 40° at ±10° overlap on −10..+10: split at 0°.
        let g = SonarGeometry::new(
            &MountPose::default(),
            &[t(0, 0.0, 0.0, 10.0), t(1, 0.0, 0.0, -10.0)],
            40.0,
            2.5,
            0.1,
            2.5,
        )
        .unwrap();
        let mut s = Sections::default();
        s.update(&g, &degree_scan());
        let got: Vec<(u8, usize, usize)> = s
            .as_slice()
            .iter()
            .map(|x| (x.sonar_index, x.first, x.end))
            .collect();
        // −30..−1 → sonar 1, 0 goes to the first claimant (equal distance), +1..+30 → sonar 0.
        assert_eq!(got[0].0, 1);
        assert_eq!(got[1].0, 0);
        assert_eq!(got[0].1, 60);
        assert_eq!(got[1].2, 121);
        assert_eq!(got[0].2, got[1].1);
    }

    #[test]
    fn cone_outside_the_field_of_view_has_no_section() {
        let g = SonarGeometry::new(
            &MountPose::default(),
            &[t(0, 0.0, 0.0, 180.0)],
            20.0,
            2.5,
            0.1,
            2.5,
        )
        .unwrap();
        let mut s = Sections::default();
        s.update(&g, &degree_scan());
        assert!(s.as_slice().is_empty());
    }

    #[test]
    fn full_circle_scan_wraps_the_rear_cone() {
        // A 360° laser (−180°..179°) sees a rear sonar across the ±180° seam.
        let g = SonarGeometry::new(
            &MountPose::default(),
            &[t(0, 0.0, 0.0, 180.0)],
            20.0,
            2.5,
            0.1,
            2.5,
        )
        .unwrap();
        let shape = ScanShape::new(-PI, 1f64.to_radians(), 360).unwrap();
        let mut ranges = [0.0f32; 360];
        g.paint_ring(
            &ring(&[(0, 1.0, SonarStatus::Valid)]),
            &shape,
            0.0,
            &mut ranges,
        );
        let painted: Vec<usize> = (0..360).filter(|&i| ranges[i].is_finite()).collect();
        assert_eq!(
            painted,
            [(0..=10).collect::<Vec<_>>(), (350..360).collect()].concat()
        );
    }

    proptest::proptest! {
        #[test]
        fn windowed_arc_search_finds_exactly_the_beams_a_full_sweep_finds(
            x in -0.3f64..0.3, y in -0.3f64..0.3, yaw in -200f64..200.0,
            cone in 5f64..60.0, r in 0.05f64..3.0, full in proptest::bool::ANY,
        ) {
            let g = SonarGeometry::new(&MountPose::default(), &[t(0, x, y, yaw)], cone, 2.5, 0.0, 2.5).unwrap();
            let shape = if full {
                ScanShape::new(-PI, TAU / 1024.0, 1024).unwrap()
            } else {
                crate::testkit::urg_04lx_shape()
            };
            let pose = g.pose(0).unwrap();
            let mut got = Vec::new();
            g.for_each_arc_beam(&shape, pose, r, |i, d| got.push((i, d)));
            got.sort_by_key(|a| a.0);
            let want: Vec<(usize, f64)> = (0..shape.count)
                .filter_map(|i| ray_arc(pose, g.cos_half, shape.angle(i), r).map(|d| (i, d)))
                .collect();
            proptest::prop_assert_eq!(got, want);
        }
    }

    #[test]
    fn malformed_scan_layout_is_refused() {
        assert!(ScanShape::new(0.0, 0.0, 10).is_none());
        assert!(ScanShape::new(f64::NAN, 0.01, 10).is_none());
        assert!(ScanShape::new(0.0, 0.01, 0).is_none());
        assert!(ScanShape::new(0.0, 0.01, MAX_BEAMS + 1).is_none());
        let u = crate::testkit::urg_04lx_shape();
        assert!((u.angle(0) + 2.0862).abs() < 1e-3 && u.count == 682);
    }
}
