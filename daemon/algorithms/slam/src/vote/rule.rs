//! The per-cell vote (SLAMfusion, Sec. III-B and the second GPU kernel).
//!
//! Every member's cell is first read as one of three states with the
//! thresholds nav2 and map_server use (occupied ≥ 65, free ≤ 19, the rest and
//! −1 unknown), so the fuzzy map's 30 ("unknown level") and a faint wall
//! count as unknown.
//!
//! - [`majority`], the paper's rule: the state more than half the members
//!   give; without such a majority the cell is occupied ("when in doubt, we
//!   decide to assign the value corresponding to an obstacle"; most
//!   disagreements lie on the border of free and unknown space, where an
//!   obstacle usually is). With three members that is "at least two agree".
//! - [`weighted`]: each member's vote counts with its certainty for the cell
//!   (how far its occupancy lies past the threshold, 0.5–1; an unknown
//!   vote counts 0.5) times the member's weight (from its pose covariance),
//!   and an occupied or free vote is discounted by up to half where the
//!   region was mapped mostly from sonar beams (wide cones in smoke:
//!   weaker evidence than the laser's). The heaviest state wins; a tie
//!   goes to occupied, as in the paper.

use smokenav_platform_map::{FREE, OCCUPIED, UNKNOWN};

/// One member's reading of one cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CellState {
    Free,
    Occupied,
    Unknown,
}

impl CellState {
    /// The state of an occupancy value (0..100, −1 unknown).
    #[inline]
    pub fn of(v: i8) -> Self {
        match v {
            v if !(0..=100).contains(&v) => CellState::Unknown,
            v if v >= 65 => CellState::Occupied,
            v if v <= 19 => CellState::Free,
            _ => CellState::Unknown,
        }
    }

    /// The value a published trinary map carries.
    #[inline]
    pub fn value(self) -> i8 {
        match self {
            CellState::Free => FREE,
            CellState::Occupied => OCCUPIED,
            CellState::Unknown => UNKNOWN,
        }
    }

    fn index(self) -> usize {
        match self {
            CellState::Occupied => 0,
            CellState::Free => 1,
            CellState::Unknown => 2,
        }
    }
}

/// How sure a member is of its reading of `v` (0.5 at the threshold, 1 at 0 or 100).
#[inline]
pub fn certainty(v: i8) -> f64 {
    match CellState::of(v) {
        CellState::Occupied => 0.5 + 0.5 * f64::from(v.min(100) - 65) / 35.0,
        CellState::Free => 0.5 + 0.5 * f64::from(19 - v.max(0)) / 19.0,
        CellState::Unknown => 0.5,
    }
}

/// The paper's rule over the members' states.
#[inline]
pub fn majority(votes: &[CellState]) -> CellState {
    let mut n = [0usize; 3];
    for v in votes {
        n[v.index()] += 1;
    }
    let total = votes.len();
    for s in [CellState::Occupied, CellState::Free, CellState::Unknown] {
        if 2 * n[s.index()] > total {
            return s;
        }
    }
    CellState::Occupied
}

/// One weighted vote: the member's value for the cell and its weight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WeightedVote {
    pub value: i8,
    pub weight: f64,
}

/// The weighted rule; `sonar_share` (0–1) is the share of the region's
/// evidence that came from sonar beams.
#[inline]
pub fn weighted(votes: &[WeightedVote], sonar_share: f64) -> CellState {
    let discount = 1.0 - 0.5 * sonar_share.clamp(0.0, 1.0);
    let mut score = [0.0f64; 3];
    for v in votes {
        let s = CellState::of(v.value);
        let mut w = v.weight * certainty(v.value);
        if s != CellState::Unknown {
            w *= discount;
        }
        score[s.index()] += w;
    }
    let (occ, free, unk) = (score[0], score[1], score[2]);
    if occ >= free && occ >= unk {
        CellState::Occupied
    } else if free > unk {
        CellState::Free
    } else {
        CellState::Unknown
    }
}

