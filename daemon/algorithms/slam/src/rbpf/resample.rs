//! Systematic (low-variance) resampling: one uniform draw places `n` equally
//! spaced pointers over the cumulative weights, so a particle of weight `w`
//! is copied `⌊n·w⌋` or `⌈n·w⌉` times.

/// Indices of the particles to copy, in order, for normalised `weights`;
/// `u` is a uniform draw in [0, 1).
pub fn systematic(weights: &[f64], u: f64) -> Systematic<'_> {
    let n = weights.len();
    let step = 1.0 / n as f64;
    Systematic {
        weights,
        step,
        pointer: u * step,
        cumulative: weights.first().copied().unwrap_or(0.0),
        index: 0,
        left: n,
    }
}

#[derive(Debug, Clone)]
pub struct Systematic<'w> {
    weights: &'w [f64],
    step: f64,
    pointer: f64,
    cumulative: f64,
    index: usize,
    left: usize,
}

impl Iterator for Systematic<'_> {
    type Item = usize;

    fn next(&mut self) -> Option<usize> {
        if self.left == 0 {
            return None;
        }
        self.left -= 1;
        while self.pointer > self.cumulative && self.index + 1 < self.weights.len() {
            self.index += 1;
            self.cumulative += self.weights[self.index];
        }
        self.pointer += self.step;
        Some(self.index)
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        (self.left, Some(self.left))
    }
}

impl ExactSizeIterator for Systematic<'_> {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn copies_follow_the_weights() {
        let picks: Vec<usize> = systematic(&[0.1, 0.6, 0.0, 0.3], 0.5).collect();
        assert_eq!(picks, [1, 1, 1, 3]);
        assert_eq!(systematic(&[1.0], 0.99).collect::<Vec<_>>(), [0]);
        assert_eq!(systematic(&[], 0.3).count(), 0);
    }
}
