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
//!   With two left (one out), every cell they differ on would be a wall,
//!   the union of both maps: the vote (`super`) then lets the first of them
//!   decide, as `majority-reference` does.
//! - `majority-reference` ([`majority_or`]): the paper's majority, but
//!   without one the cell takes the reference member's state (the next
//!   member's in order while the reference is out). Three members rarely draw a wall in the
//!   same cell: on the dense-smoke trial 146 cells were occupied in all
//!   three maps. Where they split, the paper's rule draws a wall on every
//!   disagreement, so the fused map holds each member's copy of a wall a
//!   cell or two apart. The reference holds the frame and draws one of
//!   those copies.
//! - `corroborated` ([`corroborated_doubt`]): the paper's majority, but
//!   without one a wall only where another member has a wall within a cell
//!   of it, the border the paper's rationale speaks of; else free if any
//!   member saw free space, else unknown. One member's lone wall (a smoke
//!   phantom, a sonar arc, a wall drawn off by a pose error) is not drawn;
//!   two members' copies of a wall a cell apart still are. Measured on five
//!   dense-smoke recordings and three clean twins at three seeds each (the
//!   README's vote table): at or below its best member in 12 of 15 smoke
//!   runs and 7 of 9 clean ones, the paper's majority in 7 and 7.
//! - `corroborated-reference` ([`reference_corroborated_doubt`]): the
//!   paper's majority, but without one the reference's state, except that a
//!   reference wall no other member has a wall within a cell of is not drawn.
//!   Where `corroborated` lost to the graph (the reference) on the `./demo`
//!   recordings, it had drawn the other members' copy of a wall where they
//!   split three ways; `majority-reference` keeps the reference's geometry
//!   there but also its lone walls. Same maps as above plus three later
//!   recordings, seeds 1, 2, 42: at or below its best member in 26 of 33
//!   smoke runs (`corroborated` 24), 15 of 15 on the five `./demo`
//!   recordings (11), 7 of 9 clean ones (6).
//! - [`weighted`]: each member's vote counts with its certainty for the cell
//!   (how far its occupancy lies past the threshold, 0.5–1; an unknown
//!   vote counts 0.5) times the member's weight (from its pose covariance),
//!   and an occupied or free vote is discounted by up to half where the
//!   region was mapped mostly from sonar beams (wide cones in smoke:
//!   weaker evidence than the laser's). The heaviest state wins; a tie
//!   goes to occupied, as in the paper.
//! - [`Consensus`]: the paper's majority, but over walls within a tolerance
//!   and on one member's geometry. Members that map the same wall a cell or
//!   two apart (their poses differ by a few centimetres where alignment is
//!   rigid and the maps are not) make the cell-exact majority draw both
//!   copies: a split (occupied / free / unknown) is occupied. Here a member
//!   agrees with a wall when it has a wall within `radius` cells, the walls
//!   are those of the *base* member (the one whose walls the others confirm
//!   most, counted in walls that stand: a share would favour a member that
//!   maps little), a base wall the members who looked there mostly see as free is
//!   dropped (ties stay occupied, as in the paper), and where the base has
//!   no wall nearby a member's wall is added if a majority has one within
//!   the radius.

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
    majority_or(votes, CellState::Occupied)
}

/// The state more than half the members give, `fallback` without such a majority.
#[inline]
pub fn majority_or(votes: &[CellState], fallback: CellState) -> CellState {
    strict_majority(votes).unwrap_or(fallback)
}

/// The state more than half the members give, if any.
#[inline]
pub fn strict_majority(votes: &[CellState]) -> Option<CellState> {
    let mut n = [0usize; 3];
    for v in votes {
        n[v.index()] += 1;
    }
    let total = votes.len();
    [CellState::Occupied, CellState::Free, CellState::Unknown]
        .into_iter()
        .find(|s| 2 * n[s.index()] > total)
}

