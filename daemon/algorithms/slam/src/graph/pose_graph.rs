//! A 2D pose graph and its optimiser: sparse nonlinear least squares on SE(2).
//!
//! Vertices are robot poses, edges measured relative poses with an
//! information matrix (g2o's `EDGE_SE2`: the error of edge i→j with
//! measurement z is `t2v(z⁻¹ · (xᵢ⁻¹ · xⱼ))`, its cost `eᵀ Ω e`). The
//! optimiser is Levenberg–Marquardt over the poses' (x, y, θ) with a sparse
//! Cholesky factorisation of the normal equations ([`super::block_cholesky`]:
//! `faer`'s supernodal factorisation in a vertex-wise AMD order; the
//! symbolic factorisation is computed once per graph structure and reused,
//! with its buffers, every iteration).
//!
//! A robust kernel (Cauchy or Huber, by iteratively reweighted least squares)
//! can be applied to the edges marked `robust` (loop closures), so a single
//! false closure is down-weighted instead of bending the whole map.
//!
//! What the optimiser refuses: a vertex that no edge ties to a fixed vertex
//! (its pose is undetermined: the error names it), a non-finite value. On any
//! failure the poses keep their last good values.

use super::block_cholesky::{BlockCholesky, CholeskyError};
use smokenav_shared_types::Pose2;
use smokenav_shared_types::odom::normalize_angle;

/// The normal equations: dimension, lower-triangle entries (row, col, value), gradient.
pub type LinearSystem = (usize, Vec<(usize, usize, f64)>, Vec<f64>);

/// A symmetric 3 × 3 information matrix over (x, y, θ), row-major.
pub type Information = [[f64; 3]; 3];

/// One relative-pose measurement between two vertices (indices into the graph).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Edge {
    pub from: usize,
    pub to: usize,
    /// Pose of `to` in the frame of `from`.
    pub measurement: Pose2,
    pub information: Information,
    /// Apply the robust kernel to this edge (loop closures).
    pub robust: bool,
}

/// Down-weights large residuals; `c` is in units of the Mahalanobis distance √(eᵀΩe).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum RobustKernel {
    #[default]
    None,
    /// Quadratic up to `c`, linear beyond.
    Huber(f64),
    /// `c²/2 · ln(1 + s/c²)`: a residual far beyond `c` barely counts.
    Cauchy(f64),
}

