//! The SLAM pipeline: what the SLAM process, `smokenav slam` and the demo's
//! offline comparison all run, so a replay does exactly what the robot did.
//!
//! Bus messages in, in the order they were received:
//!
//! 1. odometry goes into a bounded history ([`OdomBuffer`]); a reading
//!    flagged `OdometryFlags::RESET` empties it and tells the front end (or,
//!    without one, the motion filter and the back-end) that the odometry
//!    frame jumped;
//! 2. a scan (fused or laser) is converted into a [`RangeScan`] with the
//!    laser noise of the smoke it was taken in ([`LaserNoiseModel`]); only
//!    the newest scan waits for its odometry, an older one still waiting is
//!    superseded and counted (nothing queues without bound);
//! 3. [`SlamPipeline::poll`] pairs the waiting scan with the odometry
//!    interpolated to its stamp — waiting up to [`OdomPolicy::wait_ns`] for
//!    odometry that may still arrive, holding the newest reading up to
//!    [`OdomPolicy::max_gap_ns`] old, and the last odometry used (counted)
//!    beyond that; a laser that gives its time between beams has its sweep
//!    deskewed by the odometry's velocity over the 100 ms before the stamp
//!    ([`RangeScan::deskew`]), and each echo painted from a sonar is moved
//!    by the odometry's motion since its transducer fired (dated by
//!    [`SonarAges`] from when its value changed; [`RangeScan::compensate_sonar`]);
//! 4. the front end corrects the odometry by correlative matching against the
//!    last scans ([`FrontEnd`]); where the fusion withheld more than
//!    [`MAX_WITHHELD_TO_MATCH`] of the scan from the laser, the match
//!    corrects the heading only and the odometry carries the position;
//! 5. the motion filter decides whether the scan is used
//!    ([`SlamBackend::process`]) or only moves the estimate
//!    ([`SlamBackend::predict`]).
//!
//! Time is passed in (`now_ns`), never read: a replay at any speed gives the
//! same result as the live run when the same scans were processed.

use crate::backend::{self, BackendOptions, RelocalizeError, SlamBackend, SlamUpdate, StampedPose};
use crate::frontend::{FrontEnd, FrontEndParams, MAP_RANGE_MARGIN};
use crate::motion_filter::{MotionFilter, MotionFilterParams};
use crate::noise::LaserNoiseModel;
use crate::odom_buffer::{OdomAt, OdomBuffer};
use crate::scan::{BeamKind, Endpoint, EndpointLimits, NO_SONAR, RangeScan};
use crate::side_wall::SideSonars;
use crate::sonar_age::SonarAges;
use smokenav_platform_config::SlamSection;
use smokenav_platform_map::OccupancyGrid;
use smokenav_shared_types::{FusedScan, LaserScan, Odometry, OdometryFlags};
use smokenav_shared_types::{Pose2, Twist2};

/// A scan the fusion withheld more than this share of beams from the laser
/// (painted from the sonar or dropped as smoke) corrects only the heading in
/// the front end ([`FrontEnd::track_heading`]): what is left is the laser's
/// view past the edge of the smoke, often one wall or a partial room, and
/// matching it in full slid the pose along that wall (on the dense-smoke
/// trial the graph's map error was 0.17 m, against 0.09 m with odometry
/// through the smoke), but left to odometry entirely the heading drifted
/// (a Pioneer with a wheel 2 % off turned 16° in its first metre while the
/// smoke sensor warmed up). Such scans stay out of the front end's local map.
pub const MAX_WITHHELD_TO_MATCH: f64 = 0.1;
/// How far before a scan's stamp the odometry is read to tell how the
/// robot moved during the sweep ([`RangeScan::deskew`]): one period of a
/// 10 Hz base, the Pioneer's and the Scout's odometry rate.
const TWIST_LOOKBACK_NS: u64 = 100_000_000;

/// How long a scan waits for its odometry, and how much odometry is kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OdomPolicy {
    /// Odometry newer than a scan may still be on its way: wait this long for it, ns.
    pub wait_ns: u64,
    /// A scan up to this far past the newest odometry uses that odometry, ns.
    pub max_gap_ns: u64,
    /// Odometry readings kept for interpolation.
    pub history: usize,
}

impl Default for OdomPolicy {
    fn default() -> Self {
        Self {
            wait_ns: 100_000_000,
            max_gap_ns: 300_000_000,
            // ~10 s at the Pioneer's 50 Hz.
            history: 512,
        }
    }
}

