//! `[slam]`: the Rao-Blackwellised particle-filter SLAM (GMapping class).
//!
//! Every parameter has a default tuned for a laser scanner. `preset = "seed-table3"`
//! starts from the values of SmokeNav (Santos et al. 2015), Table 3 instead (GMapping as the
//! SmokeNav authors ran it on sonar-only data in the 4.57 × 4.04 m MRL arena):
//!
//! | Table 3          | key here             | value |
//! |------------------|----------------------|-------|
//! | maxUrange        | `max_urange_m`       | 16.0  |
//! | sigma            | `sigma_m`            | 0.05  |
//! | kernelSize       | `kernel_size`        | 1     |
//! | iterations       | `iterations`         | 5     |
//! | linearUpdate     | `linear_update_m`    | 0.5   |
//! | angularUpdate    | `angular_update_rad` | 0.8   |
//! | temporalUpdate   | `temporal_update_s`  | 3.0   |
//! | resampleThreshold| `resample_threshold` | 0.5   |
//! | particles        | `particles`          | 30    |
//! | delta            | `resolution_m`       | 0.01  |
//!
//! Keys given explicitly in the file override the preset. Parameters Table 3
//! does not list take GMapping's own defaults in the Table 3 preset (srr 0.1,
//! srt 0.2, str 0.1, stt 0.2, lsigma 0.075, ogain 3, lstep/astep 0.05) and
//! write every processed scan into the maps, as GMapping does.
//!
//! The default preset differs where smokenav's filter differs from GMapping:
//! it processes every scan, its motion model is fed odometry already
//! corrected by the front end (so the rotation-proportional noise srt/stt is
//! 0.05 instead of 0.2: injecting 0.06 rad per scan in a 1.5 rad/s turn only to
//! have matching remove it leaves a residual that accumulates), and it writes
//! scans into the maps every 0.5 m or 0.5 rad instead of every scan.

use crate::slam_fuzzy::FuzzySection;
use crate::slam_graph::GraphSection;
use crate::slam_vote::VoteSection;
use crate::validate::{Validate, Validator};
use serde::{Deserialize, Serialize};

/// Which parameter set unspecified keys come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum SlamPreset {
    /// Tuned for a laser scanner on a moving robot: every scan is processed.
    #[default]
    #[serde(rename = "default")]
    Default,
    /// SmokeNav (Santos et al. 2015), Table 3 (GMapping fed by sonar in the MRL arena).
    #[serde(rename = "seed-table3")]
    SeedTable3,
}

/// The scan topic the SLAM process consumes (`[slam] input`, and `--input`
/// of `smokenav-slam` with the `clap` feature).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum SlamInput {
    /// `fusion/scan`: the SmokeNav fused scan (per-beam sources, smoke level).
    #[default]
    #[serde(rename = "fused")]
    Fused,
    /// `laser/scan`: the raw laser scan.
    #[serde(rename = "laser")]
    Laser,
}

/// The SLAM algorithm behind the pipeline (`[slam] backend`, and `--backend`
/// of `smokenav-slam` and `smokenav slam` with the `clap` feature): the
/// particle filter, the pose graph with loop closure, the fuzzy-map
/// registration, or a vote over several of them (`[slam.vote]`).
/// Unknown names are rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum SlamBackendKind {
    /// Rao-Blackwellised particle filter (GMapping class).
    #[default]
    #[serde(rename = "rbpf")]
    Rbpf,
    /// Pose graph with loop closure (Karto / Cartographer class).
    #[serde(rename = "graph")]
    Graph,
    /// Fuzzy confidence maps registered scan to scan (`[slam.fuzzy]`).
    #[serde(rename = "fuzzy")]
    Fuzzy,
    /// A per-cell vote over the maps of several back-ends (`[slam.vote]`).
    #[serde(rename = "vote")]
    Vote,
    /// No estimate of its own: the laser and the sonar cones mapped in 3D at
    /// the front end's pose and projected to the floor (`[mapping]`'s
    /// heights); a vote member that sees obstacles out of the laser plane.
    #[serde(rename = "projected")]
    Projected,
}

impl SlamBackendKind {
    pub fn as_str(self) -> &'static str {
        match self {
            SlamBackendKind::Rbpf => "rbpf",
            SlamBackendKind::Graph => "graph",
            SlamBackendKind::Fuzzy => "fuzzy",
            SlamBackendKind::Vote => "vote",
            SlamBackendKind::Projected => "projected",
        }
    }
}