impl RobustKernel {
    /// (cost, IRLS weight) of a squared Mahalanobis residual `s`; the cost is
    /// on the χ² scale (s for a quadratic kernel).
    fn apply(&self, s: f64) -> (f64, f64) {
        match *self {
            RobustKernel::None => (s, 1.0),
            RobustKernel::Huber(c) => {
                let r = s.sqrt();
                if r <= c {
                    (s, 1.0)
                } else {
                    (2.0 * c * r - c * c, c / r)
                }
            }
            RobustKernel::Cauchy(c) => {
                let c2 = c * c;
                (c2 * (s / c2).ln_1p(), 1.0 / (1.0 + s / c2))
            }
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OptimizeParams {
    pub max_iterations: u32,
    /// Stop once an iteration lowers the cost by less than this share of it.
    pub relative_tolerance: f64,
    pub kernel: RobustKernel,
    /// Initial Levenberg–Marquardt damping, relative to the Hessian's diagonal.
    pub initial_lambda: f64,
}

impl Default for OptimizeParams {
    fn default() -> Self {
        Self {
            max_iterations: 500,
            relative_tolerance: 1e-9,
            kernel: RobustKernel::None,
            initial_lambda: 1e-5,
        }
    }
}

/// What one optimisation did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OptimizeReport {
    /// Σ eᵀΩe over all edges before and after (without the kernel).
    pub chi2_before: f64,
    pub chi2_after: f64,
    /// The kernel-weighted cost that was minimised, before and after.
    pub cost_before: f64,
    pub cost_after: f64,
    /// Linear systems solved (accepted and rejected steps).
    pub iterations: u32,
    /// The relative tolerance was reached before `max_iterations`.
    pub converged: bool,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GraphError {
    #[error("vertex {vertex} is under-constrained: {reason}")]
    UnderConstrained { vertex: u64, reason: &'static str },
    #[error("edge {index} refers to vertex index {vertex}, but the graph has {vertices} vertices")]
    DanglingEdge {
        index: usize,
        vertex: usize,
        vertices: usize,
    },
    #[error("edge {index} ({from} → {to}): {what}")]
    BadEdge {
        index: usize,
        from: u64,
        to: u64,
        what: &'static str,
    },
    #[error("vertex {vertex} has a non-finite pose")]
    NonFiniteVertex { vertex: u64 },
    #[error("the linear system is indeterminate (factorisation failed: {0})")]
    Indeterminate(String),
    #[error("the graph has no vertex")]
    Empty,
}

/// The poses, their external ids (for messages and files) and the edges.
#[derive(Debug, Clone, Default)]
pub struct PoseGraph {
    poses: Vec<Pose2>,
    ids: Vec<u64>,
    fixed: Vec<bool>,
    edges: Vec<Edge>,
    /// Cached structure of the normal equations; invalidated by a new vertex or edge.
    structure: Option<Structure>,
}

/// The sparsity pattern of the normal equations and its symbolic factorisation.
#[derive(Debug, Clone)]
struct Structure {
    /// Block column of each vertex, `None` for fixed vertices.
    block: Vec<Option<usize>>,
    dim: usize,
    /// The factorisation; its `values_len` is the number of (row, col)
    /// entries: 6 per free vertex, 9 per edge between two free vertices.
    llt: BlockCholesky,
}

fn indeterminate(e: CholeskyError) -> GraphError {
    GraphError::Indeterminate(e.to_string())
}

/// Symmetric positive definite (by Cholesky): the test every information matrix must pass.
pub fn is_positive_definite(m: &Information) -> bool {
    let sym = (0..3).all(|r| {
        (0..3).all(|c| {
            let (a, b) = (m[r][c], m[c][r]);
            a.is_finite() && (a - b).abs() <= 1e-9 * (a.abs().max(b.abs()).max(1.0))
        })
    });
    if !sym {
        return false;
    }
    let l11 = m[0][0];
    if l11 <= 0.0 {
        return false;
    }
    let l11 = l11.sqrt();
    let l21 = m[1][0] / l11;
    let l31 = m[2][0] / l11;
    let d2 = m[1][1] - l21 * l21;
    if d2 <= 0.0 {
        return false;
    }
    let l22 = d2.sqrt();
    let l32 = (m[2][1] - l31 * l21) / l22;
    m[2][2] - l31 * l31 - l32 * l32 > 0.0
}

/// Error of an edge and its Jacobians with respect to (xᵢ, yᵢ, θᵢ) and (xⱼ, yⱼ, θⱼ).
#[inline]
fn linearise(xi: &Pose2, xj: &Pose2, z: &Pose2) -> ([f64; 3], [[f64; 3]; 3], [[f64; 3]; 3]) {
    let (si, ci) = xi.theta.sin_cos();
    let (sz, cz) = z.theta.sin_cos();
    let (dx, dy) = (xj.x - xi.x, xj.y - xi.y);
    // xᵢ⁻¹·xⱼ translation: Rᵢᵀ (tⱼ − tᵢ).
    let lx = ci * dx + si * dy;
    let ly = -si * dx + ci * dy;
    let (ux, uy) = (lx - z.x, ly - z.y);
    let e = [
        cz * ux + sz * uy,
        -sz * ux + cz * uy,
        normalize_angle(xj.theta - xi.theta - z.theta),
    ];
    // d(Rᵢᵀ d)/dθᵢ = (ly, −lx); then through Rzᵀ.
    let (gx, gy) = (ly, -lx);
    // Rzᵀ Rᵢᵀ = R(θᵢ + θz)ᵀ, by the angle-sum rule (no third sin_cos).
    let (s, c) = (si * cz + ci * sz, ci * cz - si * sz);
    let ji = [
        [-c, -s, cz * gx + sz * gy],
        [s, -c, -sz * gx + cz * gy],
        [0.0, 0.0, -1.0],
    ];
    let jj = [[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]];
    (e, ji, jj)
}

#[inline]
fn quad(e: &[f64; 3], o: &Information) -> f64 {
    let mut s = 0.0;
    for r in 0..3 {
        for c in 0..3 {
            s += e[r] * o[r][c] * e[c];
        }
    }
    s
}

/// `aᵀ W b` for 3 × 3 blocks.
#[inline]
fn at_w_b(a: &[[f64; 3]; 3], w: &Information, b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut wb = [[0.0; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            wb[r][c] = w[r][0] * b[0][c] + w[r][1] * b[1][c] + w[r][2] * b[2][c];
        }
    }
    let mut out = [[0.0; 3]; 3];
    for r in 0..3 {
        for c in 0..3 {
            out[r][c] = a[0][r] * wb[0][c] + a[1][r] * wb[1][c] + a[2][r] * wb[2][c];
        }
    }
    out
}

impl PoseGraph {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a vertex with an external id; returns its index.
    pub fn add_vertex(&mut self, id: u64, pose: Pose2) -> usize {
        self.poses.push(pose);
        self.ids.push(id);
        self.fixed.push(false);
        self.structure = None;
        self.poses.len() - 1
    }

    pub fn add_edge(&mut self, edge: Edge) {
        self.edges.push(edge);
        self.structure = None;
    }

    /// Removes the last edge (e.g. a loop closure the optimisation refused).
    pub fn pop_edge(&mut self) -> Option<Edge> {
        self.structure = None;
        self.edges.pop()
    }

    /// Removes the first edge equal to `edge` (a loop closure later matches
    /// contradicted); false if the graph has none.
    pub fn remove_edge(&mut self, edge: &Edge) -> bool {
        let Some(i) = self.edges.iter().position(|e| e == edge) else {
            return false;
        };
        self.edges.remove(i);
        self.structure = None;
        true
    }

    /// Holds a vertex where it is (the gauge). Without any fixed vertex the
    /// optimiser holds the first one.
    pub fn set_fixed(&mut self, index: usize, fixed: bool) {
        if let Some(f) = self.fixed.get_mut(index) {
            *f = fixed;
            self.structure = None;
        }
    }

    pub fn is_fixed(&self, index: usize) -> bool {
        self.fixed.get(index).copied().unwrap_or(false)
    }

    pub fn len(&self) -> usize {
        self.poses.len()
    }

    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    pub fn poses(&self) -> &[Pose2] {
        &self.poses
    }

    pub fn set_pose(&mut self, index: usize, pose: Pose2) {
        if let Some(p) = self.poses.get_mut(index) {
            *p = pose;
        }
    }

    /// A copy of the vertices and edges without the cached factorisation
    /// (a copy handed to another thread adds edges, which invalidates it).
    pub fn snapshot(&self) -> PoseGraph {
        PoseGraph {
            poses: self.poses.clone(),
            ids: self.ids.clone(),
            fixed: self.fixed.clone(),
            edges: self.edges.clone(),
            structure: None,
        }
    }

    pub fn ids(&self) -> &[u64] {
        &self.ids
    }

    pub fn edges(&self) -> &[Edge] {
        &self.edges
    }

    /// Σ eᵀΩe over all edges at the current poses.
    pub fn chi2(&self) -> f64 {
        self.edges
            .iter()
            .map(|e| {
                let (r, _, _) = linearise(&self.poses[e.from], &self.poses[e.to], &e.measurement);
                quad(&r, &e.information)
            })
            .sum()
    }

    /// eᵀΩe of one edge at the current poses.
    pub fn edge_chi2(&self, edge: &Edge) -> f64 {
        let (r, _, _) = linearise(
            &self.poses[edge.from],
            &self.poses[edge.to],
            &edge.measurement,
        );
        quad(&r, &edge.information)
    }

    fn cost(&self, poses: &[Pose2], kernel: &RobustKernel) -> (f64, f64) {
        let (mut chi2, mut cost) = (0.0, 0.0);
        for e in &self.edges {
            let (r, _, _) = linearise(&poses[e.from], &poses[e.to], &e.measurement);
            let s = quad(&r, &e.information);
            chi2 += s;
            cost += if e.robust { kernel.apply(s).0 } else { s };
        }
        (chi2, cost)
    }

    /// Checks edges and vertices, and that every vertex is tied to a fixed one.
    pub fn validate(&self) -> Result<(), GraphError> {
        if self.poses.is_empty() {
            return Err(GraphError::Empty);
        }
        let n = self.poses.len();
        for (i, p) in self.poses.iter().enumerate() {
            if !p.is_finite() {
                return Err(GraphError::NonFiniteVertex {
                    vertex: self.ids[i],
                });
            }
        }
        let mut parent: Vec<usize> = (0..n).collect();
        fn root(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        let mut touched = vec![false; n];
        for (k, e) in self.edges.iter().enumerate() {
            for v in [e.from, e.to] {
                if v >= n {
                    return Err(GraphError::DanglingEdge {
                        index: k,
                        vertex: v,
                        vertices: n,
                    });
                }
            }
            let bad = |what| GraphError::BadEdge {
                index: k,
                from: self.ids[e.from],
                to: self.ids[e.to],
                what,
            };
            if e.from == e.to {
                return Err(bad("an edge from a vertex to itself"));
            }
            if !e.measurement.is_finite() {
                return Err(bad("the measurement is not finite"));
            }
            if !is_positive_definite(&e.information) {
                return Err(bad("the information matrix is not positive definite"));
            }
            touched[e.from] = true;
            touched[e.to] = true;
            let (a, b) = (root(&mut parent, e.from), root(&mut parent, e.to));
            if a != b {
                parent[a] = b;
            }
        }
        let gauge = self.gauge();
        let mut anchored = vec![false; n];
        for &g in &gauge {
            let r = root(&mut parent, g);
            anchored[r] = true;
        }
        for (i, &has_edge) in touched.iter().enumerate() {
            if gauge.contains(&i) {
                continue;
            }
            if !has_edge {
                return Err(GraphError::UnderConstrained {
                    vertex: self.ids[i],
                    reason: "no edge ties it to any other vertex",
                });
            }
            let r = root(&mut parent, i);
            if !anchored[r] {
                return Err(GraphError::UnderConstrained {
                    vertex: self.ids[i],
                    reason: "no chain of edges ties it to a fixed vertex",
                });
            }
        }
        Ok(())
    }

    /// The fixed vertices, or the first vertex when none is marked.
    fn gauge(&self) -> Vec<usize> {
        let fixed: Vec<usize> = (0..self.poses.len()).filter(|&i| self.fixed[i]).collect();
        if fixed.is_empty() && !self.poses.is_empty() {
            vec![0]
        } else {
            fixed
        }
    }

    fn build_structure(&self) -> Result<Structure, GraphError> {
        let gauge = self.gauge();
        let mut block = vec![None; self.poses.len()];
        let mut next = 0;
        for (i, b) in block.iter_mut().enumerate() {
            if !gauge.contains(&i) {
                *b = Some(next);
                next += 1;
            }
        }
        let dim = 3 * next;
        let links: Vec<(usize, usize)> = self
            .edges
            .iter()
            .filter_map(|e| match (block[e.from], block[e.to]) {
                (Some(a), Some(b)) => Some(if a > b { (a, b) } else { (b, a) }),
                _ => None,
            })
            .collect();
        let llt = BlockCholesky::new(next, &links).map_err(indeterminate)?;
        Ok(Structure { block, dim, llt })
    }

    /// Fills the lower triangle of H (in the order of the structure's pairs)
    /// and the gradient b at `poses`.
    fn normal_equations(
        &self,
        s: &Structure,
        poses: &[Pose2],
        kernel: &RobustKernel,
        values: &mut Vec<f64>,
        b: &mut [f64],
    ) {
        values.clear();
        values.resize(s.llt.values_len(), 0.0);
        b.iter_mut().for_each(|v| *v = 0.0);
        let free = s.dim / 3;
        let mut offdiag = 6 * free;
        let diag_at = |k: usize, r: usize, c: usize| 6 * k + r * (r + 1) / 2 + c;
        for e in &self.edges {
            let (r, ji, jj) = linearise(&poses[e.from], &poses[e.to], &e.measurement);
            let w = if e.robust {
                kernel.apply(quad(&r, &e.information)).1
            } else {
                1.0
            };
            let mut o = e.information;
            o.iter_mut().flatten().for_each(|v| *v *= w);
            let (bi, bj) = (s.block[e.from], s.block[e.to]);
            let mut add_grad = |blk: Option<usize>, j: &[[f64; 3]; 3]| {
                if let Some(k) = blk {
                    for c in 0..3 {
                        let mut g = 0.0;
                        for rr in 0..3 {
                            let ow = o[rr][0] * r[0] + o[rr][1] * r[1] + o[rr][2] * r[2];
                            g += j[rr][c] * ow;
                        }
                        b[3 * k + c] += g;
                    }
                }
            };
            add_grad(bi, &ji);
            add_grad(bj, &jj);
            for (blk, j) in [(bi, &ji), (bj, &jj)] {
                if let Some(k) = blk {
                    let h = at_w_b(j, &o, j);
                    for rr in 0..3 {
                        for c in 0..=rr {
                            values[diag_at(k, rr, c)] += h[rr][c];
                        }
                    }
                }
            }
            if let (Some(a), Some(bb)) = (bi, bj) {
                // Block (hi, lo) of the lower triangle.
                let h = if a > bb {
                    at_w_b(&ji, &o, &jj)
                } else {
                    at_w_b(&jj, &o, &ji)
                };
                for rr in 0..3 {
                    for c in 0..3 {
                        values[offdiag + 3 * rr + c] = h[rr][c];
                    }
                }
                offdiag += 9;
            }
        }
    }

    /// The Gauss–Newton normal equations at the current poses (no kernel, no
    /// damping): the lower triangle of H as (row, col, value) with repeated
    /// positions to be summed, and the gradient b. For inspection and for
    /// comparing linear solvers.
    pub fn linear_system(&self) -> Result<LinearSystem, GraphError> {
        self.validate()?;
        let s = self.build_structure()?;
        let mut values = Vec::new();
        let mut b = vec![0.0; s.dim];
        self.normal_equations(&s, &self.poses, &RobustKernel::None, &mut values, &mut b);
        let free = s.dim / 3;
        let mut out = Vec::with_capacity(values.len());
        for k in 0..free {
            for r in 0..3 {
                for c in 0..=r {
                    out.push((3 * k + r, 3 * k + c, values[6 * k + r * (r + 1) / 2 + c]));
                }
            }
        }
        let mut at = 6 * free;
        for e in &self.edges {
            if let (Some(a), Some(bb)) = (s.block[e.from], s.block[e.to]) {
                let (hi, lo) = if a > bb { (a, bb) } else { (bb, a) };
                for r in 0..3 {
                    for c in 0..3 {
                        out.push((3 * hi + r, 3 * lo + c, values[at + 3 * r + c]));
                    }
                }
                at += 9;
            }
        }
        Ok((s.dim, out, b))
    }

    /// Levenberg–Marquardt from the current poses. On success the poses are
    /// replaced by the optimum; on failure they are left as they were.
    pub fn optimize(&mut self, p: &OptimizeParams) -> Result<OptimizeReport, GraphError> {
        let (poses, report) = self.with_structure(|g, s| g.optimize_with(s, p))?;
        self.poses = poses;
        Ok(report)
    }

    /// The marginal covariance of vertex `index`'s (x, y, θ), in the map
    /// frame, at the current poses: its 3 × 3 block of the inverse of the
    /// Gauss–Newton information (with `kernel`'s weights on the robust edges,
    /// as the optimiser last saw them), found by one sparse factorisation and
    /// three solves. A fixed vertex's is zero.
    pub fn marginal_covariance(
        &mut self,
        index: usize,
        kernel: &RobustKernel,
    ) -> Result<Information, GraphError> {
        self.with_structure(|g, s| g.marginal_with(s, index, kernel))
    }

    /// Runs `f` on the validated graph with its sparse structure (built
    /// once per graph structure and kept for the next call).
    fn with_structure<R>(
        &mut self,
        f: impl FnOnce(&Self, &mut Structure) -> Result<R, GraphError>,
    ) -> Result<R, GraphError> {
        self.validate()?;
        if self.structure.is_none() {
            self.structure = Some(self.build_structure()?);
        }
        let mut s = self.structure.take().expect("built above");
        let result = f(self, &mut s);
        self.structure = Some(s);
        result
    }

    fn marginal_with(
        &self,
        s: &mut Structure,
        index: usize,
        kernel: &RobustKernel,
    ) -> Result<Information, GraphError> {
        let Some(k) = s.block.get(index).copied().flatten() else {
            return Ok([[0.0; 3]; 3]);
        };
        let mut values = Vec::new();
        let mut b = vec![0.0; s.dim];
        self.normal_equations(s, &self.poses, kernel, &mut values, &mut b);
        s.llt.factorize(&values).map_err(indeterminate)?;
        // Three columns of the identity at the vertex's block: H X = E gives
        // the block's columns of H⁻¹.
        let mut cols = vec![0.0; 3 * s.dim];
        for c in 0..3 {
            cols[c * s.dim + 3 * k + c] = 1.0;
        }
        s.llt.solve_in_place(&mut cols, 3).map_err(indeterminate)?;
        let mut out = [[0.0; 3]; 3];
        for (r, row) in out.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                // Symmetrised: the two triangles differ by rounding only.
                *v = 0.5 * (cols[c * s.dim + 3 * k + r] + cols[r * s.dim + 3 * k + c]);
            }
        }
        if out.iter().flatten().any(|v| !v.is_finite()) {
            return Err(GraphError::Indeterminate("non-finite marginal".into()));
        }
        Ok(out)
    }

    fn optimize_with(
        &self,
        s: &mut Structure,
        p: &OptimizeParams,
    ) -> Result<(Vec<Pose2>, OptimizeReport), GraphError> {
        let mut poses = self.poses.clone();
        let (chi2_before, cost_before) = self.cost(&poses, &p.kernel);
        let mut report = OptimizeReport {
            chi2_before,
            chi2_after: chi2_before,
            cost_before,
            cost_after: cost_before,
            iterations: 0,
            converged: false,
        };
        if s.dim == 0 || self.edges.is_empty() {
            report.converged = true;
            return Ok((poses, report));
        }
        let mut values = Vec::new();
        let mut damped = Vec::new();
        let mut b = vec![0.0; s.dim];
        let mut step = vec![0.0; s.dim];
        let mut cost = cost_before;
        let mut lambda = p.initial_lambda.max(0.0);
        let mut nu = 2.0;
        let mut relinearise = true;
        let mut trial = poses.clone();
        let free = s.dim / 3;
        while report.iterations < p.max_iterations {
            if relinearise {
                self.normal_equations(s, &poses, &p.kernel, &mut values, &mut b);
                relinearise = false;
            }
            damped.clone_from(&values);
            for k in 0..free {
                for r in 0..3 {
                    let i = 6 * k + r * (r + 1) / 2 + r;
                    damped[i] += lambda * values[i].max(1e-9);
                }
            }
            report.iterations += 1;
            match s.llt.factorize(&damped) {
                Ok(()) => {}
                Err(e) => {
                    // A damped system that is still not positive definite.
                    if lambda > 1e12 {
                        return Err(indeterminate(e));
                    }
                    lambda = (lambda * nu).max(1e-6);
                    nu *= 2.0;
                    continue;
                }
            }
            for (d, g) in step.iter_mut().zip(&b) {
                *d = -g;
            }
            s.llt.solve_in_place(&mut step, 1).map_err(indeterminate)?;
            if step.iter().any(|v| !v.is_finite()) {
                return Err(GraphError::Indeterminate("non-finite step".into()));
            }
            for (i, pose) in poses.iter().enumerate() {
                trial[i] = match s.block[i] {
                    Some(k) => Pose2::new(
                        pose.x + step[3 * k],
                        pose.y + step[3 * k + 1],
                        normalize_angle(pose.theta + step[3 * k + 2]),
                    ),
                    None => *pose,
                };
            }
            let (_, new_cost) = self.cost(&trial, &p.kernel);
            // Predicted decrease of the damped quadratic model: Δᵀ(λD Δ − b).
            let mut predicted = 0.0;
            for k in 0..free {
                for r in 0..3 {
                    let i = 3 * k + r;
                    let d = lambda * values[6 * k + r * (r + 1) / 2 + r].max(1e-9);
                    predicted += step[i] * (d * step[i] - b[i]);
                }
            }
            if new_cost.is_finite() && new_cost < cost {
                let gain = (cost - new_cost) / predicted.max(1e-300);
                let improvement = (cost - new_cost) / cost.max(1e-300);
                std::mem::swap(&mut poses, &mut trial);
                cost = new_cost;
                relinearise = true;
                lambda *= (1.0f64 / 3.0).max(1.0 - (2.0 * gain - 1.0).powi(3));
                nu = 2.0;
                if improvement < p.relative_tolerance {
                    report.converged = true;
                    break;
                }
            } else {
                let small = step.iter().map(|v| v.abs()).fold(0.0, f64::max) < 1e-12;
                if small {
                    report.converged = true;
                    break;
                }
                lambda = (lambda * nu).max(1e-9);
                nu *= 2.0;
                if lambda > 1e16 {
                    report.converged = true;
                    break;
                }
            }
        }
        let (chi2_after, cost_after) = self.cost(&poses, &p.kernel);
        report.chi2_after = chi2_after;
        report.cost_after = cost_after;
        Ok((poses, report))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn info(xy: f64, t: f64) -> Information {
        [[xy, 0.0, 0.0], [0.0, xy, 0.0], [0.0, 0.0, t]]
    }

    fn edge(from: usize, to: usize, z: Pose2) -> Edge {
        Edge {
            from,
            to,
            measurement: z,
            information: info(100.0, 400.0),
            robust: false,
        }
    }

    /// A square of four 2 m legs with left turns, odometry initial guess bent by 0.1 rad per leg.
    fn square() -> PoseGraph {
        let mut g = PoseGraph::new();
        let leg = Pose2::new(2.0, 0.0, std::f64::consts::FRAC_PI_2);
        let mut guess = Pose2::default();
        for i in 0..4 {
            g.add_vertex(i, guess);
            guess = guess.compose(&Pose2::new(2.1, 0.05, std::f64::consts::FRAC_PI_2 + 0.1));
        }
        for i in 0..3 {
            g.add_edge(edge(i, i + 1, leg));
        }
        g.add_edge(edge(3, 0, leg));
        g
    }

    #[test]
    fn jacobians_match_finite_differences() {
        let xi = Pose2::new(1.0, -2.0, 0.7);
        let xj = Pose2::new(3.0, 0.5, -2.9);
        let z = Pose2::new(0.4, 1.1, 2.6);
        let (_, ji, jj) = linearise(&xi, &xj, &z);
        let h = 1e-6;
        for k in 0..3 {
            let bump = |p: &Pose2, d: f64| {
                let mut q = *p;
                match k {
                    0 => q.x += d,
                    1 => q.y += d,
                    _ => q.theta += d,
                }
                q
            };
            let (ep, _, _) = linearise(&bump(&xi, h), &xj, &z);
            let (em, _, _) = linearise(&bump(&xi, -h), &xj, &z);
            let (fp, _, _) = linearise(&xi, &bump(&xj, h), &z);
            let (fm, _, _) = linearise(&xi, &bump(&xj, -h), &z);
            for r in 0..3 {
                let ni = normalize_angle(ep[r] - em[r]) / (2.0 * h);
                let nj = normalize_angle(fp[r] - fm[r]) / (2.0 * h);
                assert!(
                    (ni - ji[r][k]).abs() < 1e-6,
                    "Ji[{r}][{k}] {ni} vs {}",
                    ji[r][k]
                );
                assert!(
                    (nj - jj[r][k]).abs() < 1e-6,
                    "Jj[{r}][{k}] {nj} vs {}",
                    jj[r][k]
                );
            }
        }
    }

    #[test]
    fn consistent_square_closes_exactly() {
        let mut g = square();
        let before = g.chi2();
        let r = g.optimize(&OptimizeParams::default()).unwrap();
        assert!(before > 1.0, "{before}");
        assert!(r.chi2_after < 1e-12, "{r:?}");
        assert!(r.converged);
        let p2 = g.poses()[2];
        assert!(
            (p2.x - 2.0).abs() < 1e-6 && (p2.y - 2.0).abs() < 1e-6,
            "{p2:?}"
        );
        assert_eq!(
            g.poses()[0],
            Pose2::default(),
            "the first vertex holds the gauge"
        );
    }

    #[test]
    fn cauchy_kernel_keeps_one_false_closure_from_bending_the_chain() {
        // A straight 10-pose corridor with tight odometry, and one false closure
        // that claims pose 9 is back at pose 0.
        let build = |kernel| {
            let mut g = PoseGraph::new();
            for i in 0..10 {
                g.add_vertex(i, Pose2::new(i as f64, 0.0, 0.0));
            }
            for i in 0..9 {
                g.add_edge(edge(i, i + 1, Pose2::new(1.0, 0.0, 0.0)));
            }
            g.add_edge(Edge {
                robust: true,
                ..edge(0, 9, Pose2::new(0.5, 0.0, 0.0))
            });
            g.optimize(&OptimizeParams {
                kernel,
                ..OptimizeParams::default()
            })
            .unwrap();
            g.poses()[9].x
        };
        let plain = build(RobustKernel::None);
        let robust = build(RobustKernel::Cauchy(1.0));
        assert!(
            plain < 8.0,
            "least squares is pulled by the closure: {plain}"
        );
        assert!(
            (robust - 9.0).abs() < 0.05,
            "the kernel ignores it: {robust}"
        );
    }

    #[test]
    fn a_graph_of_fixed_vertices_optimises_to_itself() {
        let mut g = PoseGraph::new();
        g.add_vertex(7, Pose2::new(1.0, 2.0, 0.5));
        let r = g.optimize(&OptimizeParams::default()).unwrap();
        assert!(r.converged);
        assert_eq!(g.poses()[0], Pose2::new(1.0, 2.0, 0.5));
        assert_eq!(
            g.marginal_covariance(0, &RobustKernel::None).unwrap(),
            [[0.0; 3]; 3]
        );
    }

    #[test]
    fn vertex_without_edges_is_named() {
        let mut g = square();
        g.add_vertex(77, Pose2::new(5.0, 5.0, 0.0));
        let before = g.poses().to_vec();
        let err = g.optimize(&OptimizeParams::default()).unwrap_err();
        assert_eq!(
            err,
            GraphError::UnderConstrained {
                vertex: 77,
                reason: "no edge ties it to any other vertex"
            }
        );
        assert!(err.to_string().contains("vertex 77"), "{err}");
        assert_eq!(g.poses(), &before[..], "the last good solution is kept");
    }

    #[test]
    fn island_not_tied_to_the_fixed_vertex_is_named() {
        let mut g = square();
        let a = g.add_vertex(100, Pose2::new(9.0, 0.0, 0.0));
        let b = g.add_vertex(101, Pose2::new(10.0, 0.0, 0.0));
        g.add_edge(edge(a, b, Pose2::new(1.0, 0.0, 0.0)));
        let err = g.optimize(&OptimizeParams::default()).unwrap_err();
        assert!(
            matches!(err, GraphError::UnderConstrained { vertex: 100, .. }),
            "{err}"
        );
        // Fixing the island makes it well posed.
        g.set_fixed(0, true);
        g.set_fixed(a, true);
        g.optimize(&OptimizeParams::default()).unwrap();
    }

    #[test]
    fn non_positive_definite_information_is_refused() {
        let mut g = square();
        g.add_edge(Edge {
            information: [[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            ..edge(0, 2, Pose2::new(2.0, 2.0, std::f64::consts::PI))
        });
        assert!(matches!(
            g.optimize(&OptimizeParams::default()),
            Err(GraphError::BadEdge { index: 4, .. })
        ));
        assert!(!is_positive_definite(&info(1.0, 0.0)));
        assert!(is_positive_definite(&info(1.0, 1e-9)));
    }

    /// A chain is a tree: the marginal is the covariance composed along it,
    /// which here is known in closed form.
    #[test]
    fn a_chains_marginal_is_its_edges_composed() {
        let mut g = PoseGraph::new();
        for i in 0..3 {
            g.add_vertex(i, Pose2::new(i as f64, 0.0, 0.0));
        }
        // σ² = 0.01 m² across and along each 1 m step, 0.0025 rad² in heading.
        g.add_edge(edge(0, 1, Pose2::new(1.0, 0.0, 0.0)));
        g.add_edge(edge(1, 2, Pose2::new(1.0, 0.0, 0.0)));
        let c = g.marginal_covariance(2, &RobustKernel::None).unwrap();
        let want = [
            [0.02, 0.0, 0.0],
            [0.0, 0.0225, 0.0025],
            [0.0, 0.0025, 0.005],
        ];
        for r in 0..3 {
            for k in 0..3 {
                assert!((c[r][k] - want[r][k]).abs() < 1e-9, "{c:?}");
            }
        }
        assert_eq!(
            g.marginal_covariance(0, &RobustKernel::None).unwrap(),
            [[0.0; 3]; 3],
            "the gauge vertex is certain"
        );
    }

    #[test]
    fn a_loop_closure_shrinks_the_far_end_of_the_loop() {
        let mut open = PoseGraph::new();
        let mut closed = square();
        open.add_vertex(0, Pose2::default());
        for i in 1..4 {
            open.add_vertex(i, closed.poses()[i as usize]);
            open.add_edge(edge(
                i as usize - 1,
                i as usize,
                Pose2::new(2.0, 0.0, std::f64::consts::FRAC_PI_2),
            ));
        }
        closed.optimize(&OptimizeParams::default()).unwrap();
        let trace = |c: Information| c[0][0] + c[1][1];
        let o = trace(open.marginal_covariance(3, &RobustKernel::None).unwrap());
        let k = trace(closed.marginal_covariance(3, &RobustKernel::None).unwrap());
        assert!(k < 0.5 * o, "closed {k} against open {o}");
        // An island makes the information singular: named, not a garbage answer.
        closed.add_vertex(9, Pose2::default());
        assert!(matches!(
            closed.marginal_covariance(3, &RobustKernel::None),
            Err(GraphError::UnderConstrained { vertex: 9, .. })
        ));
    }

    /// A Manhattan-style world (the M3500 / city10k kind): a walk on a 1 m
    /// grid, odometry with noise, loop closures wherever the walk comes back
    /// to a cell, started from the composed odometry.
    fn grid_world(n: usize, seed: u64) -> (PoseGraph, Vec<Pose2>) {
        let mut state = seed;
        let mut uniform = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let mut gauss = move || {
            let (u, v) = (uniform(), uniform());
            (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
        };
        let mut truth = vec![Pose2::new(0.0, 0.0, 0.0)];
        let mut turns = seed;
        for _ in 1..n {
            turns = turns
                .wrapping_mul(2862933555777941757)
                .wrapping_add(3037000493);
            let p = *truth.last().unwrap();
            let theta = normalize_angle(
                p.theta
                    + match (turns >> 33) % 5 {
                        0 => std::f64::consts::FRAC_PI_2,
                        1 => -std::f64::consts::FRAC_PI_2,
                        _ => 0.0,
                    },
            );
            truth.push(Pose2::new(
                (p.x + theta.cos()).round(),
                (p.y + theta.sin()).round(),
                theta,
            ));
        }
        let sigma = [0.05, 0.05, 0.02];
        let information = info(1.0 / (sigma[0] * sigma[0]), 1.0 / (sigma[2] * sigma[2]));
        let mut noisy = |a: &Pose2, b: &Pose2| {
            let z = a.inverse().compose(b);
            Pose2::new(
                z.x + sigma[0] * gauss(),
                z.y + sigma[1] * gauss(),
                normalize_angle(z.theta + sigma[2] * gauss()),
            )
        };
        let mut g = PoseGraph::new();
        let mut guess = truth[0];
        g.add_vertex(0, guess);
        let mut visits: std::collections::HashMap<(i64, i64), Vec<usize>> = Default::default();
        visits.entry((0, 0)).or_default().push(0);
        for i in 1..n {
            let z = noisy(&truth[i - 1], &truth[i]);
            guess = guess.compose(&z);
            g.add_vertex(i as u64, guess);
            g.add_edge(Edge {
                from: i - 1,
                to: i,
                measurement: z,
                information,
                robust: false,
            });
            let cell = (truth[i].x as i64, truth[i].y as i64);
            let earlier = visits.entry(cell).or_default();
            for &j in earlier.iter().rev().filter(|&&j| i - j > 10).take(2) {
                let z = noisy(&truth[j], &truth[i]);
                g.add_edge(Edge {
                    from: j,
                    to: i,
                    measurement: z,
                    information,
                    robust: false,
                });
            }
            earlier.push(i);
        }
        (g, truth)
    }

    #[test]
    fn a_grid_world_converges_from_its_odometry_to_the_chi2_of_an_optimum() {
        let (mut g, truth) = grid_world(1500, 7);
        let (n, e) = (g.len(), g.edges().len());
        let at_truth = {
            let mut t = g.clone();
            for (i, p) in truth.iter().enumerate() {
                t.set_pose(i, *p);
            }
            t.chi2()
        };
        let start = g.chi2();
        let r = g.optimize(&OptimizeParams::default()).unwrap();
        let expected = 3.0 * (e - n) as f64;
        // A local minimum (a loop folded the wrong way) would stay far above
        // 3(E − n), the χ² expected at the optimum of this noise; the truth
        // itself sits near 3E.
        eprintln!(
            "grid world: {n} poses, {e} edges; χ² {start:.0} → {:.1} in {} iterations (truth {at_truth:.1}, 3(E−n) = {expected})",
            r.chi2_after, r.iterations
        );
        assert!(r.converged);
        assert!(
            r.chi2_after < at_truth,
            "{} against the truth's {at_truth}",
            r.chi2_after
        );
        assert!(
            (r.chi2_after - expected).abs() < 0.2 * expected,
            "{} against {expected}",
            r.chi2_after
        );
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(200))]
        /// Any graph, however its edges repeat, cross or leave vertices
        /// apart: the optimiser answers (an error or a solution no worse than
        /// its start) and never panics; the marginal of every vertex too.
        #[test]
        fn arbitrary_graphs_never_panic_the_solver(
            n in 1usize..12,
            raw in proptest::collection::vec(
                (0usize..12, 0usize..12, -5.0f64..5.0, -5.0f64..5.0, -3.2f64..3.2, 0.01f64..100.0, 0.0f64..1.0, proptest::bool::ANY),
                0..30,
            ),
            fixed in proptest::option::of(0usize..12),
        ) {
            let mut g = PoseGraph::new();
            for i in 0..n {
                g.add_vertex(i as u64, Pose2::new(i as f64 * 0.3, (i % 3) as f64, 0.1 * i as f64));
            }
            if let Some(f) = fixed {
                g.set_fixed(f, true);
            }
            for &(a, b, x, y, t, w, skew, robust) in &raw {
                let (from, to) = (a % n, b % n);
                let mut information = info(w, w * 0.5);
                information[0][1] = skew * w;
                information[1][0] = skew * w;
                g.add_edge(Edge { from, to, measurement: Pose2::new(x, y, t), information, robust });
            }
            let before = g.chi2();
            let p = OptimizeParams { kernel: RobustKernel::Cauchy(1.0), ..OptimizeParams::default() };
            if let Ok(r) = g.optimize(&p) {
                proptest::prop_assert!(r.cost_after <= r.cost_before * (1.0 + 1e-9) + 1e-9);
                proptest::prop_assert!(g.poses().iter().all(|q| q.x.is_finite() && q.y.is_finite() && q.theta.is_finite()));
            } else {
                proptest::prop_assert!((g.chi2() - before).abs() <= 1e-9 * before.max(1.0));
            }
            for i in 0..n {
                let _ = g.marginal_covariance(i, &RobustKernel::None);
            }
        }
    }
}
