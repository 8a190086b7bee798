//! Sparse Cholesky of a pose graph's normal equations, kept between solves.
//!
//! The matrix is made of 3 × 3 blocks, one block row and column per free
//! vertex. Three things make the repeated factorisations of a growing graph
//! cheaper than `faer`'s one-call solver:
//!
//! - the fill-reducing order is computed on the vertex graph (AMD over n
//!   vertices instead of 3n scalars, with a ninth of the entries) and each
//!   vertex's three unknowns are kept together, so the factor's columns come
//!   in dense groups of three;
//! - the factorisation is supernodal: it works on those groups as small
//!   dense blocks instead of entry by entry (on a 3737-vertex graph faer's
//!   own rule picked the simplicial one, whose numeric factorisation and
//!   row-pattern walks took 31 % of a long run's CPU);
//! - the factor's values, the summed matrix and the scratch memory are kept
//!   and reused: allocated per factorisation they were megabytes mapped and
//!   unmapped every iteration (page faults were 12 of 86 CPU-s on a long run).

use std::sync::Arc;

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::reborrow::Reborrow;
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::linalg::amd;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymmetricOrdering,
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMat};
use faer::{Conj, MatMut, Par};

/// Why a factorisation or solve could not be done.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CholeskyError {
    #[error("sparse structure: {0}")]
    Structure(String),
    #[error("not positive definite: {0}")]
    NotPositiveDefinite(String),
    #[error("no factorisation to solve with")]
    NotFactorised,
}

/// The symbolic factorisation of one sparsity pattern and the buffers its
/// numeric factorisations reuse.
pub struct BlockCholesky {
    dim: usize,
    /// Where each unknown sits in the permuted system.
    unknown_at: Vec<usize>,
    /// Right-hand sides in the permuted order.
    rhs: Vec<f64>,
    pattern: SymbolicSparseColMat<usize>,
    symbolic: Arc<SymbolicCholesky<usize>>,
    /// For each value (in `new`'s order), its position among the pattern's.
    slot: Vec<usize>,
    /// The matrix with repeated entries summed, in the pattern's order.
    summed: Vec<f64>,
    factor: Vec<f64>,
    factorised: bool,
    scratch_req: StackReq,
    scratch: MemBuffer,
}

impl std::fmt::Debug for BlockCholesky {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BlockCholesky")
            .field("dim", &self.dim)
            .field("factor_entries", &self.factor.len())
            .field("factorised", &self.factorised)
            .finish_non_exhaustive()
    }
}

impl Clone for BlockCholesky {
    /// The structure is shared; the values and scratch start afresh.
    fn clone(&self) -> Self {
        Self {
            dim: self.dim,
            unknown_at: self.unknown_at.clone(),
            rhs: vec![0.0; self.rhs.len()],
            pattern: self.pattern.clone(),
            symbolic: Arc::clone(&self.symbolic),
            slot: self.slot.clone(),
            summed: vec![0.0; self.summed.len()],
            factor: vec![0.0; self.factor.len()],
            factorised: false,
            scratch_req: self.scratch_req,
            scratch: MemBuffer::new(self.scratch_req),
        }
    }
}

