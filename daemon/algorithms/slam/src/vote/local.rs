//! Block-by-block re-alignment of one member's map after the rigid one.
//!
//! The rigid alignment ([`super::align`]) finds the one transform that lays
//! a member's walls best on the reference's. Two back-ends that corrected
//! different loops, or drifted differently through a blind stretch in
//! smoke, draw the same wall a cell or two apart in one region and on top of
//! each other in another: no single transform fixes both. The per-cell vote
//! then splits on every such wall (the paper's rule draws both copies; the
//! `corroborated` rule drops both when they are two cells apart).
//!
//! Here a member's map, already resampled onto the reference's grid through
//! its rigid transform, is cut into square blocks; each block is resampled
//! again with the integer shift (in the member's cells, within
//! `±shift`) that puts the most of its walls on the reference's walls, if
//! that shift beats no shift by [`MIN_GAIN`]. A block with fewer than
//! [`MIN_WALLS`] reference walls is left alone: too little to align on.
//! Only a member whose rigid residual says its map does not fit as one piece
//! is re-aligned (the caller's gate), so maps that agree already are not
//! nudged by a cell of noise.

use super::rule::CellState;
use smokenav_platform_map::OccupancyGrid;

/// A shift is taken only when it lays this share more of the block's
/// member walls on reference walls than no shift does.
pub const MIN_GAIN: f64 = 0.1;
/// Reference walls a block needs to be re-aligned.
pub const MIN_WALLS: u32 = 20;

/// The member's value at reference cell `(x, y)` through the affine `a`
/// (reference cell → member cell), shifted by `(dx, dy)` member cells;
/// −1 (unknown) outside the member's map. The one lookup of a member's
/// cell: the vote's resampling uses it unshifted.
#[inline]
pub(super) fn sample(g: &OccupancyGrid, a: &[f64; 6], x: f64, y: f64, dx: i64, dy: i64) -> i8 {
    let mx = (a[0] * x + a[1] * y + a[2]).floor();
    let my = (a[3] * x + a[4] * y + a[5]).floor();
    if !(mx.is_finite() && my.is_finite()) {
        return -1;
    }
    let (ix, iy) = (mx as i64 + dx, my as i64 + dy);
    if ix < 0 || iy < 0 || ix >= g.width as i64 || iy >= g.height as i64 {
        return -1;
    }
    g.cells[iy as usize * g.width + ix as usize]
}