/// What the pipeline did with its input so far.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PipelineStats {
    /// Scans handed to the back-end (used or held back by the motion filter).
    pub scans: u64,
    /// Scans the motion filter held back (odometry only).
    pub held_back: u64,
    /// Scans superseded by a newer one before their odometry was known.
    pub superseded: u64,
    /// Scans without odometry at their stamp (the last odometry used was held).
    pub no_odometry: u64,
    /// Of those, the ones since the last scan that had odometry: a base
    /// driver gone silent (or never started) shows here.
    pub no_odometry_in_a_row: u64,
    /// Odometry readings flagged as a reset of the odometry frame.
    pub odom_resets: u64,
    /// Odometry readings that moved further from the one before than any
    /// robot drives in the time between ([`odometry_jumped`]), unflagged:
    /// taken as a reset, not as motion.
    pub odom_jumps: u64,
    /// Odometry readings dropped because their stamp went backwards (or was not finite).
    pub odom_out_of_order: u64,
    /// Scans without a usable endpoint (odometry and free space only).
    pub empty_scans: u64,
    /// Scans whose front-end match was not trusted (its prediction was used).
    pub frontend_fallbacks: u64,
    /// Scans whose position was left to odometry (their heading matched)
    /// because the fusion withheld more than [`MAX_WITHHELD_TO_MATCH`] of
    /// them from the laser (counted in `frontend_fallbacks` too when even
    /// the heading could not be matched).
    pub frontend_withheld: u64,
    /// The current blind stretch: odometry travel (m) and turn (rad, summed
    /// both ways) since the last scan whose heading the laser matched in
    /// the front end. Where the laser is blind (dense smoke, or walls out
    /// of range) the heading is odometry's alone, and heading error is what
    /// smoke costs a map most: on the dense-smoke trial with the
    /// simulator's seed 5, 16° of wheel odometry drift in a 14.7 m blind
    /// stretch turned the whole bay behind it. Zero without a front end.
    pub blind_m: f64,
    pub blind_rad: f64,
    /// The longest blind stretch so far, m.
    pub longest_blind_m: f64,
    /// Scans whose heading the front end turned onto the local map's
    /// square walls after a blind stretch, and the last such turn, rad.
    pub headings_squared: u64,
    pub last_squared_turn: f64,
    /// Scans whose heading a side sonar running along a wall corrected
    /// while nothing matched ([`crate::side_wall`]).
    pub side_wall_headings: u64,
    /// Scans whose sweep was deskewed ([`RangeScan::deskew`]): the laser
    /// gave its time between beams and odometry reached 100 ms before.
    pub deskewed: u64,
    /// Scans whose sonar-painted echoes were moved to where they were
    /// heard ([`RangeScan::compensate_sonar`], `[slam] sonar_age_compensation`).
    pub sonar_compensated: u64,
}

pub struct SlamPipeline {
    sensor_pose: Pose2,
    noise: LaserNoiseModel,
    limits: EndpointLimits,
    policy: OdomPolicy,
    odom: OdomBuffer,
    frontend: Option<FrontEnd>,
    /// `[slam] deskew`.
    deskew: bool,
    /// `[slam] sonar_age_compensation`, and the readings' ages.
    sonar_age_compensation: bool,
    sonar_ages: SonarAges,
    motion_filter: MotionFilter,
    backend: Box<dyn SlamBackend>,
    /// The newest scan, waiting for its odometry while `pending`.
    scan: RangeScan,
    pending: bool,
    endpoints: Vec<Endpoint>,
    /// Odometry of the last scan paired (held when a scan has none).
    last_odom: Option<Pose2>,
    /// Scans were placed on a made-up odometry (the origin: none had come
    /// yet), so the first real reading starts the odometry frame, as a
    /// reset does, rather than being travel from the origin — a Pioneer's
    /// odometry reads wherever it was left (MIT CSAIL's starts at x 576 m).
    odom_made_up: bool,
    /// Front-end corrected odometry of the last scan handed on.
    last_corrected: Option<Pose2>,
    /// Odometry of the last scan the front end tracked (for the blind stretch).
    blind_odom: Option<Pose2>,
    stats: PipelineStats,
    last_update: Option<SlamUpdate>,
    /// [`Self::with_footprint`].
    footprint_m: f64,
    /// [`Self::with_side_sonars`].
    side_sonars: SideSonars,
    /// `[fusion.v2] contradiction_margin_m` ([`Self::with_contradiction_margin`]).
    contradiction_margin_m: f32,
    /// `[slam] resolution_m`: the maps' cell size.
    resolution_m: f64,
}