#[cfg(test)]
mod tests {
    use super::CellState::{Free as F, Occupied as O, Unknown as U};
    use super::*;

    #[test]
    fn two_of_three_agreeing_set_the_cell() {
        assert_eq!(majority(&[O, O, F]), O);
        assert_eq!(majority(&[F, O, F]), F);
        assert_eq!(majority(&[U, F, U]), U);
        assert_eq!(majority(&[F, F, F]), F);
    }

    #[test]
    fn three_way_disagreement_is_occupied() {
        // The paper: "In case of disagreement … the value to be used was 1."
        assert_eq!(majority(&[O, F, U]), O);
        assert_eq!(majority(&[U, F, O]), O);
    }

    #[test]
    fn with_two_members_left_a_split_is_occupied() {
        assert_eq!(majority(&[F, U]), O);
        assert_eq!(majority(&[F, F]), F);
        assert_eq!(majority(&[U]), U);
    }

    #[test]
    fn thresholds_are_map_servers() {
        assert_eq!(CellState::of(-1), U);
        assert_eq!(CellState::of(30), U, "the fuzzy map's unknown level");
        assert_eq!(CellState::of(19), F);
        assert_eq!(CellState::of(20), U);
        assert_eq!(CellState::of(64), U);
        assert_eq!(CellState::of(65), O);
        assert_eq!(CellState::of(100), O);
    }

    /// A 3 × 3 hand-made patch from three members, voted cell by cell.
    #[test]
    fn hand_made_grids_vote_cell_by_cell() {
        #[rustfmt::skip]
        let a: [i8; 9] = [100, 100, -1,
                            0,   0, -1,
                            0, 100,  0];
        #[rustfmt::skip]
        let b: [i8; 9] = [100,   0,  0,
                            0,  -1, -1,
                          100,  30,  0];
        #[rustfmt::skip]
        let c: [i8; 9] = [ 0,    0, 100,
                            0, 100, -1,
                           -1, 100,  5];
        #[rustfmt::skip]
        let want: [i8; 9] = [100,   0, 100,
                               0, 100,  -1,
                             100, 100,   0];
        let got: Vec<i8> = (0..9)
            .map(|i| majority(&[a[i], b[i], c[i]].map(CellState::of)).value())
            .collect();
        assert_eq!(got, want);
    }

    #[test]
    fn a_confident_member_outweighs_two_hesitant_ones() {
        let v = |value, weight| WeightedVote { value, weight };
        // Two members barely free (19), one sure of a wall (100): by majority free …
        assert_eq!(majority(&[19, 19, 100].map(CellState::of)), CellState::Free);
        // … weighted: 2 × 0.5 = 1.0 for free against 1.0 for occupied: a tie, occupied.
        assert_eq!(weighted(&[v(19, 1.0), v(19, 1.0), v(100, 1.0)], 0.0), O);
        // A member with a poor pose (weight 0.3) does not carry the wall.
        assert_eq!(weighted(&[v(19, 1.0), v(19, 1.0), v(100, 0.3)], 0.0), F);
        // Sure free against a faint wall: free.
        assert_eq!(weighted(&[v(0, 1.0), v(0, 1.0), v(70, 1.0)], 0.0), F);
    }

    #[test]
    fn sonar_mapped_regions_lean_to_unknown() {
        let v = |value| WeightedVote { value, weight: 1.0 };
        // One member says occupied (0.57), two unknown (0.5 each): occupied wins
        // where the laser mapped, unknown where sonar did.
        assert_eq!(weighted(&[v(100), v(-1)], 0.0), O);
        // A faint wall (0.57) against two unknowns (1.0): unknown.
        assert_eq!(weighted(&[v(70), v(-1), v(-1)], 0.0), U);
        assert_eq!(weighted(&[v(100), v(0), v(-1)], 0.0), O);
        assert_eq!(weighted(&[v(70), v(-1)], 1.0), U);
        assert_eq!(weighted(&[v(70), v(-1)], 0.0), O);
    }
}