impl BlockCholesky {
    /// The pattern of a symmetric matrix of `blocks` 3 × 3 block rows and
    /// columns: every diagonal block, and an off-diagonal block (i, j) for
    /// each link (i, j) with i > j (a link may repeat: the blocks are summed).
    ///
    /// The values (see [`Self::values_len`]) come in this order: for each
    /// diagonal block its lower triangle, (0,0) (1,0) (1,1) (2,0) (2,1) (2,2);
    /// then for each link its block (i, j), row-major.
    pub fn new(blocks: usize, links: &[(usize, usize)]) -> Result<Self, CholeskyError> {
        let dim = 3 * blocks;
        let other = |e: &dyn std::fmt::Debug| CholeskyError::Structure(format!("{e:?}"));
        if let Some((i, j)) = links.iter().find(|&&(i, j)| i >= blocks || j >= i) {
            return Err(CholeskyError::Structure(format!(
                "block ({i}, {j}) is not below the diagonal of {blocks} × {blocks} blocks"
            )));
        }
        // The vertex graph, lower triangle, each column's rows sorted: the
        // diagonal block first, then the vertices it shares an edge with.
        let mut below: Vec<Vec<usize>> = (0..blocks).map(|j| vec![j]).collect();
        for &(i, j) in links {
            below[j].push(i);
        }
        for rows in &mut below {
            rows.sort_unstable();
            rows.dedup();
        }
        let vertex_graph = block_pattern(&below);
        let mut order = vec![0usize; blocks];
        let mut position = vec![0usize; blocks];
        let nnz = vertex_graph.compute_nnz();
        let mut amd_scratch =
            MemBuffer::try_new(amd::order_scratch::<usize>(blocks, nnz)).map_err(|e| other(&e))?;
        amd::order(
            &mut order,
            &mut position,
            vertex_graph.rb(),
            amd::Control::default(),
            MemStack::new(&mut amd_scratch),
        )
        .map_err(|e| other(&e))?;
        // The matrix is stored already permuted (each vertex's three
        // unknowns together, at its place in the order), so a factorisation
        // does not permute it again.
        let mut lower: Vec<Vec<usize>> = (0..blocks)
            .map(|j| Vec::with_capacity(below[j].len()))
            .collect();
        let mut upper: Vec<Vec<usize>> = (0..blocks)
            .map(|j| Vec::with_capacity(below[j].len()))
            .collect();
        for (j, rows) in below.iter().enumerate() {
            for &i in rows {
                let (a, b) = (position[i], position[j]);
                let (hi, lo) = if a >= b { (a, b) } else { (b, a) };
                lower[lo].push(hi);
                upper[hi].push(lo);
            }
        }
        for rows in lower.iter_mut().chain(upper.iter_mut()) {
            rows.sort_unstable();
        }
        let pattern = scalar_pattern(&lower, true);
        // Without a permutation faer analyses the upper triangle, and
        // factorises the lower one (the supernodal side) as it is given.
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
            ..Default::default()
        };
        let symbolic = factorize_symbolic_cholesky(
            scalar_pattern(&upper, false).rb(),
            faer::Side::Upper,
            SymmetricOrdering::Identity,
            params,
        )
        .map_err(|e| other(&e))?;
        // Each value's place among the lower pattern's values: in scalar
        // column 3J + c the diagonal block gives rows 3J + c..3J + 3, then
        // every block below it three rows.
        let col_ptr = pattern.col_ptr();
        let at = |r: usize, c: usize| -> usize {
            let (r, c) = if r >= c { (r, c) } else { (c, r) };
            let (bi, bj) = (r / 3, c / 3);
            let start = col_ptr[c];
            if bi == bj {
                start + (r % 3 - c % 3)
            } else {
                let k = lower[bj]
                    .binary_search(&bi)
                    .expect("every link's block was put in its column above");
                start + (3 - c % 3) + 3 * (k - 1) + r % 3
            }
        };
        let mut slot = Vec::with_capacity(6 * blocks + 9 * links.len());
        for &p in &position {
            for r in 0..3 {
                for c in 0..=r {
                    slot.push(at(3 * p + r, 3 * p + c));
                }
            }
        }
        for &(i, j) in links {
            let (pi, pj) = (position[i], position[j]);
            for r in 0..3 {
                for c in 0..3 {
                    slot.push(at(3 * pi + r, 3 * pj + c));
                }
            }
        }
        let to_vertex = |v: usize| 3 * position[v / 3] + v % 3;
        let unknown_at = (0..dim).map(to_vertex).collect();
        let req = symbolic
            .factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default())
            .or(symbolic.solve_in_place_scratch::<f64>(3, Par::Seq));
        let scratch = MemBuffer::try_new(req).map_err(|e| other(&e))?;
        Ok(Self {
            dim,
            unknown_at,
            rhs: vec![0.0; 3 * dim],
            summed: vec![0.0; pattern.compute_nnz()],
            factor: vec![0.0; symbolic.len_val()],
            pattern,
            symbolic: Arc::new(symbolic),
            slot,
            factorised: false,
            scratch_req: req,
            scratch,
        })
    }

    /// How many values [`Self::factorize`] takes: 6 per block, 9 per link.
    pub fn values_len(&self) -> usize {
        self.slot.len()
    }

    /// Factorises the matrix whose values, in the order [`Self::new`] states,
    /// are `values`.
    pub fn factorize(&mut self, values: &[f64]) -> Result<(), CholeskyError> {
        assert_eq!(
            values.len(),
            self.slot.len(),
            "6 values per block, 9 per link"
        );
        self.factorised = false;
        self.summed.iter_mut().for_each(|v| *v = 0.0);
        for (&s, &v) in self.slot.iter().zip(values) {
            self.summed[s] += v;
        }
        let a = SparseColMatRef::new(self.pattern.rb(), &self.summed);
        self.symbolic
            .factorize_numeric_llt::<f64>(
                &mut self.factor,
                a,
                faer::Side::Lower,
                Default::default(),
                Par::Seq,
                MemStack::new(&mut self.scratch),
                Default::default(),
            )
            .map_err(|e| CholeskyError::NotPositiveDefinite(format!("{e:?}")))?;
        self.factorised = true;
        Ok(())
    }

    /// Solves A X = B in place for the last factorised A; `b` holds up to
    /// three right-hand sides, column-major.
    pub fn solve_in_place(&mut self, b: &mut [f64], columns: usize) -> Result<(), CholeskyError> {
        if !self.factorised {
            return Err(CholeskyError::NotFactorised);
        }
        assert!(
            columns <= 3 && b.len() == columns * self.dim,
            "up to three columns of dim"
        );
        let n = self.dim;
        for col in 0..columns {
            for (i, &at) in self.unknown_at.iter().enumerate() {
                self.rhs[col * n + at] = b[col * n + i];
            }
        }
        LltRef::new(&self.symbolic, &self.factor).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut self.rhs[..columns * n], n, columns),
            Par::Seq,
            MemStack::new(&mut self.scratch),
        );
        for col in 0..columns {
            for (i, &at) in self.unknown_at.iter().enumerate() {
                b[col * n + i] = self.rhs[col * n + at];
            }
        }
        Ok(())
    }
}