/// Fastest a base's odometry may move between two readings, m/s: well
/// above any platform smokenav drives (a Pioneer 3-DX tops out at
/// 1.2 m/s, a Nomad Scout near 1 m/s).
const MAX_ODOM_SPEED_M_S: f64 = 5.0;
/// … plus this much whatever the time between (readings stamped close
/// together, jitter), m.
const MAX_ODOM_STEP_M: f64 = 0.5;

/// Whether odometry moved from reading `last` to `now` (stamp ns, pose)
/// further than a robot drives in the time between: a frame that jumped
/// without its reset flag (a driver's fault, a corrupt reading, a base
/// that reconnected unnoticed). Taken as motion it carries the poses, and
/// the map with them, as far. A reading not newer than `last` is left to
/// the buffer, which drops it.
fn odometry_jumped(last: (u64, Pose2), now: (u64, Pose2)) -> bool {
    let ((t0, p0), (t1, p1)) = (last, now);
    if t1 <= t0 || !p1.is_finite() {
        return false;
    }
    let dt = (t1 - t0) as f64 * 1e-9;
    (p1.x - p0.x).hypot(p1.y - p0.y) > MAX_ODOM_STEP_M + MAX_ODOM_SPEED_M_S * dt
}

impl SlamPipeline {
    /// A pipeline with `cfg`'s front end, motion filter and noise model around `backend`.
    pub fn new(cfg: &SlamSection, backend: Box<dyn SlamBackend>) -> Self {
        let policy = OdomPolicy::default();
        Self {
            sensor_pose: Pose2::default(),
            noise: LaserNoiseModel::from_config(cfg),
            limits: EndpointLimits::from_config(cfg),
            policy,
            odom: OdomBuffer::new(policy.history),
            deskew: cfg.deskew,
            sonar_age_compensation: cfg.sonar_age_compensation,
            sonar_ages: SonarAges::default(),
            frontend: cfg.frontend.then(|| {
                FrontEnd::new(FrontEndParams {
                    resolution: cfg.resolution_m,
                    window_m: cfg.frontend_window_m,
                    window_rad: cfg.frontend_window_rad,
                    max_scans: cfg.frontend_scans as usize,
                    // Measured on MIT CSAIL: the margin keeps the graph's
                    // corridors their length (0.3 % short without), but the
                    // RBPF fed by it ended 0.148 m from the reference
                    // instead of 0.087 m, so the RBPF keeps the cut map.
                    map_range_margin_m: if backend.name() == "rbpf" {
                        0.0
                    } else {
                        MAP_RANGE_MARGIN
                    },
                    square_after_blind_m: cfg.square_after_blind_m,
                    side_wall_window_m: cfg.side_wall_window_m,
                })
            }),
            motion_filter: MotionFilter::new(MotionFilterParams::from_config(cfg)),
            backend,
            scan: RangeScan::default(),
            pending: false,
            endpoints: Vec::new(),
            last_odom: None,
            odom_made_up: false,
            last_corrected: None,
            blind_odom: None,
            stats: PipelineStats::default(),
            last_update: None,
            footprint_m: 0.0,
            side_sonars: SideSonars::default(),
            contradiction_margin_m: crate::scan::CONTRADICTION_MARGIN_M,
            resolution_m: cfg.resolution_m,
        }
    }

    /// A pipeline around the back-end `[slam] backend` names.
    pub fn from_config(cfg: &SlamSection, opts: &BackendOptions) -> Self {
        Self::new(cfg, backend::from_config(cfg, opts))
            .with_footprint(vote_aware_footprint(cfg, opts.footprint_m))
    }

    /// Where the laser sits on the robot (bus scans carry no mount).
    pub fn with_sensor_pose(mut self, mount: Pose2) -> Self {
        self.sensor_pose = mount;
        self
    }

    pub fn with_odom_policy(mut self, policy: OdomPolicy) -> Self {
        self.policy = policy;
        self.odom = OdomBuffer::new(policy.history);
        self
    }

    pub fn noise_model(&self) -> &LaserNoiseModel {
        &self.noise
    }