/// The `corroborated` rule's state of cell `i` where the members have no
/// majority: occupied if a member that sees a wall there has another
/// member's wall within one cell (`states` member-major, `n = width·height`
/// cells per member), else free if any member sees free space, else unknown.
pub fn corroborated_doubt(
    states: &[CellState],
    members: usize,
    width: usize,
    height: usize,
    i: usize,
) -> CellState {
    let n = width * height;
    let wall_near = |k: usize| wall_within_a_cell(states, k, width, height, i);
    if (0..members).any(|k| {
        states[k * n + i] == CellState::Occupied && (0..members).any(|j| j != k && wall_near(j))
    }) {
        CellState::Occupied
    } else {
        free_if_seen(states, members, n, i)
    }
}

/// The `corroborated-reference` rule's state of cell `i` where the members
/// have no majority: the reference's (member 0's) state, but a reference
/// wall without another member's wall within a cell is not drawn (free if
/// any member sees free space there, else unknown). Arguments as in
/// [`corroborated_doubt`].
pub fn reference_corroborated_doubt(
    states: &[CellState],
    members: usize,
    width: usize,
    height: usize,
    i: usize,
) -> CellState {
    let reference = states[i];
    if reference != CellState::Occupied
        || (1..members).any(|k| wall_within_a_cell(states, k, width, height, i))
    {
        reference
    } else {
        free_if_seen(states, members, width * height, i)
    }
}

/// Member `k` has a wall in cell `i` or one of its eight neighbours.
#[inline]
fn wall_within_a_cell(
    states: &[CellState],
    k: usize,
    width: usize,
    height: usize,
    i: usize,
) -> bool {
    let n = width * height;
    let (x, y) = (i % width, i / width);
    (y.saturating_sub(1)..(y + 2).min(height)).any(|yy| {
        (x.saturating_sub(1)..(x + 2).min(width))
            .any(|xx| states[k * n + yy * width + xx] == CellState::Occupied)
    })
}

