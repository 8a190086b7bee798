//! The combined scan SmokeNav hands to SLAM.

use crate::header::Header;
use crate::laser::{LaserScan, MAX_BEAMS};
use crate::sonar::MAX_SONARS;
use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

/// Which sensor a section (or beam) of the fused scan came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum SectionSource {
    /// The laser's own readings, untouched.
    #[default]
    Laser = 0,
    /// The sonar reading replaced the laser in this section.
    Sonar = 1,
    /// Sonar superimposed on the laser (both kept, nearer wins per beam).
    /// As a beam's source: a laser range in a section given to the sonar,
    /// which the sonar did not contradict (v2); SLAM maps it, unmatched.
    Both = 2,
    /// Neither is trusted: beams are marked beyond-max so SLAM treats them as no return.
    Neither = 3,
}

impl SectionSource {
    /// The source a `u8` field holds; unknown values read as `Laser`.
    pub fn from_u8(v: u8) -> Self {
        match v {
            1 => SectionSource::Sonar,
            2 => SectionSource::Both,
            3 => SectionSource::Neither,
            _ => SectionSource::Laser,
        }
    }

    /// Its name in JSON records and logs (`laser`, `sonar`, `both`, `neither`).
    pub fn as_str(self) -> &'static str {
        match self {
            SectionSource::Laser => "laser",
            SectionSource::Sonar => "sonar",
            SectionSource::Both => "both",
            SectionSource::Neither => "neither",
        }
    }

    /// The source named `s`, as [`SectionSource::as_str`] spells it.
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "laser" => SectionSource::Laser,
            "sonar" => SectionSource::Sonar,
            "both" => SectionSource::Both,
            "neither" => SectionSource::Neither,
            _ => return None,
        })
    }
}

/// A fusion method: what `[fusion] method` selects, what `--method` takes,
/// and what a [`FusedScan`] says produced it. Its names (`laser-only`, `v1`,
/// `v2`) are the same in the profile, on the command line and in JSON. Both
/// methods are those of SmokeNav (Santos et al. 2015).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[serde(rename_all = "kebab-case")]
#[repr(u8)]
pub enum FusionMethod {
    /// The laser scan untouched.
    #[default]
    LaserOnly = 0,
    /// SmokeNav v1, the heuristic (Algorithm 2).
    V1 = 1,
    /// SmokeNav v2, the fuzzy model (Algorithm 3).
    V2 = 2,
}

impl FusionMethod {
    /// The method a `u8` field holds; unknown values read as `LaserOnly`.
    pub fn from_u8(v: u8) -> Self {
        match v {
            1 => FusionMethod::V1,
            2 => FusionMethod::V2,
            _ => FusionMethod::LaserOnly,
        }
    }

    /// Its name (`laser-only`, `v1`, `v2`).
    pub fn as_str(self) -> &'static str {
        match self {
            FusionMethod::LaserOnly => "laser-only",
            FusionMethod::V1 => "v1",
            FusionMethod::V2 => "v2",
        }
    }

    /// The method named `s`, as [`FusionMethod::as_str`] spells it.
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "laser-only" => FusionMethod::LaserOnly,
            "v1" => FusionMethod::V1,
            "v2" => FusionMethod::V2,
            _ => return None,
        })
    }
}

/// Which inputs the synchroniser could pair for this output.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum SyncState {
    /// Laser, sonar and smoke all present within the sync window.
    #[default]
    Complete = 0,
    /// The sonar (or smoke) input timed out: the scan is the laser alone.
    LaserOnly = 1,
    /// The laser timed out: the scan is built from sonar alone.
    SonarOnly = 2,
    /// Laser and sonar fused without a smoke reading (none within the sync
    /// timeout): v2 assumes smoke and keeps the sonar witness on in every
    /// section (as it does, under `Complete`, for a sensor that is not ready).
    NoSmoke = 3,
}

impl SyncState {
    /// The state a `u8` field holds; unknown values read as `Complete`.
    pub fn from_u8(v: u8) -> Self {
        match v {
            1 => SyncState::LaserOnly,
            2 => SyncState::SonarOnly,
            3 => SyncState::NoSmoke,
            _ => SyncState::Complete,
        }
    }

    /// Its name in JSON records and logs (`complete`, `laser-only`, `sonar-only`, `no-smoke`).
    pub fn as_str(self) -> &'static str {
        match self {
            SyncState::Complete => "complete",
            SyncState::LaserOnly => "laser-only",
            SyncState::SonarOnly => "sonar-only",
            SyncState::NoSmoke => "no-smoke",
        }
    }
}

