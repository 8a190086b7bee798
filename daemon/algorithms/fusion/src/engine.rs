//! One fusion cycle: a synchronised (laser, sonar, smoke) set in, a
//! [`FusedScan`] out, written into a caller-provided buffer without allocating.

use crate::geometry::{GeometryError, ScanShape, Section, Sections, SonarEcho, SonarGeometry};
use crate::v1::{self, LaserSectionStats, SmokeClassifier, SmokeState};
use crate::v2::{FuzzyModel, LaserTrust};
use smokenav_platform_config::RobotConfig;
use smokenav_platform_config::ScanLayout;
use smokenav_platform_config::fusion::{V1Params, V2Params};
use smokenav_shared_types::laser::{BEAM_BEYOND_MAX, BEAM_NO_RETURN};
use smokenav_shared_types::{
    BeamReading, FixedStr, FusedScan, FusionMethod, Header, LaserScan, MAX_BEAMS, MAX_SONARS,
    SectionDecision, SectionSource, SmokeReading, SonarReading, SonarRing, SyncState,
};
use std::f64::consts::TAU;

/// The smoke level the fuzzy model may use: a reading of a `ready` sensor
/// with a finite level; `None` means the smoke sensor is silent.
fn usable_smoke_level(smoke: Option<&SmokeReading>) -> Option<f64> {
    smoke
        .filter(|s| s.is_ready() && s.level.is_finite())
        .map(|s| f64::from(s.level))
}

/// Why a cycle produced nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum StepError {
    #[error("neither a laser scan nor a sonar ring to fuse")]
    NoInput,
    #[error("method laser-only needs a laser scan; only sonar arrived")]
    LaserRequired,
    #[error("sonar only, and no scan layout yet: neither `[laser] scan` nor a laser scan gave one")]
    NoLayout,
}

/// What one cycle decided, for health reporting.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepReport {
    pub sync_state: SyncState,
    pub smoke_state: SmokeState,
    /// Sections in the output, and how many of them used the sonar (alone or superimposed).
    pub sections: usize,
    pub sonar_sections: usize,
    /// ρL of v2 (1 for the laser alone, 0 without a laser).
    pub rho_laser: f32,
    /// The laser scan's layout was unusable (no beams, bad increment): passed through untouched.
    pub bad_layout: bool,
    /// v2 fused laser and sonar without a usable smoke reading and assumed
    /// smoke (the witness on in every section; see the `v2` module).
    pub smoke_silent: bool,
    /// Laser beams v2 dropped as specks of patchy smoke (`v2.speck_max_beams`).
    pub speck_beams: usize,
    /// Laser beams v2 kept in sections it gave to the sonar, which the
    /// sonar did not contradict (`v2.keep_uncontradicted_laser`).
    pub vouched_beams: usize,
}

/// The layout of the last laser scan, used to shape sonar-only output.
#[derive(Debug, Clone, Copy)]
struct Template {
    shape: ScanShape,
    range_min: f32,
    range_max: f32,
    time_increment: f32,
    scan_time: f32,
    frame_id: FixedStr<{ smokenav_shared_types::header::FRAME_ID_LEN }>,
}

impl Template {
    /// The layout the laser's configuration states (the robot profile's
    /// `[laser] scan`), computed as a driver computes it from the sensor's
    /// own parameters; `None` if it gives no usable layout.
    fn from_layout(l: &ScanLayout, frame_id: &str) -> Option<Self> {
        let inc = TAU / f64::from(l.steps_per_turn.max(1));
        let shape = ScanShape::new(
            (f64::from(l.first_step) - f64::from(l.front_step)) * inc,
            inc,
            l.last_step.checked_sub(l.first_step)? as usize + 1,
        )?;
        let scan_time = 60.0 / f64::from(l.rpm.max(1));
        Some(Self {
            shape,
            range_min: l.range_min_mm as f32 / 1000.0,
            range_max: l.range_max_mm as f32 / 1000.0,
            time_increment: (scan_time / f64::from(l.steps_per_turn.max(1))) as f32,
            scan_time: scan_time as f32,
            frame_id: FixedStr::from_str_truncate(frame_id),
        })
    }
}