/// The pattern whose column j holds rows `columns[j]` (sorted).
fn block_pattern(columns: &[Vec<usize>]) -> SymbolicSparseColMat<usize> {
    let n = columns.len();
    let mut col_ptr = Vec::with_capacity(n + 1);
    col_ptr.push(0);
    let mut row_idx = Vec::with_capacity(columns.iter().map(Vec::len).sum());
    for rows in columns {
        row_idx.extend_from_slice(rows);
        col_ptr.push(row_idx.len());
    }
    SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx)
}

/// The scalar pattern of 3 × 3 blocks at `columns` (block rows per block
/// column, sorted, the diagonal among them): only the diagonal block's
/// lower (or upper) triangle, every other block whole.
fn scalar_pattern(columns: &[Vec<usize>], lower: bool) -> SymbolicSparseColMat<usize> {
    let n = 3 * columns.len();
    let mut col_ptr = Vec::with_capacity(n + 1);
    col_ptr.push(0);
    let mut row_idx = Vec::with_capacity(columns.iter().map(|c| 9 * c.len()).sum());
    for (j, rows) in columns.iter().enumerate() {
        for c in 0..3 {
            for &i in rows {
                let range = match (i == j, lower) {
                    (true, true) => c..3,
                    (true, false) => 0..c + 1,
                    (false, _) => 0..3,
                };
                row_idx.extend(range.map(|r| 3 * i + r));
            }
            col_ptr.push(row_idx.len());
        }
    }
    SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx)
}

#[cfg(test)]
mod tests {
    use super::*;

    type Dense = Vec<Vec<f64>>;