/// The decision for one sonar section τ of one scan.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
pub struct SectionDecision {
    /// First beam of the section in the scan.
    pub first_beam: u16,
    /// One past the last beam of the section.
    pub end_beam: u16,
    /// Sonar index (robot profile numbering) that defines the section.
    pub sonar_index: u8,
    /// A [`SectionSource`] as `u8`.
    pub source: u8,
    /// Zero.
    pub _reserved: [u8; 2],
    /// Trust in the sonar, ρS ∈ [0, 1] (v2; 1/0 for v1's crisp choice).
    pub rho_sonar: f32,
    /// Trust in the laser, ρL ∈ [0, 1].
    pub rho_laser: f32,
    /// The sonar range that was used or rejected, m.
    pub sonar_range: f32,
}

impl SectionDecision {
    /// The section's [`SectionSource`].
    pub fn source(&self) -> SectionSource {
        SectionSource::from_u8(self.source)
    }
}

/// A laser-scan-shaped output any 2D SLAM can consume, plus why it looks the way it does.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[repr(C)]
#[type_name("smokenav::FusedScan")]
pub struct FusedScan {
    /// The combined scan (header stamp = the laser scan's stamp).
    pub scan: LaserScan,
    /// Per-beam [`SectionSource`] as `u8` (Laser, Sonar or Neither), for
    /// consumers that model sonar beams with a wider noise.
    pub beam_source: [u8; MAX_BEAMS],
    /// A [`FusionMethod`] as `u8`.
    pub method: u8,
    /// A [`SyncState`] as `u8`.
    pub sync_state: u8,
    /// Zero.
    pub _reserved: [u8; 2],
    /// Sections in use (`<= MAX_SONARS`).
    pub section_count: u32,
    /// The decision per section; the first `section_count` are in use.
    pub sections: [SectionDecision; MAX_SONARS],
    /// Smoke level used for the decision (the SmokeNav paper's mV scale; see `SmokeReading::level`).
    pub smoke_level: f32,
    /// Standard deviation of the valid laser ranges of the whole scan, m.
    pub laser_spread: f32,
    /// Stamps of the inputs that were fused, ns (0 when absent).
    pub sonar_stamp_ns: u64,
    /// Stamp of the fused smoke reading, ns (0 when absent).
    pub smoke_stamp_ns: u64,
}

impl Default for FusedScan {
    fn default() -> Self {
        Self {
            scan: LaserScan::default(),
            beam_source: [0; MAX_BEAMS],
            method: 0,
            sync_state: 0,
            _reserved: [0; 2],
            section_count: 0,
            sections: [SectionDecision::default(); MAX_SONARS],
            smoke_level: 0.0,
            laser_spread: 0.0,
            sonar_stamp_ns: 0,
            smoke_stamp_ns: 0,
        }
    }
}

impl FusedScan {
    /// The combined scan's header.
    pub fn header(&self) -> &Header {
        &self.scan.header
    }

    /// The sections in use.
    pub fn sections(&self) -> &[SectionDecision] {
        &self.sections[..(self.section_count as usize).min(MAX_SONARS)]
    }

    /// The [`FusionMethod`] that produced the scan.
    pub fn method(&self) -> FusionMethod {
        FusionMethod::from_u8(self.method)
    }

    /// Which inputs were paired.
    pub fn sync_state(&self) -> SyncState {
        SyncState::from_u8(self.sync_state)
    }

    /// The source of beam `i`.
    pub fn beam_source(&self, i: usize) -> SectionSource {
        SectionSource::from_u8(self.beam_source[i])
    }

    /// Share of sections where the sonar was used (alone or superimposed):
    /// the SmokeNav paper's "sonar usage".
    pub fn sonar_usage(&self) -> f32 {
        let s = self.sections();
        if s.is_empty() {
            return 0.0;
        }
        let used = s
            .iter()
            .filter(|d| matches!(d.source(), SectionSource::Sonar | SectionSource::Both))
            .count();
        used as f32 / s.len() as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fusion_method_has_one_name_in_every_form() {
        for m in [FusionMethod::LaserOnly, FusionMethod::V1, FusionMethod::V2] {
            let json = serde_json::to_string(&m).unwrap();
            assert_eq!(json, format!("\"{}\"", m.as_str()));
            assert_eq!(serde_json::from_str::<FusionMethod>(&json).unwrap(), m);
            assert_eq!(FusionMethod::parse(m.as_str()), Some(m));
            assert_eq!(FusionMethod::from_u8(m as u8), m);
        }
        assert!(serde_json::from_str::<FusionMethod>("\"v3\"").is_err());
    }
}