/// The fusion core: configured once, then `step` per synchronised set.
#[derive(Debug, Clone)]
pub struct FusionEngine {
    method: FusionMethod,
    geometry: SonarGeometry,
    sections: Sections,
    v1: V1Params,
    fuzzy: FuzzyModel,
    classifier: SmokeClassifier,
    /// The layout sonar-only output takes: the last laser scan's, else the configured one.
    template: Option<Template>,
    by_index: [Option<SonarReading>; MAX_SONARS],
    ring_max_range: f32,
    paint: Box<[f32; MAX_BEAMS]>,
    decisions: [SectionSource; MAX_SONARS],
    /// v2: whether each section's own laser rule trusts its laser (ρL(τ) > ρT).
    section_laser_ok: [bool; MAX_SONARS],
    /// `paint` already holds the section's sonar echo arc (painted by the
    /// witness this cycle), so `apply_sections` need not paint it again.
    echo_painted: [bool; MAX_SONARS],
}

impl FusionEngine {
    pub fn new(method: FusionMethod, geometry: SonarGeometry, v1: V1Params, v2: V2Params) -> Self {
        Self {
            method,
            geometry,
            sections: Sections::default(),
            v1,
            fuzzy: FuzzyModel::new(v2),
            classifier: SmokeClassifier::default(),
            template: None,
            by_index: [None; MAX_SONARS],
            ring_max_range: 0.0,
            paint: Box::new([f32::INFINITY; MAX_BEAMS]),
            decisions: [SectionSource::Laser; MAX_SONARS],
            section_laser_ok: [true; MAX_SONARS],
            echo_painted: [false; MAX_SONARS],
        }
    }

    /// From a robot profile; `method` overrides `[fusion] method`.
    pub fn from_config(
        cfg: &RobotConfig,
        method: Option<FusionMethod>,
    ) -> Result<Self, GeometryError> {
        let geometry = SonarGeometry::from_config(&cfg.laser, &cfg.sonar, &cfg.fusion)?;
        let method = method.unwrap_or(cfg.fusion.method);
        let mut e = Self::new(
            method,
            geometry,
            cfg.fusion.v1.clone(),
            cfg.fusion.v2.clone(),
        );
        e.template = cfg
            .laser
            .scan
            .as_ref()
            .and_then(|l| Template::from_layout(l, &cfg.laser.frame_id));
        Ok(e)
    }

    pub fn method(&self) -> FusionMethod {
        self.method
    }

    pub fn geometry(&self) -> &SonarGeometry {
        &self.geometry
    }

    /// The sections of the latest scan layout.
    pub fn sections(&self) -> &Sections {
        &self.sections
    }

    pub fn smoke_state(&self) -> SmokeState {
        self.classifier.state()
    }

    pub fn smoke_rising(&self) -> bool {
        self.classifier.rising()
    }

    /// Tracks the smoke state from a reading that is not part of a fused set
    /// (laser-only runs), so health still shows it.
    pub fn observe_smoke(&mut self, reading: &SmokeReading) -> SmokeState {
        self.classifier.update(Some(reading), &self.v1)
    }

