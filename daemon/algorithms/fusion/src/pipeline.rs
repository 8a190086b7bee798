//! The synchroniser and the fusion engine wired together: what the fusion
//! process and `smokenav fuse` both run, so a replay does exactly what the robot did.

use crate::engine::{FusionEngine, StepReport};
use crate::geometry::GeometryError;
use crate::sync::{Matched, Sync3, SyncCounters, SyncSettings};
use smokenav_platform_config::RobotConfig;
use smokenav_platform_config::fusion::SyncParams;
use smokenav_shared_types::{FusedScan, FusionMethod, LaserScan, SmokeReading, SonarRing};

/// Topic positions in the synchroniser and its counters.
pub const LASER: usize = 0;
pub const SONAR: usize = 1;
pub const SMOKE: usize = 2;
pub const TOPIC_NAMES: [&str; 3] = ["laser", "sonar", "smoke"];

/// Outputs so far.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PipelineStats {
    /// Fused scans produced.
    pub outputs: u64,
    /// Synchronised sets that could not be fused (smoke alone, or sonar alone under laser-only).
    pub skipped: u64,
    /// Sections over all outputs, and those that used the sonar.
    pub sections: u64,
    pub sonar_sections: u64,
    /// Laser scans whose layout was unusable (passed through untouched).
    pub bad_layouts: u64,
    /// Laser beams v2 dropped as specks of patchy smoke.
    pub speck_beams: u64,
    /// Laser beams v2 kept, uncontradicted, in sections it gave to the sonar.
    pub vouched_beams: u64,
}

impl PipelineStats {
    /// The paper's "sonar usage": share of sections that used the sonar.
    pub fn sonar_usage(&self) -> f64 {
        if self.sections == 0 {
            0.0
        } else {
            self.sonar_sections as f64 / self.sections as f64
        }
    }
}

pub fn sync_settings(p: &SyncParams) -> SyncSettings<3> {
    let ns = |s: f64| (s.max(0.0) * 1e9).round() as u64;
    SyncSettings {
        queue_size: p.queue_size,
        max_interval_ns: ns(p.max_interval_s),
        age_penalty: p.age_penalty,
        lower_bound_ns: [
            ns(p.laser_min_period_s),
            ns(p.sonar_min_period_s),
            ns(p.smoke_min_period_s),
        ],
        timeout_ns: Some(ns(p.timeout_s)),
    }
}

/// Synchroniser + engine + output buffer.
#[derive(Debug)]
pub struct FusionPipeline {
    sync: Sync3<LaserScan, SonarRing, SmokeReading>,
    engine: FusionEngine,
    out: Box<FusedScan>,
    stats: PipelineStats,
    last: Option<StepReport>,
}

struct Parts<'p> {
    engine: &'p mut FusionEngine,
    out: &'p mut FusedScan,
    stats: &'p mut PipelineStats,
    last: &'p mut Option<StepReport>,
}

impl Parts<'_> {
    fn fuse(
        &mut self,
        laser: Option<&LaserScan>,
        sonar: Option<&SonarRing>,
        smoke: Option<&SmokeReading>,
        emit: &mut impl FnMut(&FusedScan, &StepReport),
    ) {
        match self.engine.step(laser, sonar, smoke, self.out) {
            Ok(report) => {
                self.stats.outputs += 1;
                self.stats.sections += report.sections as u64;
                self.stats.sonar_sections += report.sonar_sections as u64;
                self.stats.bad_layouts += u64::from(report.bad_layout);
                self.stats.speck_beams += report.speck_beams as u64;
                self.stats.vouched_beams += report.vouched_beams as u64;
                *self.last = Some(report);
                emit(self.out, &report);
            }
            Err(_) => self.stats.skipped += 1,
        }
    }
}

impl FusionPipeline {
    pub fn new(engine: FusionEngine, sync: &SyncParams) -> Self {
        Self {
            sync: Sync3::new(sync_settings(sync)),
            engine,
            out: Box::default(),
            stats: PipelineStats::default(),
            last: None,
        }
    }

    /// From a robot profile; `method` overrides `[fusion] method`.
    pub fn from_config(
        cfg: &RobotConfig,
        method: Option<FusionMethod>,
    ) -> Result<Self, GeometryError> {
        Ok(Self::new(
            FusionEngine::from_config(cfg, method)?,
            &cfg.fusion.sync,
        ))
    }

    pub fn engine(&self) -> &FusionEngine {
        &self.engine
    }

    pub fn sync_counters(&self) -> &SyncCounters<3> {
        self.sync.counters()
    }

    /// Topics currently taking part in sets (laser, sonar, smoke).
    pub fn active(&self) -> [bool; 3] {
        self.sync.core().active()
    }

    pub fn stats(&self) -> &PipelineStats {
        &self.stats
    }

    /// The report of the latest output.
    pub fn last_report(&self) -> Option<&StepReport> {
        self.last.as_ref()
    }

    fn split(&mut self) -> (&mut Sync3<LaserScan, SonarRing, SmokeReading>, Parts<'_>) {
        (
            &mut self.sync,
            Parts {
                engine: &mut self.engine,
                out: &mut self.out,
                stats: &mut self.stats,
                last: &mut self.last,
            },
        )
    }

    /// A laser scan arrived at `now_ns`. Under `laser-only` it is passed on at
    /// once; otherwise it waits in the synchroniser for its partners.
    pub fn push_laser(
        &mut self,
        scan: &LaserScan,
        now_ns: u64,
        emit: &mut impl FnMut(&FusedScan, &StepReport),
    ) {
        let bypass = self.engine.method() == FusionMethod::LaserOnly;
        let (sync, mut parts) = self.split();
        if bypass {
            parts.fuse(Some(scan), None, None, emit);
            return;
        }
        sync.push_a(scan, now_ns, &mut |m: Matched<'_, _, _, _>| {
            parts.fuse(m.a, m.b, m.c, emit)
        });
    }

    pub fn push_sonar(
        &mut self,
        ring: &SonarRing,
        now_ns: u64,
        emit: &mut impl FnMut(&FusedScan, &StepReport),
    ) {
        if self.engine.method() == FusionMethod::LaserOnly {
            return;
        }
        let (sync, mut parts) = self.split();
        sync.push_b(ring, now_ns, &mut |m: Matched<'_, _, _, _>| {
            parts.fuse(m.a, m.b, m.c, emit)
        });
    }

    pub fn push_smoke(
        &mut self,
        reading: &SmokeReading,
        now_ns: u64,
        emit: &mut impl FnMut(&FusedScan, &StepReport),
    ) {
        if self.engine.method() == FusionMethod::LaserOnly {
            self.engine.observe_smoke(reading);
            return;
        }
        let (sync, mut parts) = self.split();
        sync.push_c(reading, now_ns, &mut |m: Matched<'_, _, _, _>| {
            parts.fuse(m.a, m.b, m.c, emit)
        });
    }

    /// Time passes without input: silent topics time out.
    pub fn poll(&mut self, now_ns: u64, emit: &mut impl FnMut(&FusedScan, &StepReport)) {
        let (sync, mut parts) = self.split();
        sync.poll(now_ns, &mut |m: Matched<'_, _, _, _>| {
            parts.fuse(m.a, m.b, m.c, emit)
        });
    }

    /// End of a recording: fuse what can still be matched.
    pub fn flush(&mut self, emit: &mut impl FnMut(&FusedScan, &StepReport)) {
        let (sync, mut parts) = self.split();
        sync.flush(&mut |m: Matched<'_, _, _, _>| parts.fuse(m.a, m.b, m.c, emit));
    }
}
