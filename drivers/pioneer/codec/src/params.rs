//! Conversion factors per robot subclass (ARIA's `params/<subclass>.p` and
//! `ArRobotTypes.cpp`). The subclass comes from the SYNC2 reply; a missing
//! entry gives silently wrong odometry (allenh1/p2os PR #36), so an unknown
//! subclass is an error unless the user names one in the robot profile.

use serde::Serialize;
use thiserror::Error;

/// ARIA's AngleConvFactor for every ARCOS base: 2π/4096 rad per unit.
pub const ANGLE_CONV: f64 = 0.001534;

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RobotParams {
    pub subclass: &'static str,
    /// rad per THPOS unit.
    pub angle_conv: f64,
    /// mm per XPOS/YPOS unit.
    pub dist_conv: f64,
    /// mm/s per wheel-velocity unit.
    pub vel_conv: f64,
    /// mm per sonar-range unit.
    pub range_conv: f64,
    /// rad/s per unit of (right − left)/2 wheel velocity.
    pub diff_conv: f64,
    /// mm/s per VEL2 unit.
    pub vel2_divisor: f64,
    pub radius_mm: f64,
    pub width_mm: f64,
    pub max_vel_mm_s: f64,
    pub max_rot_vel_deg_s: f64,
    pub sonar_count: u8,
}

// One row of ARIA's table; positional to keep the table readable.
#[allow(clippy::too_many_arguments)]
const fn pioneer(
    subclass: &'static str,
    dist_conv: f64,
    range_conv: f64,
    diff_conv: f64,
    radius_mm: f64,
    width_mm: f64,
    max_vel_mm_s: f64,
    max_rot_vel_deg_s: f64,
    sonar_count: u8,
) -> RobotParams {
    RobotParams {
        subclass,
        angle_conv: ANGLE_CONV,
        dist_conv,
        vel_conv: 1.0,
        range_conv,
        diff_conv,
        vel2_divisor: 20.0,
        radius_mm,
        width_mm,
        max_vel_mm_s,
        max_rot_vel_deg_s,
        sonar_count,
    }
}

/// Every subclass we have verified numbers for.
pub const KNOWN_ROBOTS: &[RobotParams] = &[
    pioneer("p3dx", 0.485, 1.0, 0.0056, 250.0, 425.0, 2200.0, 500.0, 16),
    pioneer("p3dx-sh", 1.0, 1.0, 0.0056, 250.0, 425.0, 2200.0, 500.0, 16),
    pioneer(
        "p3dx-sh-lms1xx",
        1.0,
        1.0,
        0.0056,
        250.0,
        425.0,
        2200.0,
        500.0,
        16,
    ),
    pioneer(
        "p3dx-sh-lms500",
        1.0,
        1.0,
        0.0056,
        250.0,
        425.0,
        2200.0,
        500.0,
        16,
    ),
    pioneer("p3at", 0.465, 1.0, 0.0034, 500.0, 505.0, 1200.0, 300.0, 16),
    pioneer("p3at-sh", 1.0, 1.0, 0.0034, 500.0, 505.0, 1200.0, 300.0, 16),
    pioneer(
        "p3at-sh-lms1xx",
        1.0,
        1.0,
        0.0034,
        500.0,
        505.0,
        1200.0,
        300.0,
        16,
    ),
    pioneer(
        "p3at-sh-lms500",
        1.0,
        1.0,
        0.0034,
        500.0,
        505.0,
        1200.0,
        300.0,
        16,
    ),
    pioneer(
        "p3atiw-sh",
        1.0,
        1.0,
        0.0034,
        500.0,
        490.0,
        1200.0,
        300.0,
        16,
    ),
    pioneer("p2dx", 0.84, 0.268, 0.0056, 250.0, 425.0, 2200.0, 500.0, 16),
    pioneer(
        "p2de", 0.969, 0.268, 0.0056, 250.0, 425.0, 2200.0, 500.0, 16,
    ),
    pioneer("p2at8", 1.32, 1.0, 0.0034, 500.0, 505.0, 1200.0, 300.0, 16),
    pioneer(
        "patrolbot-sh",
        1.0,
        1.0,
        0.0056,
        250.0,
        425.0,
        2200.0,
        500.0,
        16,
    ),
    pioneer(
        "peoplebot-sh",
        1.0,
        1.0,
        0.006,
        340.0,
        425.0,
        2200.0,
        500.0,
        32,
    ),
    pioneer(
        "powerbot", 0.5813, 1.0, 0.00373, 550.0, 680.0, 2000.0, 360.0, 32,
    ),
    pioneer("amigo-sh", 1.0, 1.0, 0.011, 180.0, 279.0, 1000.0, 300.0, 8),
    RobotParams {
        vel_conv: 0.6154,
        ..pioneer("amigo", 0.5083, 1.0, 0.011, 180.0, 279.0, 1000.0, 300.0, 8)
    },
];

#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[error(
    "unknown robot subclass {subclass:?}: no conversion factors for it (known: {known}); \
     set [base.pioneer] subclass in the robot profile to one of the known ones"
)]
pub struct UnknownSubclass {
    pub subclass: String,
    pub known: String,
}

/// The parameters for `subclass` (case-insensitive, as ARIA's file lookup).
pub fn params_for(subclass: &str) -> Result<&'static RobotParams, UnknownSubclass> {
    let s = subclass.trim();
    KNOWN_ROBOTS
        .iter()
        .find(|p| p.subclass.eq_ignore_ascii_case(s))
        .ok_or_else(|| UnknownSubclass {
            subclass: subclass.to_owned(),
            known: KNOWN_ROBOTS
                .iter()
                .map(|p| p.subclass)
                .collect::<Vec<_>>()
                .join(", "),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn p3dx_and_p3dx_sh_differ_only_in_dist_conv() {
        let a = params_for("p3dx").unwrap();
        let b = params_for("P3DX-SH").unwrap();
        assert_eq!(a.dist_conv, 0.485);
        assert_eq!(b.dist_conv, 1.0);
        assert_eq!(a.angle_conv, 0.001534);
        assert_eq!(
            (a.vel_conv, a.range_conv, a.diff_conv, a.vel2_divisor),
            (1.0, 1.0, 0.0056, 20.0)
        );
        assert_eq!(
            (b.vel_conv, b.range_conv, b.diff_conv, b.vel2_divisor),
            (1.0, 1.0, 0.0056, 20.0)
        );
        assert_eq!(
            (a.radius_mm, a.width_mm, a.max_vel_mm_s, a.max_rot_vel_deg_s),
            (250.0, 425.0, 2200.0, 500.0)
        );
    }

    #[test]
    fn unknown_subclass_names_itself_and_the_known_ones() {
        // MobileSim's "box" model (rosaria #47).
        let e = params_for("box").unwrap_err();
        assert_eq!(e.subclass, "box");
        let msg = e.to_string();
        assert!(
            msg.contains("\"box\"") && msg.contains("p3dx-sh") && msg.contains("[base.pioneer]"),
            "{msg}"
        );
    }

    #[test]
    fn sh_lms1xx_variant_is_known() {
        // allenh1/p2os PR #36: `p3dx-sh-lms1xx` fell back to defaults there.
        assert_eq!(params_for("p3dx-sh-lms1xx").unwrap().dist_conv, 1.0);
    }

    #[test]
    fn amigo_has_its_own_velocity_factor() {
        assert_eq!(params_for("amigo").unwrap().vel_conv, 0.6154);
    }
}