    /// Fuses one set into `out`. Any input may be absent (timed out):
    /// laser without sonar (or, except for v2, without smoke) gives the laser
    /// untouched ([`SyncState::LaserOnly`]); v2 with laser and sonar but no
    /// usable smoke reading assumes smoke ([`SyncState::NoSmoke`]); sonar without laser gives Algorithm 1's
    /// scan in the last laser layout ([`SyncState::SonarOnly`]).
    pub fn step(
        &mut self,
        laser: Option<&LaserScan>,
        sonar: Option<&SonarRing>,
        smoke: Option<&SmokeReading>,
        out: &mut FusedScan,
    ) -> Result<StepReport, StepError> {
        let smoke_state = if self.method == FusionMethod::LaserOnly && smoke.is_none() {
            // Laser-only runs without the synchroniser; smoke comes via `observe_smoke`.
            self.classifier.state()
        } else {
            self.classifier.update(smoke, &self.v1)
        };
        self.index_sonar(sonar);
        out.method = self.method as u8;
        out.smoke_level = smoke.map_or(0.0, |s| if s.level.is_finite() { s.level } else { 0.0 });
        out.sonar_stamp_ns = sonar.map_or(0, |s| s.header.stamp_ns);
        out.smoke_stamp_ns = smoke.map_or(0, |s| s.header.stamp_ns);
        match (laser, sonar) {
            (Some(l), _) => Ok(self.fuse_laser(l, sonar.is_some(), smoke, smoke_state, out)),
            (None, Some(s)) if self.method != FusionMethod::LaserOnly => {
                let t = self.template.ok_or(StepError::NoLayout)?;
                Ok(self.sonar_only(&t, s, smoke_state, out))
            }
            (None, Some(_)) => Err(StepError::LaserRequired),
            (None, None) => Err(StepError::NoInput),
        }
    }

    fn index_sonar(&mut self, sonar: Option<&SonarRing>) {
        self.by_index = [None; MAX_SONARS];
        self.ring_max_range = 0.0;
        if let Some(ring) = sonar {
            self.ring_max_range = ring.max_range;
            for r in ring.readings() {
                if let Some(slot) = self.by_index.get_mut(r.index as usize) {
                    *slot = Some(*r);
                }
            }
        }
    }

    fn echo(&self, sonar_index: u8) -> (SonarEcho, f32) {
        let r = self
            .by_index
            .get(sonar_index as usize)
            .and_then(Option::as_ref);
        let raw = r.map_or(0.0, |r| if r.range.is_finite() { r.range } else { 0.0 });
        (self.geometry.classify(r, self.ring_max_range), raw)
    }

    fn fuse_laser(
        &mut self,
        l: &LaserScan,
        with_sonar: bool,
        smoke: Option<&SmokeReading>,
        smoke_state: SmokeState,
        out: &mut FusedScan,
    ) -> StepReport {
        out.scan = *l;
        out.beam_source.fill(SectionSource::Laser as u8);
        let complete = with_sonar && smoke.is_some();
        // v2 does not fall back to the laser alone when the smoke sensor is
        // silent: it fuses with the sonar and assumes smoke.
        let smoke_silent =
            self.method == FusionMethod::V2 && with_sonar && usable_smoke_level(smoke).is_none();
        // The sync state says what was paired: a reading of a sensor that is not
        // ready still completes the set (the report flags `smoke_silent`).
        out.sync_state = if smoke_silent && smoke.is_none() {
            SyncState::NoSmoke
        } else if complete {
            SyncState::Complete
        } else {
            SyncState::LaserOnly
        } as u8;
        let spread = spread(l);
        out.laser_spread = spread as f32;
        out.section_count = 0;
        let mut report = StepReport {
            sync_state: out.sync_state(),
            smoke_state,
            sections: 0,
            sonar_sections: 0,
            rho_laser: 1.0,
            bad_layout: false,
            smoke_silent,
            speck_beams: 0,
            vouched_beams: 0,
        };
        let Some(shape) = ScanShape::of(l) else {
            report.bad_layout = true;
            return report;
        };
        self.template = Some(Template {
            shape,
            range_min: l.range_min,
            range_max: l.range_max,
            time_increment: l.time_increment,
            scan_time: l.scan_time,
            frame_id: l.header.frame_id,
        });
        self.sections.update(&self.geometry, &shape);
        self.echo_painted = [false; MAX_SONARS];
        let n_sections = self.sections.as_slice().len();
        report.sections = n_sections;
        let fuse = (complete || smoke_silent) && self.method != FusionMethod::LaserOnly;
        if !fuse {
            for k in 0..n_sections {
                self.decisions[k] = SectionSource::Laser;
                self.record_section(k, 0.0, 1.0, out);
            }
            out.section_count = n_sections as u32;
            return report;
        }
        let mut specks = false;
        match self.method {
            FusionMethod::V1 => self.decide_v1(l, smoke_state, out),
            _ => {
                let (rho, measured_smoke) =
                    self.decide_v2(l, &shape, smoke, smoke_silent, spread, out);
                report.rho_laser = rho as f32;
                specks = measured_smoke;
            }
        }
        out.section_count = n_sections as u32;
        // v2's witness also vouches: in a section given to its sonar, a laser
        // beam the sonar does not contradict reached the sonar's nearest
        // surface or passed it, so smoke did not catch it there.
        let keep_margin = (self.method == FusionMethod::V2
            && self.fuzzy.params().keep_uncontradicted_laser)
            .then(|| self.fuzzy.params().contradiction_margin_m as f32);
        report.vouched_beams = self.apply_sections(l, &shape, keep_margin, out);
        // Patchy smoke also catches lone beams the sonar cannot judge (thin
        // smoke below the witness's threshold, beams between cones). Only
        // where smoke is measured: a silent sensor (warming up) is not
        // evidence enough to drop thin objects. Last, so that only beams
        // still the laser's are dropped and counted.
        if specks {
            report.speck_beams = self.blank_specks(l, out);
        }
        report.sonar_sections = self.decisions[..n_sections]
            .iter()
            .filter(|d| matches!(d, SectionSource::Sonar | SectionSource::Both))
            .count();
        report
    }