    /// An odometry reading arrived.
    pub fn push_odom(&mut self, o: &Odometry) {
        let pose = Pose2::new(o.x, o.y, o.theta);
        let flagged = o.flags & OdometryFlags::RESET != 0;
        let first_real = self.odom_made_up && pose.is_finite();
        let jump = self
            .odom
            .newest()
            .filter(|&last| !flagged && odometry_jumped(last, (o.header.stamp_ns, pose)));
        if let Some((t, p)) = jump {
            self.stats.odom_jumps += 1;
            tracing::warn!(
                "odometry moved {:.1} m in {:.2} s without a reset flag: taken as a reset of its frame, not as motion (is the base driver sound?)",
                (pose.x - p.x).hypot(pose.y - p.y),
                (o.header.stamp_ns - t) as f64 * 1e-9
            );
        }
        if flagged || first_real || jump.is_some() {
            // The odometry frame jumped: poses before and after must not be mixed.
            self.odom.clear();
            self.odom_made_up = false;
            self.stats.odom_resets += u64::from(flagged);
            // The jump is no travel of the blind stretch.
            self.blind_odom = None;
            match &mut self.frontend {
                // The front end bridges the jump by matching: its output stays continuous.
                Some(fe) => fe.odometry_reset(),
                None => {
                    self.motion_filter.odometry_reset();
                    self.backend.odometry_reset();
                }
            }
        }
        self.odom.push(o.header.stamp_ns, pose);
    }

    fn supersede(&mut self) {
        self.stats.superseded += u64::from(self.pending);
        self.pending = true;
    }

    /// A fused scan arrived: it replaces a scan still waiting for odometry.
    pub fn push_fused(&mut self, f: &FusedScan) {
        self.supersede();
        let factor = self.noise.factor(f64::from(f.smoke_level));
        self.scan
            .fill_from_fused(f, self.sensor_pose, factor, self.contradiction_margin_m);
        if self.scan.sonar_stamp_ns != 0 {
            self.sonar_ages
                .observe(self.scan.sonar_stamp_ns, &self.scan.sonar);
        }
    }

    /// A laser scan arrived: it replaces a scan still waiting for odometry.
    pub fn push_laser(&mut self, l: &LaserScan) {
        self.supersede();
        self.scan.fill_from_laser(l, self.sensor_pose);
    }

    /// A scan is waiting for its odometry.
    pub fn pending(&self) -> bool {
        self.pending
    }

    /// The newest scan converted from the bus (waiting while [`Self::pending`]).
    pub fn scan(&self) -> &RangeScan {
        &self.scan
    }

    /// The odometry the last bus scan was paired with.
    pub fn last_odometry(&self) -> Option<Pose2> {
        self.last_odom
    }

    /// At `now_ns`: the waiting scan, if its odometry is known (or will not
    /// come), through the front end, the motion filter and the back-end.
    pub fn poll(&mut self, now_ns: u64) -> Option<SlamUpdate> {
        if !self.pending {
            return None;
        }
        let odom = match self.odom.at(
            self.scan.stamp_ns,
            now_ns,
            self.policy.wait_ns,
            self.policy.max_gap_ns,
        ) {
            OdomAt::NotYet => return None,
            OdomAt::Missing => {
                self.stats.no_odometry += 1;
                self.stats.no_odometry_in_a_row += 1;
                self.last_odom.unwrap_or_else(|| {
                    self.odom_made_up = true;
                    Pose2::default()
                })
            }
            OdomAt::Interpolated(p) | OdomAt::Held(p) | OdomAt::Oldest(p) => {
                self.stats.no_odometry_in_a_row = 0;
                p
            }
        };
        self.pending = false;
        let mut scan = std::mem::take(&mut self.scan);
        if self.deskew
            && scan.time_increment_s > 0.0
            && let Some(twist) = self.twist_before(scan.stamp_ns, &odom)
        {
            scan.deskew(twist);
            self.stats.deskewed += 1;
        }
        if self.sonar_age_compensation && scan.sonar_of.iter().any(|&i| i != NO_SONAR) {
            let (ages, history, stamp) = (&self.sonar_ages, &self.odom, scan.stamp_ns);
            let mut moved = false;
            scan.compensate_sonar(|index| {
                let age = ages.age_s(index, stamp)?;
                let then = history.interpolated(stamp.checked_sub((age * 1e9) as u64)?)?;
                moved = true;
                Some(odom.between(&then))
            });
            self.stats.sonar_compensated += u64::from(moved);
        }
        self.last_odom = Some(odom);
        let update = self.process(&scan, &odom);
        self.scan = scan;
        Some(update)
    }

