//! Exact nearest-neighbour queries on point sets and a Euclidean distance
//! transform, the two building blocks of the map metrics.

/// Points bucketed on a uniform grid for exact nearest-neighbour queries.
pub struct PointIndex {
    points: Vec<(f64, f64)>,
    min: (f64, f64),
    cell: f64,
    cols: usize,
    rows: usize,
    /// CSR: bucket `b` holds `items[start[b]..start[b + 1]]`.
    start: Vec<u32>,
    items: Vec<u32>,
}

impl PointIndex {
    /// `cell` should be a few times the typical point spacing. Empty input is allowed.
    pub fn new(points: Vec<(f64, f64)>, cell: f64) -> Self {
        let cell = if cell.is_finite() && cell > 0.0 {
            cell
        } else {
            1.0
        };
        let (mut lo, mut hi) = (
            (f64::INFINITY, f64::INFINITY),
            (f64::NEG_INFINITY, f64::NEG_INFINITY),
        );
        for &(x, y) in &points {
            lo = (lo.0.min(x), lo.1.min(y));
            hi = (hi.0.max(x), hi.1.max(y));
        }
        if points.is_empty() {
            lo = (0.0, 0.0);
            hi = (0.0, 0.0);
        }
        // Keep the bucket count bounded whatever the spread of the points.
        let mut cell = cell;
        while ((hi.0 - lo.0) / cell + 1.0) * ((hi.1 - lo.1) / cell + 1.0) > 4.0e6 {
            cell *= 2.0;
        }
        let cols = ((hi.0 - lo.0) / cell) as usize + 1;
        let rows = ((hi.1 - lo.1) / cell) as usize + 1;
        let bucket = |x: f64, y: f64| -> usize {
            let cx = (((x - lo.0) / cell) as usize).min(cols - 1);
            let cy = (((y - lo.1) / cell) as usize).min(rows - 1);
            cy * cols + cx
        };
        let mut counts = vec![0u32; cols * rows + 1];
        for &(x, y) in &points {
            counts[bucket(x, y) + 1] += 1;
        }
        for i in 1..counts.len() {
            counts[i] += counts[i - 1];
        }
        let start = counts.clone();
        let mut fill = counts;
        let mut items = vec![0u32; points.len()];
        for (i, &(x, y)) in points.iter().enumerate() {
            let b = bucket(x, y);
            items[fill[b] as usize] = i as u32;
            fill[b] += 1;
        }
        Self {
            points,
            min: lo,
            cell,
            cols,
            rows,
            start,
            items,
        }
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Distance from `(x, y)` to the nearest indexed point (∞ when empty).
    pub fn nearest_distance(&self, x: f64, y: f64) -> f64 {
        self.nearest_where(x, y, f64::INFINITY, |_| true)
            .unwrap_or(f64::INFINITY)
    }

    /// Distance from `(x, y)` to the nearest indexed point whose index (its
    /// place in the `points` given to [`Self::new`]) `keep` accepts, if one
    /// lies within `max_m`.
    pub fn nearest_where(
        &self,
        x: f64,
        y: f64,
        max_m: f64,
        keep: impl Fn(usize) -> bool,
    ) -> Option<f64> {
        if self.points.is_empty() {
            return None;
        }
        let fx = ((x - self.min.0) / self.cell).floor();
        let fy = ((y - self.min.1) / self.cell).floor();
        let cx = fx.clamp(-1.0, self.cols as f64) as i64;
        let cy = fy.clamp(-1.0, self.rows as f64) as i64;
        let mut best2 = if max_m.is_finite() {
            max_m * max_m
        } else {
            f64::INFINITY
        };
        let mut found = false;
        let max_ring = self.cols.max(self.rows) as i64 + 2;
        for ring in 0..=max_ring {
            // Every point in ring r is at least (r − 1)·cell away: stop once that beats the best.
            if ring >= 1 {
                let bound = (ring - 1) as f64 * self.cell;
                if bound * bound > best2 {
                    break;
                }
            }
            for by in (cy - ring)..=(cy + ring) {
                if by < 0 || by >= self.rows as i64 {
                    continue;
                }
                let on_edge_row = by == cy - ring || by == cy + ring;
                let mut bx = cx - ring;
                while bx <= cx + ring {
                    if bx >= 0 && bx < self.cols as i64 {
                        let b = by as usize * self.cols + bx as usize;
                        for &i in &self.items[self.start[b] as usize..self.start[b + 1] as usize] {
                            let (px, py) = self.points[i as usize];
                            let d2 = (px - x) * (px - x) + (py - y) * (py - y);
                            if d2 <= best2 && keep(i as usize) {
                                best2 = d2;
                                found = true;
                            }
                        }
                    }
                    // Interior rows only need the ring's two end buckets.
                    bx += if on_edge_row || ring == 0 {
                        1
                    } else {
                        2 * ring
                    };
                }
            }
        }
        found.then(|| best2.sqrt())
    }
}

/// Exact Euclidean distance transform of a binary grid (Felzenszwalb &
/// Huttenlocher, "Distance transforms of sampled functions", 2012): for every
/// cell, the distance in cells to the nearest `true` cell (∞ if there is none).
pub fn distance_transform(width: usize, height: usize, sites: &[bool]) -> Vec<f64> {
    const INF: f64 = 1e20;
    let mut f: Vec<f64> = sites.iter().map(|&s| if s { 0.0 } else { INF }).collect();
    let n = width.max(height);
    let mut buf_in = vec![0.0; n];
    let mut buf_out = vec![0.0; n];
    let mut v = vec![0usize; n];
    let mut z = vec![0.0; n + 1];
    // Columns, then rows.
    for x in 0..width {
        for y in 0..height {
            buf_in[y] = f[y * width + x];
        }
        dt_1d(&buf_in[..height], &mut buf_out[..height], &mut v, &mut z);
        for y in 0..height {
            f[y * width + x] = buf_out[y];
        }
    }
    for y in 0..height {
        buf_in[..width].copy_from_slice(&f[y * width..(y + 1) * width]);
        dt_1d(&buf_in[..width], &mut buf_out[..width], &mut v, &mut z);
        f[y * width..(y + 1) * width].copy_from_slice(&buf_out[..width]);
    }
    f.into_iter()
        .map(|d2| {
            if d2 >= INF / 2.0 {
                f64::INFINITY
            } else {
                d2.sqrt()
            }
        })
        .collect()
}

/// 1D squared-distance transform under the lower envelope of parabolas.
fn dt_1d(f: &[f64], d: &mut [f64], v: &mut [usize], z: &mut [f64]) {
    let n = f.len();
    if n == 0 {
        return;
    }
    let mut k = 0usize;
    v[0] = 0;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    let meet = |q: usize, p: usize| {
        ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * (q as f64 - p as f64))
    };
    for q in 1..n {
        let mut s = meet(q, v[k]);
        // z[0] = −∞ stops the loop at k = 0 (s is always finite).
        while s <= z[k] {
            k -= 1;
            s = meet(q, v[k]);
        }
        k += 1;
        v[k] = q;
        z[k] = s;
        z[k + 1] = f64::INFINITY;
    }
    k = 0;
    for (q, out) in d.iter_mut().enumerate() {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let p = v[k];
        let dq = q as f64 - p as f64;
        *out = dq * dq + f[p];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_matches_brute_force() {
        let mut pts = Vec::new();
        let mut s = 12345u64;
        let mut rnd = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s % 10_000) as f64 / 1000.0
        };
        for _ in 0..500 {
            pts.push((rnd(), rnd() * 0.5));
        }
        let idx = PointIndex::new(pts.clone(), 0.2);
        for _ in 0..300 {
            let (x, y) = (rnd() * 1.4 - 2.0, rnd() - 3.0);
            let brute = pts
                .iter()
                .map(|p| ((p.0 - x).powi(2) + (p.1 - y).powi(2)).sqrt())
                .fold(f64::INFINITY, f64::min);
            assert!((idx.nearest_distance(x, y) - brute).abs() < 1e-12);
        }
        assert_eq!(
            PointIndex::new(vec![], 0.1).nearest_distance(0.0, 0.0),
            f64::INFINITY
        );
    }

    #[test]
    fn distance_transform_is_exact_euclidean() {
        let (w, h) = (13, 9);
        let mut sites = vec![false; w * h];
        sites[2 * w + 3] = true;
        sites[7 * w + 11] = true;
        let dt = distance_transform(w, h, &sites);
        for y in 0..h {
            for x in 0..w {
                let brute = [(3.0, 2.0), (11.0, 7.0)]
                    .iter()
                    .map(|&(sx, sy): &(f64, f64)| {
                        ((x as f64 - sx).powi(2) + (y as f64 - sy).powi(2)).sqrt()
                    })
                    .fold(f64::INFINITY, f64::min);
                assert!(
                    (dt[y * w + x] - brute).abs() < 1e-9,
                    "({x},{y}) {} vs {brute}",
                    dt[y * w + x]
                );
            }
        }
        assert!(
            distance_transform(3, 3, &[false; 9])
                .iter()
                .all(|d| d.is_infinite())
        );
    }
}