    fn decide_v1(&mut self, l: &LaserScan, state: SmokeState, out: &mut FusedScan) {
        let n = self.sections.as_slice().len();
        for k in 0..n {
            let s = self.sections.as_slice()[k];
            let stats = if matches!(state, SmokeState::Light) {
                v1::section_stats(l, s.first, s.end, &self.v1)
            } else {
                LaserSectionStats::default()
            };
            let (echo, _) = self.echo(s.sonar_index);
            let d = v1::decide_section(state, &stats, echo, &self.v1);
            self.decisions[k] = d;
            let (rs, rl) = match d {
                SectionSource::Laser => (0.0, 1.0),
                SectionSource::Sonar => (1.0, 0.0),
                SectionSource::Both => (1.0, 1.0),
                SectionSource::Neither => (0.0, 0.0),
            };
            self.record_section(k, rs, rl, out);
        }
        // Uncovered runs: accepted only between clean sections.
        for g in self.sections.gaps(l.len()) {
            let gap = v1::decide_gap(
                state,
                g.left.map(|k| self.decisions[k]),
                g.right.map(|k| self.decisions[k]),
            );
            if gap == SectionSource::Neither {
                blank(out, g.first, g.end);
            }
        }
    }

    fn decide_v2(
        &mut self,
        l: &LaserScan,
        shape: &ScanShape,
        smoke: Option<&SmokeReading>,
        smoke_silent: bool,
        spread: f64,
        out: &mut FusedScan,
    ) -> (f64, bool) {
        let level = usable_smoke_level(smoke);
        let trust: LaserTrust = self.fuzzy.laser_trust(level, spread);
        // The smoke the witness assumes: the worst when the sensor is silent.
        let mu_smoke = if smoke_silent {
            1.0
        } else {
            trust.mu_alcoholized
        };
        let n = self.sections.as_slice().len();
        for k in 0..n {
            let s = self.sections.as_slice()[k];
            let (echo, raw) = self.echo(s.sonar_index);
            // The witness is only consulted when there is smoke to explain a contradiction.
            let share = if mu_smoke > 0.0 {
                self.contradicted_share(l, shape, k, echo)
            } else {
                None
            };
            let section = self.fuzzy.section_laser_trust_in(&trust, share, mu_smoke);
            self.section_laser_ok[k] = self.fuzzy.decide_gap(&section) == SectionSource::Laser;
            let rho_s = self.fuzzy.sonar_trust(&section, echo, f64::from(raw));
            let d = self.fuzzy.decide(rho_s, section.rho);
            self.decisions[k] = d;
            self.record_section(k, rho_s as f32, section.rho as f32, out);
            // A kept laser section in smoky air still loses the single beams
            // its sonar contradicts (patchy smoke catches every few beams).
            if d == SectionSource::Laser && share.is_some() && mu_smoke >= 0.5 {
                self.blank_contradicted(l, &s, out);
            }
        }
        let scan_gap = self.fuzzy.decide_gap(&trust);
        for g in self.sections.gaps(out.scan.len()) {
            // A gap between sections whose laser the sonar contradicted is the same smoke.
            let neighbours_ok = [g.left, g.right]
                .into_iter()
                .flatten()
                .all(|k| self.section_laser_ok[k]);
            if scan_gap == SectionSource::Neither || !neighbours_ok {
                blank(out, g.first, g.end);
            }
        }
        (trust.rho, trust.mu_alcoholized > 0.0)
    }