/// What the SLAM run does with its map (`[slam] mode`, and `--localization`
/// of `smokenav slam` and `smokenav-slam`): build it, or only track the robot
/// on a saved one (`--load-graph`, graph back-end) without changing it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum SlamMode {
    /// Map (and, from a loaded graph, keep mapping).
    #[default]
    #[serde(rename = "mapping")]
    Mapping,
    /// Localise on the loaded graph's map: no new nodes, the map unchanged.
    #[serde(rename = "localization")]
    Localization,
}

/// Where a run continued from a saved graph (`--load-graph`) places its first
/// scan before matching it against the saved map (`[slam] resume_at`, and
/// `--resume-at` of `smokenav slam` and `smokenav-slam`): where the saved
/// run ended (the robot carries on from there), or where it began (a robot
/// that starts each run from its dock, as slam_toolbox's `map_start_at_dock`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum ResumeAt {
    /// The saved run's last pose.
    #[default]
    #[serde(rename = "last")]
    Last,
    /// The saved run's first node (its start).
    #[serde(rename = "first")]
    First,
}

/// Declares the section once: each field with its doc, type, default value and
/// Table-3 value. Generates the public struct, the all-optional raw form
/// serde reads, and the preset resolution.
macro_rules! slam_section {
    ($( $(#[doc = $doc:literal])* $name:ident : $ty:ty = ($default:expr, $table3:expr) ),* $(,)?) => {
        #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
        #[serde(try_from = "RawSlamSection")]
        pub struct SlamSection {
            /// The parameter set keys not given in the file come from.
            pub preset: SlamPreset,
            $( $(#[doc = $doc])* pub $name: $ty, )*
        }

        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct RawSlamSection {
            #[serde(default)]
            preset: SlamPreset,
            $( #[serde(default)] $name: Option<$ty>, )*
        }

        impl SlamSection {
            /// All values of `preset`.
            pub fn from_preset(preset: SlamPreset) -> Self {
                match preset {
                    SlamPreset::Default => Self { preset, $( $name: $default, )* },
                    SlamPreset::SeedTable3 => Self { preset, $( $name: $table3, )* },
                }
            }
        }

        impl From<RawSlamSection> for SlamSection {
            fn from(raw: RawSlamSection) -> Self {
                let base = Self::from_preset(raw.preset);
                Self {
                    preset: raw.preset,
                    $( $name: raw.$name.unwrap_or(base.$name), )*
                }
            }
        }
    };
}

slam_section! {
    /// Number of particles (Table 3: particles).
    particles: usize = (30, 30),
    /// Threads that scan-match, weigh and write the particles of one scan side
    /// by side (each particle's work is its own, so the result does not
    /// depend on it); 0 = one per core the computer has. Cuts the time from a
    /// scan to its pose, not the CPU time.
    threads: usize = (0, 0),
    /// Map cell size, m (Table 3: delta).
    resolution_m: f64 = (0.05, 0.01),
    /// How often the SLAM process publishes the best particle's map, Hz.
    map_rate_hz: f64 = (1.0, 1.0),
    /// Largest map the SLAM process publishes or saves, in cells (width ×
    /// height; 2²⁵, e.g. 400 m × 200 m at 5 cm). A larger map is refused,
    /// counted (`maps_refused`) and named in health: a building that size
    /// is rare, a pose gone astray less so, and every subscriber's shared
    /// memory would grow to hold its map.
    max_map_cells: usize = (1 << 25, 1 << 25),
    /// Scan topic the SLAM process consumes.
    input: SlamInput = (SlamInput::Fused, SlamInput::Fused),
    /// The SLAM algorithm (`rbpf`, `graph`, `fuzzy` or `vote`).
    backend: SlamBackendKind = (SlamBackendKind::Rbpf, SlamBackendKind::Rbpf),
    /// `mapping`, or `localization` on a saved graph (needs `--load-graph` and the graph back-end).
    mode: SlamMode = (SlamMode::Mapping, SlamMode::Mapping),
    /// Where a run from a saved graph starts: `last` (where it ended) or
    /// `first` (where it began, e.g. a dock); matched there within the closure window.
    resume_at: ResumeAt = (ResumeAt::Last, ResumeAt::Last),
    /// A graph saved by `smokenav slam --save-graph` or the SLAM process's
    /// SIGUSR1 (`G` and `G.scans`) to continue or localise on, as
    /// `--load-graph` (which overrides it); an absolute path.
    load_graph: Option<std::path::PathBuf> = (None, None),
    /// Seed of the filter's random numbers: the same input and seed give the same output.
    seed: u64 = (42, 42),
    /// Readings at or beyond this are "no return" and are ignored, m (GMapping maxRange).
    max_range_m: f64 = (80.0, 80.0),
    /// Readings are used up to this range; longer ones only clear free space up to it,
    /// m (Table 3: maxUrange).
    max_urange_m: f64 = (16.0, 16.0),
    /// Standard deviation of a laser endpoint in clear air for scan matching and
    /// the scan likelihood, m (Table 3: sigma).
    sigma_m: f64 = (0.05, 0.05),
    /// Cells searched around each endpoint for the nearest obstacle (Table 3: kernelSize).
    kernel_size: u32 = (1, 1),
    /// Scan-matcher step-halving refinements (Table 3: iterations).
    iterations: u32 = (3, 5),
    /// Initial translational step of the scan matcher, m (GMapping lstep).
    lstep_m: f64 = (0.05, 0.05),
    /// Initial rotational step of the scan matcher, rad (GMapping astep).
    astep_rad: f64 = (0.05, 0.05),
    /// Use every (lskip+1)-th beam for scan matching and the likelihood (GMapping lskip).
    lskip: u32 = (0, 0),
    /// Standard deviation of an endpoint in the likelihood that weights particles, m
    /// (GMapping lsigma).
    lsigma_m: f64 = (0.075, 0.075),
    /// Smoothing of the likelihood: log-weights are divided by `ogain × particles`
    /// (GMapping ogain).
    ogain: f64 = (3.0, 3.0),
    /// Log-likelihood of a beam whose endpoint matches no obstacle, in units of
    /// `(d/lsigma)²/2` (caps the penalty of one outlier beam).
    null_likelihood: f64 = (2.0, 2.0),
    /// Odometry error in translation as a function of translation (GMapping srr).
    srr: f64 = (0.1, 0.1),
    /// Odometry error in translation as a function of rotation (GMapping srt).
    srt: f64 = (0.05, 0.2),
    /// Odometry error in rotation as a function of translation (GMapping str).
    str: f64 = (0.1, 0.1),
    /// Odometry error in rotation as a function of rotation (GMapping stt).
    stt: f64 = (0.05, 0.2),
    /// Run a filter update once the robot travelled this far, m; 0 = every scan
    /// (Table 3: linearUpdate).
    linear_update_m: f64 = (0.0, 0.5),
    /// … or turned this far, rad; 0 = every scan (Table 3: angularUpdate).
    angular_update_rad: f64 = (0.0, 0.8),
    /// … or this much time passed, s; -1 = never by time alone (Table 3: temporalUpdate).
    temporal_update_s: f64 = (-1.0, 3.0),
    /// Scans are written into the particles' maps once the robot moved this far
    /// since the last write, m (matching and weighting still happen every
    /// scan). Fewer writes keep one pose's matching error from being copied into
    /// the map scan after scan; 0 writes every processed scan.
    map_update_m: f64 = (0.5, 0.0),
    /// … or turned this far, rad.
    map_update_rad: f64 = (0.5, 0.0),
    /// Resample when the effective sample size falls below this share of the
    /// particles (Table 3: resampleThreshold).
    resample_threshold: f64 = (0.5, 0.5),
    /// Log-odds added to a cell a beam ends in.
    hit_logodds: f64 = (0.9, 0.9),
    /// Log-odds added to the cell a sonar-painted beam ends in. The fused scan
    /// paints a sonar's echo as an arc across its cone, but the echo came
    /// from one place on it (the nearest surface): the arc's cells are
    /// weaker evidence than a laser endpoint (Tran et al. 2021: weigh each sensor by
    /// its precision). The free space before the arc is as sure as a laser's.
    sonar_hit_logodds: f64 = (0.3, 0.3),
    /// Share of a painted sonar arc, about its middle, that the graph's map
    /// draws as occupied (1 = the whole arc). The fused scan paints an echo
    /// across the sonar's whole section, but the echo came from one place on
    /// it, most likely near the cone's axis, where a transducer is most
    /// sensitive (the angular term of Moravec and Elfes's sonar model): an
    /// arc's ends stand in front of an oblique wall. Where a neighbouring
    /// transducer reads shorter, the wall's normal lies towards it and the
    /// echo came from the cone's edge on that side: the share is then taken
    /// about the centre of the arc's third on that side. Free space is still
    /// cleared across the whole cone. Only the graph's map: the particle
    /// filter matches its sonar beams against its own map and keeps them.
    sonar_arc_middle: f64 = (1.0 / 3.0, 1.0),
    /// The maps (the particle filter's and the graph's) draw no wall at the
    /// end of a laser beam the sonar contradicts (its section's sonar heard
    /// its first echo more than 0.3 m further) whose range jitters from
    /// beam to beam more than this (median |second difference| of the
    /// ranges over ±2 beams), m, and clear the space up to it. That is a
    /// smoke cloud seen from clean air, which the fusion keeps while the
    /// smoke sensor on the robot reads clean; a wall's ranges run smoothly
    /// however obliquely it is met (a URG-04LX's ±10 mm noise gives ~17 mm).
    /// 0 draws every laser return, as the Table 3 preset does (GMapping).
    smoke_return_rough_m: f64 = (0.15, 0.0),
    /// Log-odds removed from a cell a beam passes through.
    miss_logodds: f64 = (0.4, 0.4),
    /// Log-odds saturate at ± this value, so the map can still change.
    max_logodds: f64 = (4.0, 4.0),
    /// Scan-match a particle's pose only when the scan has at least this many
    /// laser endpoints (after decimation); with fewer — the laser lost to
    /// smoke and only sonar arcs left — the particles follow the odometry and
    /// the sonar only weighs them. Wide sonar cones pull a matcher along a
    /// wall rather than fix the pose; wheel odometry over the seconds a smoke
    /// cloud lasts is the better guess (GMapping's minimumScore, by evidence).
    min_match_laser_points: u32 = (40, 40),
    /// Endpoint standard deviation of beams that came from sonar (per `FusedScan::beam_source`), m.
    sonar_sigma_m: f64 = (0.2, 0.2),
    /// Laser range variance in clear air (Sevcik & Oh 2007: B_o = 5, mm²). The laser
    /// noise model of `smokenav-algorithms-slam` (its `noise` module) turns these variances and
    /// the smoke levels below into a per-scan noise factor.
    laser_variance_clear: f64 = (5.0, 5.0),
    /// Laser range variance in light obscurant (Sevcik & Oh 2007: rain, B_rain = 8.39).
    laser_variance_light: f64 = (8.39, 8.39),
    /// Laser range variance in dense obscurant (Sevcik & Oh 2007: fog at ~8 m visibility, B_fog = 13.75).
    laser_variance_dense: f64 = (13.75, 13.75),
    /// Smoke level (SmokeNav's mV scale) at which the light-obscurant variance applies (SmokeNav v1's first threshold).
    smoke_level_light: f64 = (130.0, 130.0),
    /// Smoke level at and above which the dense-obscurant variance applies (SmokeNav v1's last threshold).
    smoke_level_dense: f64 = (240.0, 240.0),
    /// Track motion by matching each scan against the last scans before the
    /// particles' own scan matching (needed when odometry arrives late or stalls).
    frontend: bool = (true, true),
    /// Scans kept in the front end's local map.
    frontend_scans: u32 = (12, 12),
    /// Translational search window of the front end around its prediction, ± m.
    frontend_window_m: f64 = (1.0, 1.0),
    /// Rotational search window of the front end around its prediction, ± rad.
    frontend_window_rad: f64 = (0.4, 0.4),
    /// After this much travel on odometry's heading alone (m; the laser
    /// blind in smoke, or unmatched), a scan the front end cannot match
    /// turns its heading onto the local map's walls where both are clearly
    /// square (within ± 45°); 0 never. For buildings built square; a round
    /// or diagonal hall is left alone by itself.
    square_after_blind_m: f64 = (3.0, 3.0),
    /// While no laser match gives the heading (smoke), a sonar at ±90°
    /// whose readings over this much travel lie on a straight wall gives
    /// it (the robot's angle to the wall from how the range changes, the
    /// wall's direction the local map's nearest square one) and the
    /// sideways drift (how far the robot closed on the wall); m, 0 never.
    /// The window starts afresh where the range jumps (a wall beginning
    /// beside the robot) and after a turn.
    side_wall_window_m: f64 = (1.5, 1.5),
    /// Health goes degraded while the heading has been odometry's alone
    /// (the laser blind or unmatched in the front end) for more than this
    /// travel, m; 0 never. Dead reckoning turns a map: the Scout's odometry
    /// in the simulator drifts ~2.5°/√m, a Pioneer with one wheel 2 % off
    /// ~3°/m.
    max_blind_m: f64 = (5.0, 5.0),
    /// Deskew each laser sweep by the odometry's motion over it, where the
    /// laser gives its time between beams (the Hokuyo driver does; a
    /// CARMEN log does not). Off for a driver that stamps a scan at its last
    /// beam instead of its first (`sensor_msgs/LaserScan`: the first), whose
    /// sweeps it would bend the wrong way. The mapping process reads it too:
    /// it deskews the scans it maps by `base/odom`'s velocities.
    deskew: bool = (true, true),
    /// Move each echo the fusion painted from a sonar by the robot's motion
    /// since the transducer fired: a ring reports every transducer's last
    /// range each cycle, up to a cycle old (the Scout's: a second), and a
    /// wall ahead heard then is nearer now. The firing is dated by when the
    /// transducer's value last changed and the ring's cycle (learnt the same way).
    sonar_age_compensation: bool = (true, true),
    /// Mark free, in every map SLAM exports, the cells the robot's body
    /// covered along its trajectory (`[robot] radius_m` less half a cell):
    /// nothing stands where the robot drove. Removes the phantom walls a
    /// smoke cloud leaves in the robot's own path when the laser saw the
    /// cloud before the robot drove through it. Cleared along the back-end's
    /// trajectory (the particle filter keeps its particles' paths for it).
    /// Never in localisation: the loaded map stays as it was.
    clear_footprint: bool = (true, true),
    /// Radius of the disc cleared round each pose, m; 0: `[robot] radius_m`
    /// less half a cell. Give the disc the robot's body covers whichever way
    /// it turns, measured from its pose (the inscribed radius): a robot that
    /// is longer than wide (the Pioneer 3-DX: 210 mm to its nose, 212 mm to
    /// its sides) would otherwise erase a wall it stopped right in front of.
    footprint_radius_m: f64 = (0.0, 0.0),
    /// `[slam.fuzzy]`: the fuzzy confidence model and its registration back-end.
    fuzzy: FuzzySection = (FuzzySection::default(), FuzzySection::default()),
    /// `[slam.graph]`: the graph back-end's node spacing and loop-closure search.
    graph: GraphSection = (GraphSection::default(), GraphSection::default()),
    /// `[slam.vote]`: the members of `backend = "vote"`, the rule and the alignment.
    vote: VoteSection = (VoteSection::default(), VoteSection::default()),
}

impl Default for SlamSection {
    fn default() -> Self {
        Self::from_preset(SlamPreset::Default)
    }
}

impl Validate for SlamSection {
    fn validate(&self, key: &str, v: &mut Validator) {
        let k = |name: &str| format!("{key}.{name}");
        if !(1..=1000).contains(&self.particles) {
            v.fail(
                k("particles"),
                format!("must be 1–1000, got {}", self.particles),
            );
        }
        if self.threads > 256 {
            v.fail(
                k("threads"),
                format!("must be 0 (one per core) to 256, got {}", self.threads),
            );
        }
        if let Some(g) = &self.load_graph
            && !g.is_absolute()
        {
            v.fail(
                k("load_graph"),
                format!(
                    "must be an absolute path (a service runs in /), got {}",
                    g.display()
                ),
            );
        }
        v.within(&k("resolution_m"), self.resolution_m, 0.005, 1.0);
        v.within(&k("map_rate_hz"), self.map_rate_hz, 0.01, 20.0);
        if !(1_000..=1 << 30).contains(&self.max_map_cells) {
            v.fail(
                k("max_map_cells"),
                format!(
                    "must be 1000 to 2^30 (1073741824), got {}",
                    self.max_map_cells
                ),
            );
        }
        v.within(&k("max_range_m"), self.max_range_m, 0.1, 1000.0);
        v.within(&k("max_urange_m"), self.max_urange_m, 0.1, 1000.0);
        v.ordered(
            &k("max_urange_m"),
            self.max_urange_m - 1e-9,
            "max_range_m",
            self.max_range_m,
        );
        v.within(&k("sigma_m"), self.sigma_m, 0.001, 5.0);
        if self.kernel_size > 5 {
            v.fail(
                k("kernel_size"),
                format!("must be 0–5, got {}", self.kernel_size),
            );
        }
        if self.iterations > 12 {
            v.fail(
                k("iterations"),
                format!("must be 0–12, got {}", self.iterations),
            );
        }
        v.within(&k("lstep_m"), self.lstep_m, 0.0001, 2.0);
        v.within(&k("astep_rad"), self.astep_rad, 0.0001, 1.0);
        if self.min_match_laser_points > 100_000 {
            v.fail(
                k("min_match_laser_points"),
                format!("must be 0–100000, got {}", self.min_match_laser_points),
            );
        }
        if self.lskip > 16 {
            v.fail(k("lskip"), format!("must be 0–16, got {}", self.lskip));
        }
        v.within(&k("lsigma_m"), self.lsigma_m, 0.001, 5.0);
        v.within(&k("ogain"), self.ogain, 0.01, 1000.0);
        v.within(&k("null_likelihood"), self.null_likelihood, 0.0, 100.0);
        for (name, val) in [
            ("srr", self.srr),
            ("srt", self.srt),
            ("str", self.str),
            ("stt", self.stt),
        ] {
            v.within(&k(name), val, 0.0, 10.0);
        }
        v.within(&k("linear_update_m"), self.linear_update_m, 0.0, 100.0);
        v.within(&k("angular_update_rad"), self.angular_update_rad, 0.0, 10.0);
        if !(self.temporal_update_s == -1.0
            || (self.temporal_update_s >= 0.0 && self.temporal_update_s <= 3600.0))
        {
            v.fail(
                k("temporal_update_s"),
                format!(
                    "must be -1 (off) or within [0, 3600], got {}",
                    self.temporal_update_s
                ),
            );
        }
        v.within(&k("map_update_m"), self.map_update_m, 0.0, 100.0);
        v.within(&k("map_update_rad"), self.map_update_rad, 0.0, 10.0);
        v.within(&k("resample_threshold"), self.resample_threshold, 0.0, 1.0);
        v.within(&k("hit_logodds"), self.hit_logodds, 0.01, 20.0);
        v.within(&k("sonar_hit_logodds"), self.sonar_hit_logodds, 0.01, 20.0);
        v.within(&k("sonar_arc_middle"), self.sonar_arc_middle, 0.0, 1.0);
        v.within(
            &k("smoke_return_rough_m"),
            self.smoke_return_rough_m,
            0.0,
            10.0,
        );
        v.within(&k("miss_logodds"), self.miss_logodds, 0.01, 20.0);
        v.within(&k("max_logodds"), self.max_logodds, 0.1, 50.0);
        v.within(&k("sonar_sigma_m"), self.sonar_sigma_m, 0.001, 5.0);
        v.within(&k("max_blind_m"), self.max_blind_m, 0.0, 10_000.0);
        v.within(&k("footprint_radius_m"), self.footprint_radius_m, 0.0, 2.0);
        v.positive(&k("laser_variance_clear"), self.laser_variance_clear);
        v.positive(&k("laser_variance_light"), self.laser_variance_light);
        v.positive(&k("laser_variance_dense"), self.laser_variance_dense);
        v.non_negative(&k("smoke_level_light"), self.smoke_level_light);
        v.ordered(
            &k("smoke_level_light"),
            self.smoke_level_light,
            "smoke_level_dense",
            self.smoke_level_dense,
        );
        if !(1..=200).contains(&self.frontend_scans) {
            v.fail(
                k("frontend_scans"),
                format!("must be 1–200, got {}", self.frontend_scans),
            );
        }
        v.within(&k("frontend_window_m"), self.frontend_window_m, 0.0, 5.0);
        v.within(
            &k("square_after_blind_m"),
            self.square_after_blind_m,
            0.0,
            1000.0,
        );
        v.within(&k("side_wall_window_m"), self.side_wall_window_m, 0.0, 10.0);
        v.within(
            &k("frontend_window_rad"),
            self.frontend_window_rad,
            0.0,
            1.6,
        );
        self.fuzzy.validate(&k("fuzzy"), v);
        self.graph.validate(&k("graph"), v);
        self.vote.validate(&k("vote"), v);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::parse_toml;
    use std::path::Path;

    fn section(text: &str) -> SlamSection {
        parse_toml::<SlamSection>(text, Path::new("slam.toml")).unwrap_or_else(|e| panic!("{e}"))
    }

    #[test]
    fn seed_table3_preset_has_the_paper_values() {
        let s = section("preset = \"seed-table3\"\n");
        assert_eq!(s.max_urange_m, 16.0);
        assert_eq!(s.sigma_m, 0.05);
        assert_eq!(s.kernel_size, 1);
        assert_eq!(s.iterations, 5);
        assert_eq!(
            (s.linear_update_m, s.angular_update_rad, s.temporal_update_s),
            (0.5, 0.8, 3.0)
        );
        assert_eq!(s.resample_threshold, 0.5);
        assert_eq!(s.particles, 30);
        assert_eq!(s.resolution_m, 0.01);
        let mut v = Validator::default();
        s.validate("slam", &mut v);
        assert!(v.issues.is_empty(), "{:?}", v.issues);
    }

    #[test]
    fn explicit_key_overrides_the_preset() {
        let s = section("preset = \"seed-table3\"\nresolution_m = 0.05\nparticles = 10\n");
        assert_eq!((s.resolution_m, s.particles), (0.05, 10));
        assert_eq!(s.iterations, 5, "untouched keys keep the preset value");
    }

    #[test]
    fn empty_section_is_the_default_preset_and_valid() {
        let s = section("");
        assert_eq!(s, SlamSection::default());
        assert_eq!(s.linear_update_m, 0.0, "the default processes every scan");
        let mut v = Validator::default();
        s.validate("slam", &mut v);
        assert!(v.issues.is_empty(), "{:?}", v.issues);
    }

    #[test]
    fn unknown_slam_key_is_rejected_with_its_name() {
        let err =
            parse_toml::<SlamSection>("particels = 30\n", Path::new("slam.toml")).unwrap_err();
        assert!(err.to_string().contains("particels"), "{err}");
    }

    #[test]
    fn serialised_section_parses_back_to_itself() {
        let s = SlamSection::from_preset(SlamPreset::SeedTable3);
        let text = toml::to_string(&s).unwrap();
        assert_eq!(section(&text), s);
    }

    #[test]
    fn bad_values_are_named() {
        let s = SlamSection {
            srr: -1.0,
            temporal_update_s: -2.0,
            max_urange_m: 90.0,
            ..SlamSection::default()
        };
        let mut v = Validator::default();
        s.validate("slam", &mut v);
        let keys: Vec<_> = v.issues.iter().map(|i| i.key.as_str()).collect();
        assert!(keys.contains(&"slam.srr"), "{keys:?}");
        assert!(keys.contains(&"slam.temporal_update_s"), "{keys:?}");
        assert!(keys.contains(&"slam.max_urange_m"), "{keys:?}");
    }

    #[test]
    fn mode_names_are_strict() {
        assert_eq!(section("").mode, SlamMode::Mapping);
        assert_eq!(
            section("mode = \"localization\"\n").mode,
            SlamMode::Localization
        );
        let err = parse_toml::<SlamSection>("mode = \"localisation\"\n", Path::new("slam.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("mode") && err.contains("localisation"),
            "{err}"
        );
    }

    #[test]
    fn resume_at_names_are_strict() {
        assert_eq!(section("").resume_at, ResumeAt::Last);
        assert_eq!(
            section("resume_at = \"first\"\n").resume_at,
            ResumeAt::First
        );
        let err = parse_toml::<SlamSection>("resume_at = \"start\"\n", Path::new("slam.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("resume_at") && err.contains("start"), "{err}");
    }

    #[test]
    fn a_graph_to_load_is_an_absolute_path() {
        assert_eq!(section("").load_graph, None);
        let s = section("load_graph = \"/var/lib/smokenav/maps/graph.g2o\"\n");
        assert_eq!(
            s.load_graph.as_deref(),
            Some(Path::new("/var/lib/smokenav/maps/graph.g2o"))
        );
        let mut v = Validator::default();
        section("load_graph = \"maps/graph.g2o\"\n").validate("slam", &mut v);
        let e = format!("{v:?}");
        assert!(
            e.contains("slam.load_graph") && e.contains("absolute"),
            "{e}"
        );
    }

    #[test]
    fn backend_names_are_strict() {
        assert_eq!(
            section("backend = \"rbpf\"\n").backend,
            SlamBackendKind::Rbpf
        );
        assert_eq!(
            section("backend = \"graph\"\n").backend,
            SlamBackendKind::Graph
        );
        assert_eq!(
            section("backend = \"fuzzy\"\n").backend,
            SlamBackendKind::Fuzzy
        );
        let err = parse_toml::<SlamSection>("backend = \"karto\"\n", Path::new("slam.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("backend") && err.contains("karto"), "{err}");
    }

    #[test]
    fn vote_keys_are_strict_and_validated() {
        let s = section(
            "backend = \"vote\"\n[vote]\nmembers = [\"graph\", \"rbpf\"]\nrule = \"weighted\"\n",
        );
        assert_eq!(s.backend, SlamBackendKind::Vote);
        assert_eq!(
            s.vote.members,
            [SlamBackendKind::Graph, SlamBackendKind::Rbpf]
        );
        assert_eq!(s.vote.rule, crate::slam_vote::VoteRule::Weighted);
        assert_eq!(s.vote.max_residual_m, 0.15, "unset keys keep their default");
        assert_eq!(
            section("backend = \"vote\"\n").vote.rule,
            crate::slam_vote::VoteRule::Majority,
            "majority is the default rule"
        );
        assert_eq!(
            section("[vote]\nrule = \"corroborated\"\n").vote.rule,
            crate::slam_vote::VoteRule::Corroborated
        );
        assert_eq!(
            section("[vote]\nrule = \"corroborated-reference\"\n")
                .vote
                .rule,
            crate::slam_vote::VoteRule::CorroboratedReference
        );
        let err = parse_toml::<SlamSection>("[vote]\nmax_residual = 0.2\n", Path::new("slam.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("max_residual"), "{err}");
        let err =
            parse_toml::<SlamSection>("[vote]\nmembers = [\"karto\"]\n", Path::new("slam.toml"))
                .unwrap_err()
                .to_string();
        assert!(err.contains("karto"), "{err}");
        let bad = section(
            "[vote]\nmembers = [\"vote\", \"rbpf\", \"rbpf\"]\nqueue = 0\nlocal_block_m = 0.0\nlocal_shift_cells = 11\n",
        );
        let mut v = Validator::default();
        bad.validate("slam", &mut v);
        let msgs: Vec<String> = v.issues.iter().map(|i| i.to_string()).collect();
        assert!(
            msgs.iter()
                .any(|m| m.contains("slam.vote.members") && m.contains("itself")),
            "{msgs:?}"
        );
        assert!(
            msgs.iter().any(|m| m.contains("rbpf is named twice")),
            "{msgs:?}"
        );
        assert!(
            msgs.iter().any(|m| m.contains("slam.vote.queue")),
            "{msgs:?}"
        );
        for key in ["slam.vote.local_block_m", "slam.vote.local_shift_cells"] {
            assert!(msgs.iter().any(|m| m.contains(key)), "{key}: {msgs:?}");
        }
        let one = section("[vote]\nmembers = [\"rbpf\"]\n");
        let mut v = Validator::default();
        one.validate("slam", &mut v);
        assert!(!v.issues.is_empty(), "one member is no vote");
        // `projected` votes out of the plane only: beside two, not as one of them.
        let ok = section("[vote]\nmembers = [\"rbpf\", \"graph\", \"fuzzy\", \"projected\"]\n");
        let mut v = Validator::default();
        ok.validate("slam", &mut v);
        assert!(v.issues.is_empty(), "{:?}", v.issues);
        for bad in [
            "[vote]\nmembers = [\"rbpf\", \"projected\"]\n",
            "[vote]\nmembers = [\"projected\", \"rbpf\", \"graph\"]\n",
        ] {
            let mut v = Validator::default();
            section(bad).validate("slam", &mut v);
            assert!(
                v.issues
                    .iter()
                    .any(|i| i.to_string().contains("slam.vote.members")),
                "{bad}: {:?}",
                v.issues
            );
        }
    }

    #[test]
    fn fuzzy_keys_are_strict_and_validated() {
        let s = section("[fuzzy]\nsearch = \"correlative\"\nsonar_k = 0.4\n");
        assert_eq!(s.fuzzy.search, crate::slam_fuzzy::FuzzySearch::Correlative);
        assert_eq!(s.fuzzy.sonar_k, 0.4);
        assert_eq!(
            s.fuzzy.laser_angular_resolution_deg, 0.36,
            "untouched keys keep the preset"
        );
        let err = parse_toml::<SlamSection>("[fuzzy]\nsonar_kk = 0.4\n", Path::new("slam.toml"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("sonar_kk"), "{err}");
        let bad = section("[fuzzy]\ncuckoo_levy_beta = 3.0\nwindow_m = -1.0\n");
        let mut v = Validator::default();
        bad.validate("slam", &mut v);
        let keys: Vec<_> = v.issues.iter().map(|i| i.key.as_str()).collect();
        assert!(keys.contains(&"slam.fuzzy.cuckoo_levy_beta"), "{keys:?}");
        assert!(keys.contains(&"slam.fuzzy.window_m"), "{keys:?}");
    }
}