    /// A random symmetric positive definite block matrix as links (a chain,
    /// a few long links, each twice: repeats are summed) and values in
    /// `new`'s order, and its dense form.
    fn spd(blocks: usize, seed: u64) -> (Vec<(usize, usize)>, Vec<f64>, Dense) {
        let n = 3 * blocks;
        let mut state = seed;
        let mut rnd = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 33) as f64 / (1u64 << 31) as f64) - 0.5
        };
        let mut dense = vec![vec![0.0; n]; n];
        let mut values = Vec::new();
        for k in 0..blocks {
            for r in 0..3 {
                for c in 0..=r {
                    let v = if r == c { 10.0 + rnd() } else { 0.2 * rnd() };
                    values.push(v);
                    dense[3 * k + r][3 * k + c] += v;
                    if r != c {
                        dense[3 * k + c][3 * k + r] += v;
                    }
                }
            }
        }
        let mut links: Vec<(usize, usize)> = (1..blocks).map(|i| (i, i - 1)).collect();
        links.extend([(blocks.saturating_sub(1), 0), (blocks / 2, 1)]);
        links.retain(|&(i, j)| i > j && i < blocks);
        let links: Vec<(usize, usize)> = links.iter().flat_map(|&l| [l, l]).collect();
        for &(i, j) in &links {
            for r in 0..3 {
                for c in 0..3 {
                    let v = 0.1 * rnd();
                    values.push(v);
                    dense[3 * i + r][3 * j + c] += v;
                    dense[3 * j + c][3 * i + r] += v;
                }
            }
        }
        (links, values, dense)
    }

    #[test]
    fn solves_a_block_system_as_the_dense_matrix_says() {
        for blocks in [1, 2, 7, 40] {
            let (links, values, dense) = spd(blocks, blocks as u64);
            let mut llt = BlockCholesky::new(blocks, &links).unwrap();
            assert_eq!(llt.values_len(), values.len());
            llt.factorize(&values).unwrap();
            let n = 3 * blocks;
            let x: Vec<f64> = (0..3 * n).map(|i| (i as f64 * 0.37).sin()).collect();
            let mut b = vec![0.0; 3 * n];
            for col in 0..3 {
                for r in 0..n {
                    b[col * n + r] = (0..n).map(|c| dense[r][c] * x[col * n + c]).sum();
                }
            }
            llt.solve_in_place(&mut b, 3).unwrap();
            for (got, want) in b.iter().zip(&x) {
                assert!(
                    (got - want).abs() < 1e-9,
                    "{blocks} blocks: {got} vs {want}"
                );
            }
            // Refactorised with other values, the same structure solves again.
            let scaled: Vec<f64> = values.iter().map(|v| 2.0 * v).collect();
            llt.factorize(&scaled).unwrap();
            let mut b2: Vec<f64> = (0..n)
                .map(|r| (0..n).map(|c| 2.0 * dense[r][c] * x[c]).sum())
                .collect();
            llt.solve_in_place(&mut b2, 1).unwrap();
            for (got, want) in b2.iter().zip(&x[..n]) {
                assert!((got - want).abs() < 1e-9);
            }
        }
    }

    #[test]
    fn an_empty_system_factorises_and_solves_nothing() {
        let mut llt = BlockCholesky::new(0, &[]).unwrap();
        llt.factorize(&[]).unwrap();
        llt.solve_in_place(&mut [], 1).unwrap();
    }

    #[test]
    fn a_link_not_below_the_diagonal_is_refused() {
        for bad in [(0, 1), (1, 1), (2, 0)] {
            let err = BlockCholesky::new(2, &[bad]).unwrap_err();
            assert!(err.to_string().contains("below the diagonal"), "{err}");
        }
    }

    #[test]
    fn an_indefinite_matrix_is_refused_and_nothing_is_solved() {
        let (links, mut values, _) = spd(5, 3);
        let mut llt = BlockCholesky::new(5, &links).unwrap();
        // The first six values are the first diagonal block: a negative pivot.
        values[0] = -100.0;
        assert!(matches!(
            llt.factorize(&values),
            Err(CholeskyError::NotPositiveDefinite(_))
        ));
        let mut b = vec![1.0; 15];
        assert_eq!(
            llt.solve_in_place(&mut b, 1),
            Err(CholeskyError::NotFactorised)
        );
    }
}