    /// The share of section `k`'s laser ranges that lie nearer than the
    /// sonar's arc by more than the margin: the echo's arc or, when the sonar
    /// heard nothing within its cap, the cap's (beyond it a sonar misses weak
    /// and glancing echoes, so its silence there proves nothing). `None`
    /// without a sonar reading or without a beam both sensors cover.
    fn contradicted_share(
        &mut self,
        l: &LaserScan,
        shape: &ScanShape,
        k: usize,
        echo: SonarEcho,
    ) -> Option<f64> {
        let section = self.sections.as_slice()[k];
        let radius = match echo {
            SonarEcho::Echo(r) => r,
            SonarEcho::Saturated => self.geometry.cap_m(),
            SonarEcho::Missing => return None,
        };
        self.paint_arc(shape, &section, radius, f64::from(l.range_min));
        // apply_sections needs this very arc if the section goes to its sonar.
        self.echo_painted[k] = matches!(echo, SonarEcho::Echo(_));
        let end = section.end.min(l.len()).min(self.paint.len());
        let first = section.first.min(end);
        let margin = self.fuzzy.params().contradiction_margin_m;
        let (mut compared, mut nearer) = (0usize, 0usize);
        for i in first..end {
            let arc = f64::from(self.paint[i]);
            let Some(r) = l.beam(i).range().filter(|r| r.is_finite()) else {
                continue;
            };
            if !arc.is_finite() {
                continue;
            }
            compared += 1;
            if f64::from(r) < arc - margin {
                nearer += 1;
            }
        }
        (compared > 0).then(|| nearer as f64 / compared as f64)
    }

    /// Paints into `paint[section]` the distance along each beam to the arc of
    /// radius `radius` of the section's sonar (infinity where a beam misses
    /// it or meets it nearer than `range_min`).
    fn paint_arc(&mut self, shape: &ScanShape, section: &Section, radius: f64, range_min: f64) {
        let range_min = range_min.max(0.0);
        let (first, end) = (section.first, section.end.min(self.paint.len()));
        let first = first.min(end);
        self.paint[first..end].fill(f32::INFINITY);
        let Some(pose) = self.geometry.pose(section.sonar_index).copied() else {
            return;
        };
        let (geometry, paint) = (&self.geometry, &mut self.paint);
        geometry.for_each_arc_beam(shape, &pose, radius, |i, t| {
            if (first..end).contains(&i) && t >= range_min {
                paint[i] = paint[i].min(t as f32);
            }
        });
    }

    /// Blanks the section's laser beams nearer than the arc painted by the
    /// last [`Self::contradicted_share`] call for it, by more than the margin.
    fn blank_contradicted(&self, l: &LaserScan, section: &Section, out: &mut FusedScan) {
        let margin = self.fuzzy.params().contradiction_margin_m;
        let end = section.end.min(l.len()).min(self.paint.len());
        for i in section.first.min(end)..end {
            let arc = f64::from(self.paint[i]);
            if let Some(r) = l.beam(i).range().filter(|r| r.is_finite())
                && arc.is_finite()
                && f64::from(r) < arc - margin
            {
                blank(out, i, i + 1);
            }
        }
    }