/// Re-aligns `layer` (the member's cells on the `w × h` reference grid,
/// resampled through `a`) block by block against `reference` (the reference
/// member's cells on the same grid). `block` is the block side in cells,
/// `shift` the largest shift tried. Returns the blocks that were shifted.
pub fn realign_blocks(
    layer: &mut [i8],
    reference: &[i8],
    (w, h): (usize, usize),
    g: &OccupancyGrid,
    a: &[f64; 6],
    block: usize,
    shift: i64,
) -> u32 {
    let n = w * h;
    if block == 0 || shift <= 0 || layer.len() < n || reference.len() < n {
        return 0;
    }
    let wall = |v: i8| CellState::of(v) == CellState::Occupied;
    let mut shifted = 0;
    for by in (0..h).step_by(block) {
        for bx in (0..w).step_by(block) {
            let (ye, xe) = ((by + block).min(h), (bx + block).min(w));
            let ref_walls: u32 = (by..ye)
                .map(|y| (bx..xe).filter(|&x| wall(reference[y * w + x])).count() as u32)
                .sum();
            if ref_walls < MIN_WALLS {
                continue;
            }
            let score = |dx: i64, dy: i64| -> u32 {
                let mut s = 0;
                for y in by..ye {
                    for x in bx..xe {
                        if wall(reference[y * w + x])
                            && wall(sample(g, a, x as f64, y as f64, dx, dy))
                        {
                            s += 1;
                        }
                    }
                }
                s
            };
            let at_zero = score(0, 0);
            // The first best in a fixed order: reproducible.
            let mut best = (at_zero, 0, 0);
            for dy in -shift..=shift {
                for dx in -shift..=shift {
                    if (dx, dy) == (0, 0) {
                        continue;
                    }
                    let s = score(dx, dy);
                    if s > best.0 {
                        best = (s, dx, dy);
                    }
                }
            }
            if (best.1, best.2) == (0, 0)
                || f64::from(best.0) <= f64::from(at_zero) * (1.0 + MIN_GAIN)
            {
                continue;
            }
            for y in by..ye {
                for x in bx..xe {
                    layer[y * w + x] = sample(g, a, x as f64, y as f64, best.1, best.2);
                }
            }
            shifted += 1;
        }
    }
    shifted
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_platform_map::{FREE, OCCUPIED};

    /// A `w × h` map, free, with walls at the given cells.
    fn map(w: usize, h: usize, walls: &[(usize, usize)]) -> OccupancyGrid {
        let mut g = OccupancyGrid::new(w, h, 0.05, [0.0, 0.0, 0.0]);
        g.cells.iter_mut().for_each(|c| *c = FREE);
        for &(x, y) in walls {
            g.cells[y * w + x] = OCCUPIED;
        }
        g
    }

    const IDENTITY: [f64; 6] = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0];

    fn resample(g: &OccupancyGrid) -> Vec<i8> {
        let mut out = vec![0; g.width * g.height];
        for y in 0..g.height {
            for x in 0..g.width {
                out[y * g.width + x] = sample(g, &IDENTITY, x as f64, y as f64, 0, 0);
            }
        }
        out
    }

    #[test]
    fn a_wall_one_cell_off_in_one_block_is_laid_on_the_reference_and_the_other_block_stays() {
        // 80 × 40 cells, two 40-cell blocks. The reference has a vertical wall
        // at x = 10 (left block) and x = 60 (right block). The member drew
        // the left one a cell to the right (x = 11) and the right one where
        // the reference has it: no rigid shift fits both.
        let (w, h) = (80, 40);
        let rwalls: Vec<_> = (0..h).flat_map(|y| [(10, y), (60, y)]).collect();
        let mwalls: Vec<_> = (0..h).flat_map(|y| [(11, y), (60, y)]).collect();
        let reference = map(w, h, &rwalls);
        let member = map(w, h, &mwalls);
        let r = resample(&reference);
        let mut layer = resample(&member);
        let shifted = realign_blocks(&mut layer, &r, (w, h), &member, &IDENTITY, 40, 1);
        assert_eq!(shifted, 1, "only the left block moves");
        for y in 0..h {
            assert_eq!(
                layer[y * w + 10],
                OCCUPIED,
                "left wall laid on the reference's"
            );
            assert_eq!(layer[y * w + 11], FREE);
            assert_eq!(layer[y * w + 60], OCCUPIED, "right wall where it was");
        }
    }

    #[test]
    fn a_block_with_few_reference_walls_or_no_gain_is_left_alone() {
        let (w, h) = (40, 40);
        // Blocks re-aligned, and whether the member's layer stayed as it was.
        let run = |reference: &OccupancyGrid, member: &OccupancyGrid, block: usize| {
            let mut layer = resample(member);
            let n = realign_blocks(
                &mut layer,
                &resample(reference),
                (w, h),
                member,
                &IDENTITY,
                block,
                1,
            );
            (n, layer == resample(member))
        };
        // Ten reference walls only (below MIN_WALLS): nothing moves.
        let few = map(w, h, &(0..10).map(|y| (5, y)).collect::<Vec<_>>());
        let member = map(w, h, &(0..10).map(|y| (6, y)).collect::<Vec<_>>());
        assert_eq!(run(&few, &member, 40), (0, true));
        // Walls on top of each other already: no shift beats none.
        let same = map(w, h, &(0..h).map(|y| (5, y)).collect::<Vec<_>>());
        assert_eq!(run(&same, &same, 40), (0, true));
        // Block 0: off.
        assert_eq!(run(&few, &member, 0), (0, true));
    }

    #[test]
    fn a_shift_past_the_member_map_reads_unknown() {
        let g = map(4, 4, &[(0, 0)]);
        assert_eq!(sample(&g, &IDENTITY, 0.0, 0.0, -1, 0), -1);
        assert_eq!(sample(&g, &IDENTITY, 3.0, 3.0, 1, 1), -1);
        assert_eq!(sample(&g, &IDENTITY, 1.0, 0.0, -1, 0), OCCUPIED);
        let nan = [f64::NAN, 0.0, 0.0, 0.0, 1.0, 0.0];
        assert_eq!(sample(&g, &nan, 1.0, 1.0, 0, 0), -1);
    }
}