    /// The robot's velocity (robot frame: m/s, m/s, rad/s) over the
    /// [`TWIST_LOOKBACK_NS`] before `stamp_ns`, where `odom` is the odometry:
    /// how it was moving as the sweep began. `None` without odometry that far
    /// back (the first readings) or across a reset.
    fn twist_before(&self, stamp_ns: u64, odom: &Pose2) -> Option<Twist2> {
        let then = self
            .odom
            .interpolated(stamp_ns.checked_sub(TWIST_LOOKBACK_NS)?)?;
        let dt = TWIST_LOOKBACK_NS as f64 * 1e-9;
        let d = then.between(odom);
        Some(Twist2::new(d.x / dt, d.y / dt, d.theta / dt))
    }

    /// End of the input: the waiting scan with the odometry there is.
    pub fn flush(&mut self) -> Option<SlamUpdate> {
        self.poll(u64::MAX)
    }

    /// A scan whose odometry is known already (a CARMEN log pairs them), through
    /// the front end, the motion filter and the back-end.
    pub fn process(&mut self, scan: &RangeScan, odom: &Pose2) -> SlamUpdate {
        self.stats.scans += 1;
        scan.endpoints(&self.limits, &mut self.endpoints);
        if self.endpoints.is_empty() {
            self.stats.empty_scans += 1;
        }
        let odom = if odom.is_finite() {
            *odom
        } else {
            self.last_corrected.unwrap_or_default()
        };
        let corrected = match &mut self.frontend {
            Some(fe) => {
                let trusted = scan.withheld_share <= MAX_WITHHELD_TO_MATCH;
                if !trusted {
                    self.stats.frontend_withheld += 1;
                }
                // Matched in full: the laser's own sections. By heading
                // only: also the laser ranges in sections smoke gave to the
                // sonar that the sonar's echo did not contradict — walls
                // seen through thinning smoke, which hold the heading
                // through a turn the odometry slips in.
                let matched = self
                    .endpoints
                    .iter()
                    .filter(|e| {
                        if trusted {
                            e.kind == BeamKind::Laser
                        } else {
                            e.laser_range
                        }
                    })
                    .map(|e| (e.x, e.y));
                fe.set_side_ranges(self.side_sonars.ranges(&scan.sonar));
                let tracked = if trusted {
                    fe.track(matched, &odom, scan.stamp_ns)
                } else {
                    fe.track_heading(matched, &odom, scan.stamp_ns)
                };
                self.stats.side_wall_headings += u64::from(tracked.side_turn != 0.0);
                if tracked.squared_turn != 0.0 {
                    self.stats.headings_squared += 1;
                    self.stats.last_squared_turn = tracked.squared_turn;
                }
                if tracked.score.is_none() && self.last_corrected.is_some() {
                    self.stats.frontend_fallbacks += 1;
                }
                self.count_blind(tracked.score.is_some(), &odom);
                self.backend.frontend_match(&tracked);
                tracked.pose
            }
            None => odom,
        };
        self.last_corrected = Some(corrected);
        let update = if self.motion_filter.check(&corrected, scan.stamp_ns) {
            self.backend.process(scan, &corrected)
        } else {
            self.stats.held_back += 1;
            self.backend.predict(scan.stamp_ns, &corrected)
        };
        self.last_update = Some(update);
        update
    }

    /// Adds the odometry since the last tracked scan to the blind stretch,
    /// or ends it when the laser gave this scan's heading.
    fn count_blind(&mut self, laser_heading: bool, odom: &Pose2) {
        let st = &mut self.stats;
        match self.blind_odom.replace(*odom) {
            _ if laser_heading => {
                st.blind_m = 0.0;
                st.blind_rad = 0.0;
            }
            Some(last) => {
                let step = last.between(odom);
                st.blind_m += step.translation_norm();
                st.blind_rad += step.theta.abs();
                st.longest_blind_m = st.longest_blind_m.max(st.blind_m);
            }
            None => {}
        }
    }

    /// Where the first scan is placed in the map frame (before the first scan only).
    pub fn set_initial_pose(&mut self, pose: Pose2) {
        self.backend.set_initial_pose(pose);
    }

    /// An operator's pose for the robot now ([`SlamBackend::relocalize`]):
    /// a localising back-end searches around it, any back-end starts there
    /// before its first scan, a mapping one refuses it later.
    pub fn relocalize(&mut self, pose: Pose2, sigma: (f64, f64)) -> Result<(), RelocalizeError> {
        self.backend.relocalize(pose, sigma)
    }