    /// Blanks the specks of patchy smoke: runs of at most
    /// `v2.speck_max_beams` laser beams, each within the contradiction margin
    /// of the next, that lie nearer than the beams on both sides by more than
    /// the margin (a side without a range counts as farther; a run at the
    /// scan's edge has one side only and stays). Only beams the output still
    /// takes from the laser are blanked; returns how many.
    fn blank_specks(&self, l: &LaserScan, out: &mut FusedScan) -> usize {
        let p = self.fuzzy.params();
        let (margin, max_run) = (p.contradiction_margin_m as f32, p.speck_max_beams as usize);
        if max_run == 0 {
            return 0;
        }
        let mut blanked = 0;
        let n = l.len().min(out.scan.len());
        let range = |i: usize| l.beam(i).range().filter(|r| r.is_finite());
        let mut i = 0;
        while i < n {
            let Some(first) = range(i) else {
                i += 1;
                continue;
            };
            let (mut end, mut far, mut prev) = (i + 1, first, first);
            while end < n && end - i <= max_run {
                match range(end) {
                    Some(r) if (r - prev).abs() <= margin => {
                        far = far.max(r);
                        prev = r;
                        end += 1;
                    }
                    _ => break,
                }
            }
            let farther =
                |j: Option<usize>| j.is_some_and(|j| range(j).is_none_or(|r| r > far + margin));
            if end - i <= max_run && farther(i.checked_sub(1)) && farther((end < n).then_some(end))
            {
                for k in i..end {
                    if out.beam_source[k] == SectionSource::Laser as u8 {
                        blank(out, k, k + 1);
                        blanked += 1;
                    }
                }
            }
            i = end;
        }
        blanked
    }

    fn record_section(&self, k: usize, rho_sonar: f32, rho_laser: f32, out: &mut FusedScan) {
        let s = self.sections.as_slice()[k];
        let (_, raw) = self.echo(s.sonar_index);
        out.sections[k] = SectionDecision {
            first_beam: s.first as u16,
            end_beam: s.end as u16,
            sonar_index: s.sonar_index,
            source: self.decisions[k] as u8,
            _reserved: [0; 2],
            rho_sonar,
            rho_laser,
            sonar_range: raw,
        };
    }

    /// Writes the beams of every non-laser section. With `keep_margin`,
    /// a `Sonar` section keeps each laser beam that lies no nearer than the
    /// sonar's arc by more than the margin (not contradicted), and paints
    /// the arc only on the others. Returns how many beams it kept so.
    fn apply_sections(
        &mut self,
        l: &LaserScan,
        shape: &ScanShape,
        keep_margin: Option<f32>,
        out: &mut FusedScan,
    ) -> usize {
        let mut vouched = 0;
        let range_min = f64::from(l.range_min);
        for k in 0..self.sections.as_slice().len() {
            let d = self.decisions[k];
            let s = self.sections.as_slice()[k];
            match d {
                SectionSource::Laser => {}
                SectionSource::Neither => blank(out, s.first, s.end),
                SectionSource::Sonar | SectionSource::Both => {
                    if !self.echo_painted[k] {
                        match self.echo(s.sonar_index).0 {
                            SonarEcho::Echo(r) => self.paint_arc(shape, &s, r, range_min),
                            _ => self.paint[s.first..s.end].fill(f32::INFINITY),
                        }
                    }
                    for i in s.first..s.end {
                        let p = self.paint[i];
                        let laser_range = l.beam(i).range().filter(|r| r.is_finite());
                        if let (Some(m), SectionSource::Sonar, Some(lr)) =
                            (keep_margin, d, laser_range)
                            && p.is_finite()
                            && lr >= p - m
                        {
                            // Both: the laser's range, in a section smoke made the sonar's.
                            out.beam_source[i] = SectionSource::Both as u8;
                            vouched += 1;
                            continue;
                        }
                        let take_sonar = match d {
                            SectionSource::Sonar => true,
                            // Both: the nearer of the two wins.
                            _ => p.is_finite() && laser_range.is_none_or(|lr| p < lr),
                        };
                        if take_sonar {
                            let reading = if p.is_finite() {
                                BeamReading::Range(p)
                            } else {
                                BeamReading::BeyondMax
                            };
                            out.scan.set_beam(i, reading);
                            out.scan.intensities[i] = 0.0;
                            out.beam_source[i] = SectionSource::Sonar as u8;
                        }
                    }
                }
            }
        }
        vouched
    }