/// Free if any member sees free space in cell `i`, else unknown.
#[inline]
fn free_if_seen(states: &[CellState], members: usize, n: usize, i: usize) -> CellState {
    if (0..members).any(|k| states[k * n + i] == CellState::Free) {
        CellState::Free
    } else {
        CellState::Unknown
    }
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

/// Scratch and result of the consensus rule, kept between updates.
#[derive(Debug, Default)]
pub struct Consensus {
    /// Per member, per cell: a wall within the radius.
    near: Vec<bool>,
    /// One row or column of running counts.
    line: Vec<u32>,
    /// Per member: its walls that would stand less those that would go.
    standing: Vec<i64>,
    /// The member whose walls the fused map keeps.
    pub base: Option<usize>,
}

impl Consensus {
    /// Votes `states` (member-major: member `k`'s cell `i` at `k·n + i`, `n =
    /// width·height`) into `out` (`n` cells).
    pub fn vote(
        &mut self,
        states: &[CellState],
        members: usize,
        width: usize,
        height: usize,
        radius: usize,
        out: &mut [CellState],
    ) {
        let n = width * height;
        debug_assert_eq!(states.len(), members * n);
        debug_assert_eq!(out.len(), n);
        self.near.clear();
        self.near.resize(members * n, false);
        for k in 0..members {
            dilate(
                &states[k * n..(k + 1) * n],
                &mut self.near[k * n..(k + 1) * n],
                width,
                height,
                radius,
                &mut self.line,
            );
        }
        // The base: the member with the most walls that would stand, less
        // those that would go (a wall stands when the members with an opinion
        // there confirm it at least as often as they see free space). A share
        // would favour a member that maps little; a count does not.
        self.standing.clear();
        for b in 0..members {
            let mut standing = 0i64;
            for i in 0..n {
                if states[b * n + i] != CellState::Occupied {
                    continue;
                }
                let (mut y, mut a) = (0u64, 0u64);
                for k in (0..members).filter(|&k| k != b) {
                    if self.near[k * n + i] {
                        y += 1;
                        a += 1;
                    } else if states[k * n + i] == CellState::Free {
                        a += 1;
                    }
                }
                standing += if 2 * y >= a { 1 } else { -1 };
            }
            self.standing.push(standing);
        }
        let base =
            (0..members).max_by(|&a, &b| self.standing[a].cmp(&self.standing[b]).then(b.cmp(&a)));
        self.base = base;
        let Some(b) = base else {
            out.fill(CellState::Unknown);
            return;
        };
        for (i, o) in out.iter_mut().enumerate() {
            let (mut near, mut free_there, mut walls, mut free) = (0usize, 0usize, 0usize, 0usize);
            for k in 0..members {
                let s = states[k * n + i];
                if self.near[k * n + i] {
                    near += 1;
                } else if s == CellState::Free {
                    free_there += 1;
                }
                walls += usize::from(s == CellState::Occupied);
                free += usize::from(s == CellState::Free);
            }
            let own = states[b * n + i];
            *o = if own == CellState::Occupied {
                if near >= free_there {
                    CellState::Occupied
                } else {
                    CellState::Free
                }
            } else if !self.near[b * n + i] && walls > 0 && 2 * near > members {
                CellState::Occupied
            } else if 2 * free > members || own == CellState::Free {
                CellState::Free
            } else {
                CellState::Unknown
            };
        }
    }
}

/// `near[i]`: a wall of `states` within `radius` cells of `i` (a square
/// window), by running counts along rows, then along columns.
fn dilate(
    states: &[CellState],
    near: &mut [bool],
    width: usize,
    height: usize,
    radius: usize,
    line: &mut Vec<u32>,
) {
    // Rows: near[i] ← a wall within the radius along the row.
    line.clear();
    line.resize(width + 1, 0);
    for y in 0..height {
        let row = &states[y * width..(y + 1) * width];
        for x in 0..width {
            line[x + 1] = line[x] + u32::from(row[x] == CellState::Occupied);
        }
        for x in 0..width {
            let (lo, hi) = (x.saturating_sub(radius), (x + radius + 1).min(width));
            near[y * width + x] = line[hi] > line[lo];
        }
    }
    // Columns, over the row result.
    line.clear();
    line.resize(height + 1, 0);
    for x in 0..width {
        // The whole column's counts first, so the column can be overwritten.
        for y in 0..height {
            line[y + 1] = line[y] + u32::from(near[y * width + x]);
        }
        for y in 0..height {
            let (lo, hi) = (y.saturating_sub(radius), (y + radius + 1).min(height));
            near[y * width + x] = line[hi] > line[lo];
        }
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
    fn corroborated_doubt_needs_another_members_wall_within_a_cell() {
        // Four members on a 3 × 3 grid, the centre cell (4) in doubt.
        let grid = |cells: [[CellState; 9]; 4]| cells.concat();
        let mut m = [[U; 9]; 4];
        m[0][4] = O;
        m[1][4] = F;
        // Member 0's wall alone: the free floor member 1 saw.
        assert_eq!(corroborated_doubt(&grid(m), 4, 3, 3, 4), F);
        // Member 2 has a wall in the corner cell, diagonally beside it.
        m[2][8] = O;
        assert_eq!(corroborated_doubt(&grid(m), 4, 3, 3, 4), O);
        // No one saw a wall or free space: unknown.
        let u = [[U; 9]; 4];
        assert_eq!(corroborated_doubt(&grid(u), 4, 3, 3, 4), U);
        // Walls beside it, but no one's in the cell itself: not a wall here.
        let mut f = [[U; 9]; 4];
        f[0][4] = F;
        f[1][3] = O;
        f[2][5] = O;
        assert_eq!(corroborated_doubt(&grid(f), 4, 3, 3, 4), F);
    }

    #[test]
    fn without_a_majority_the_fallback_decides() {
        assert_eq!(majority_or(&[O, F, U], F), F);
        assert_eq!(majority_or(&[U, F, O], U), U);
        assert_eq!(majority_or(&[F, F, O], U), F, "a majority still wins");
        assert_eq!(majority_or(&[F, U], O), O);
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

    /// Member-major states from rows of `O` (occupied), `.` (free), `?` (unknown).
    fn layers(members: &[&[&str]]) -> (Vec<CellState>, usize, usize) {
        let (h, w) = (members[0].len(), members[0][0].len());
        let mut out = Vec::new();
        for m in members {
            for row in m.iter().rev() {
                out.extend(row.chars().map(|c| match c {
                    'O' => O,
                    '.' => F,
                    _ => U,
                }));
            }
        }
        (out, w, h)
    }

    fn draw(states: &[CellState], w: usize) -> Vec<String> {
        let mut rows: Vec<String> = states
            .chunks(w)
            .map(|r| {
                r.iter()
                    .map(|s| match s {
                        O => 'O',
                        F => '.',
                        U => '?',
                    })
                    .collect()
            })
            .collect();
        rows.reverse();
        rows
    }

    fn consensus_of(members: &[&[&str]], radius: usize) -> (Vec<String>, Option<usize>) {
        let (st, w, h) = layers(members);
        let mut c = Consensus::default();
        let mut out = vec![U; w * h];
        c.vote(&st, members.len(), w, h, radius, &mut out);
        (draw(&out, w), c.base)
    }

    #[test]
    fn a_wall_two_members_draw_a_cell_apart_is_one_wall() {
        // Members 0 and 2 put the wall in row 2, member 1 one row up.
        let a: &[&str] = &["......", "......", "OOOOOO", "......"];
        let b: &[&str] = &["......", "OOOOOO", "......", "......"];
        let c: &[&str] = &["......", "......", "OOOOOO", "......"];
        let (got, base) = consensus_of(&[a, b, c], 1);
        assert_eq!(got, ["......", "......", "OOOOOO", "......"]);
        assert_eq!(base, Some(0), "ties go to the first of the best-confirmed");
        // The cell-exact majority keeps the offset copy too: each of its cells
        // is a three-way split or (row 1: O, F, F) free — here row 1 is free,
        // but with the third member unknown there both copies are walls.
        let c2: &[&str] = &["......", "??????", "OOOOOO", "......"];
        let (st, w, h) = layers(&[a, b, c2]);
        let n = w * h;
        let maj: Vec<CellState> = (0..n)
            .map(|i| majority(&[st[i], st[n + i], st[2 * n + i]]))
            .collect();
        assert_eq!(draw(&maj, w), ["......", "OOOOOO", "OOOOOO", "......"]);
        let (got, _) = consensus_of(&[a, b, c2], 1);
        assert_eq!(got, ["......", "......", "OOOOOO", "......"]);
    }

    #[test]
    fn a_wall_only_one_member_saw_stays_unless_the_others_saw_free_there() {
        let a: &[&str] = &["..O...", "......", "OOOOOO"];
        let unseen: &[&str] = &["??????", "......", "OOOOOO"];
        let seen_free: &[&str] = &["......", "......", "OOOOOO"];
        // Nobody else looked there: nothing against it, the wall stays.
        let (got, base) = consensus_of(&[a, unseen, unseen], 1);
        assert_eq!((got[0].as_str(), base), ("..O...", Some(0)));
        // Another member looked and saw free: that member's walls are all
        // confirmed, a's are not, so the map is its: the lone wall goes.
        let (got, base) = consensus_of(&[a, seen_free, unseen], 1);
        assert_eq!((got[0].as_str(), base), ("......", Some(1)));
        let (got, _) = consensus_of(&[a, seen_free, seen_free], 1);
        assert_eq!(got[0], "......");
    }

    #[test]
    fn a_wall_the_others_agree_on_and_the_base_missed_is_added() {
        // Member 0 has the most standing walls (its wall two cells thick) but
        // missed the post the other two agree on.
        let a: &[&str] = &["......", "......", "OOOOOO", "OOOOOO"];
        let b: &[&str] = &["...O..", "......", "......", "OOOOOO"];
        let c: &[&str] = &["...O..", "......", "......", "OOOOO?"];
        let (got, base) = consensus_of(&[a, b, c], 1);
        assert_eq!(base, Some(0));
        assert_eq!(got, ["...O..", "......", "OOOOOO", "OOOOOO"]);
    }

    #[test]
    fn the_tolerance_is_a_square_window_of_the_radius() {
        let (st, w, h) = layers(&[&["......", "......", "..O...", "......", "......"]]);
        let mut near = vec![false; w * h];
        let mut line = Vec::new();
        dilate(&st, &mut near, w, h, 1, &mut line);
        let drawn: Vec<String> = near
            .chunks(w)
            .rev()
            .map(|r| r.iter().map(|&b| if b { 'x' } else { '.' }).collect())
            .collect();
        assert_eq!(drawn, ["......", ".xxx..", ".xxx..", ".xxx..", "......"]);
        dilate(&st, &mut near, w, h, 0, &mut line);
        assert_eq!(near.iter().filter(|&&b| b).count(), 1);
    }
}