    pub fn stats(&self) -> PipelineStats {
        PipelineStats {
            odom_out_of_order: self.odom.out_of_order,
            ..self.stats
        }
    }

    pub fn last_update(&self) -> Option<&SlamUpdate> {
        self.last_update.as_ref()
    }

    /// The front end's corrected odometry of the last scan (its own drifting frame), if enabled.
    pub fn frontend_pose(&self) -> Option<Pose2> {
        self.frontend.as_ref().and(self.last_corrected)
    }

    pub fn backend(&self) -> &dyn SlamBackend {
        self.backend.as_ref()
    }

    pub fn pose(&self) -> Option<Pose2> {
        self.backend.pose()
    }

    pub fn map_revision(&self) -> u64 {
        self.backend.map_revision()
    }

    pub fn map(&self) -> Option<OccupancyGrid> {
        self.map_and_footprint().map(|(m, _)| m)
    }

    /// The map, and how many of its wall cells the footprint ([`Self::with_footprint`]) cleared.
    pub fn map_and_footprint(&self) -> Option<(OccupancyGrid, usize)> {
        backend::export_map(self.backend.as_ref(), self.footprint_m)
    }

    /// [`Self::map_and_footprint`] as a job for another thread, when the
    /// back-end's map is costly to draw ([`SlamBackend::map_job`]): the
    /// scans need not wait while it is drawn. `None`: draw it in place.
    pub fn map_and_footprint_job(&self) -> Option<backend::ExportJob> {
        backend::export_map_job(self.backend.as_ref(), self.footprint_m)
    }

    /// Cells (width, height) the map has at least
    /// ([`backend::map_cells_at_least`]), known without drawing it.
    pub fn map_cells_at_least(&self) -> (usize, usize) {
        backend::map_cells_at_least(self.backend.as_ref(), self.resolution_m)
    }

    /// Marks free, in every map exported, the cells within `radius_m` of the
    /// trajectory (the robot's body; `[slam] clear_footprint`); 0 turns it off.
    /// For the vote give it to the members instead ([`BackendOptions::footprint_m`],
    /// see [`vote_aware_footprint`]).
    pub fn with_footprint(mut self, radius_m: f64) -> Self {
        self.footprint_m = radius_m.max(0.0);
        self
    }

    /// The ring's side transducers, whose readings hold the front end's
    /// heading along a wall while the laser is blind ([`crate::side_wall`]).
    pub fn with_side_sonars(mut self, sonars: SideSonars) -> Self {
        self.side_sonars = sonars;
        self
    }

    /// The fusion's `[fusion.v2] contradiction_margin_m`: how much nearer
    /// than its section's sonar echo a laser range is one the sonar
    /// contradicts, for the maps' smoke-return check (0.3 m unless set).
    pub fn with_contradiction_margin(mut self, margin_m: f64) -> Self {
        if margin_m.is_finite() && margin_m >= 0.0 {
            self.contradiction_margin_m = margin_m as f32;
        }
        self
    }

    /// What the pipeline takes from the robot's profile beyond `[slam]`:
    /// its ring's side transducers and the fusion's contradiction margin.
    pub fn with_robot(self, profile: &smokenav_platform_config::RobotConfig) -> Self {
        self.with_side_sonars(crate::projected::SensorRig::from_config(profile).side_sonars())
            .with_contradiction_margin(profile.fusion.v2.contradiction_margin_m)
    }

    /// [`SlamBackend::confidence_map`]: the combined fuzzy map, fuzzy back-end only.
    pub fn confidence_map(&self) -> Option<OccupancyGrid> {
        self.backend.confidence_map()
    }

    pub fn trajectory(&self) -> Vec<StampedPose> {
        self.backend.trajectory()
    }
}

/// The footprint the pipeline itself clears around `cfg`'s back-end: none
/// for the vote, whose members clear their own maps before they vote (given
/// [`BackendOptions::footprint_m`]) and whose trajectory is a round trip to a
/// member's thread, which an export on the scan path must not wait for.
pub fn vote_aware_footprint(cfg: &SlamSection, footprint_m: f64) -> f64 {
    if cfg.backend == smokenav_platform_config::SlamBackendKind::Vote {
        0.0
    } else {
        footprint_m
    }
}

#[cfg(test)]
mod tests;