    /// Algorithm 1 alone: the laser is silent.
    fn sonar_only(
        &mut self,
        t: &Template,
        ring: &SonarRing,
        smoke_state: SmokeState,
        out: &mut FusedScan,
    ) -> StepReport {
        let n = t.shape.count;
        let scan = &mut out.scan;
        scan.header = Header {
            stamp_ns: ring.header.stamp_ns,
            seq: ring.header.seq,
            frame_id: t.frame_id,
        };
        scan.angle_min = t.shape.angle_min as f32;
        scan.angle_increment = t.shape.inc as f32;
        scan.time_increment = t.time_increment;
        scan.scan_time = t.scan_time;
        scan.range_min = t.range_min;
        scan.range_max = t.range_max;
        scan.count = n as u32;
        scan.has_intensities = 0;
        scan.intensities.fill(0.0);
        scan.ranges[n..].fill(0.0);
        scan.beam_error[n..].fill(BEAM_NO_RETURN);
        self.geometry.paint_ring(
            ring,
            &t.shape,
            f64::from(t.range_min).max(0.0),
            &mut scan.ranges[..n],
        );
        out.beam_source.fill(SectionSource::Neither as u8);
        for i in 0..n {
            if scan.ranges[i].is_finite() {
                scan.beam_error[i] = smokenav_shared_types::laser::BEAM_OK;
                out.beam_source[i] = SectionSource::Sonar as u8;
            } else {
                scan.beam_error[i] = BEAM_BEYOND_MAX;
            }
        }
        out.sync_state = SyncState::SonarOnly as u8;
        out.laser_spread = 0.0;
        self.sections.update(&self.geometry, &t.shape);
        let count = self.sections.as_slice().len();
        let mut used = 0;
        for k in 0..count {
            let s = self.sections.as_slice()[k];
            let d = match self.echo(s.sonar_index).0 {
                SonarEcho::Echo(_) => SectionSource::Sonar,
                _ => SectionSource::Neither,
            };
            used += usize::from(d == SectionSource::Sonar);
            self.decisions[k] = d;
            self.record_section(
                k,
                if d == SectionSource::Sonar { 1.0 } else { 0.0 },
                0.0,
                out,
            );
        }
        out.section_count = count as u32;
        StepReport {
            sync_state: SyncState::SonarOnly,
            smoke_state,
            sections: count,
            sonar_sections: used,
            rho_laser: 0.0,
            bad_layout: false,
            smoke_silent: false,
            speck_beams: 0,
            vouched_beams: 0,
        }
    }
}

/// Marks beams `[first, end)` beyond max range: SLAM sees no return there.
fn blank(out: &mut FusedScan, first: usize, end: usize) {
    let end = end.min(out.scan.len());
    for i in first..end {
        out.scan.set_beam(i, BeamReading::BeyondMax);
        out.scan.intensities[i] = 0.0;
        out.beam_source[i] = SectionSource::Neither as u8;
    }
}

/// Standard deviation of the scan's valid ranges, m (0 with fewer than 2).
pub fn spread(l: &LaserScan) -> f64 {
    let (mut n, mut sum, mut sq) = (0usize, 0.0f64, 0.0f64);
    for r in l.valid_ranges().filter(|r| r.is_finite()) {
        let r = f64::from(r);
        n += 1;
        sum += r;
        sq += r * r;
    }
    if n < 2 {
        return 0.0;
    }
    let mean = sum / n as f64;
    (sq / n as f64 - mean * mean).max(0.0).sqrt()
}

#[cfg(test)]
mod tests;
