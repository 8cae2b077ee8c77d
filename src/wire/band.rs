//! A symmetric positive-definite banded matrix with a fixed half-bandwidth
//! and its L D Lᵀ factorisation in place: O(n p²) to factor, O(n p) to
//! solve, storage sized once at construction (nothing allocates after).
//!
//! The wire's implicit step assembles its Hessian here: with positions and
//! twists interleaved per node (x₀ θ₀ x₁ θ₁ …, four unknowns a node) every
//! energy term of a rod touches at most three consecutive nodes, so the
//! matrix is banded with half-bandwidth 10 whatever the node count.

/// Why a factorisation failed.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum BandError {
    /// A pivot was not positive (or not finite): the matrix is not SPD.
    #[error("pivot {row} is {pivot} (matrix not positive definite)")]
    NotPositive {
        /// Row of the failed pivot.
        row: usize,
        /// Its value.
        pivot: f64,
    },
}

/// The lower band of a symmetric n × n matrix: entry (i, j) for
/// i − p ≤ j ≤ i stored at `i (p + 1) + (j + p − i)`, so that a row's band
/// is contiguous in column order (the factorisation's inner products run
/// over two contiguous slices).
#[derive(Debug, Clone)]
pub struct BandMatrix {
    n: usize,
    cap: usize,
    p: usize,
    a: Vec<f64>,
    /// 1 / D after [`BandMatrix::factor`].
    dinv: Vec<f64>,
    /// Column scratch of the factorisation (unscaled, scaled): 2 (p + 1).
    col: Vec<f64>,
}

impl BandMatrix {
    /// A zero matrix of size up to `capacity` with half-bandwidth `p`.
    pub fn new(capacity: usize, p: usize) -> BandMatrix {
        BandMatrix {
            n: capacity,
            cap: capacity,
            p,
            a: vec![0.0; capacity * (p + 1)],
            dinv: vec![0.0; capacity],
            col: vec![0.0; 2 * (p + 1)],
        }
    }

    /// Current size.
    pub fn size(&self) -> usize {
        self.n
    }

    /// Half-bandwidth.
    pub fn bandwidth(&self) -> usize {
        self.p
    }

    /// Sets the active size (≤ capacity) and zeroes the active part.
    pub fn reset(&mut self, n: usize) {
        self.n = n.min(self.cap);
        let len = self.n * (self.p + 1);
        self.a[..len].fill(0.0);
    }

    /// Entry (i, j) of the symmetric matrix (0 outside the band).
    pub fn get(&self, i: usize, j: usize) -> f64 {
        let (i, j) = if i >= j { (i, j) } else { (j, i) };
        if i - j > self.p {
            0.0
        } else {
            self.a[i * (self.p + 1) + (j + self.p - i)]
        }
    }

    /// Adds `v` to entry (i, j) (and so to (j, i)); `|i − j|` must be within
    /// the band (checked in debug builds; ignored outside it otherwise).
    #[inline]
    pub fn add(&mut self, i: usize, j: usize, v: f64) {
        let (i, j) = if i >= j { (i, j) } else { (j, i) };
        debug_assert!(i - j <= self.p, "({i}, {j}) outside the band {}", self.p);
        if i - j <= self.p {
            self.a[i * (self.p + 1) + (j + self.p - i)] += v;
        }
    }

    /// Adds the symmetric block `m` (k × k, row-major, `m[r * k + c]`) at rows
    /// and columns `base..base + k`; only its lower triangle is read. `k`
    /// must not exceed the bandwidth + 1.
    #[inline]
    pub fn add_block(&mut self, base: usize, k: usize, m: &[f64]) {
        let (p, w) = (self.p, self.p + 1);
        debug_assert!(k <= w);
        for r in 0..k {
            let gi = base + r;
            // Row gi, columns base..=gi: contiguous in this layout.
            let start = gi * w + p - r;
            for (dst, src) in self.a[start..=start + r].iter_mut().zip(&m[r * k..r * k + r + 1]) {
                *dst += src;
            }
        }
    }

    #[inline]
    fn at(&self, i: usize, j: usize) -> usize {
        i * (self.p + 1) + (j + self.p - i)
    }

    /// Makes row and column `i` those of the identity (a fixed unknown).
    pub fn pin(&mut self, i: usize) {
        let p = self.p;
        for j in i.saturating_sub(p)..i {
            let k = self.at(i, j);
            self.a[k] = 0.0;
        }
        for r in i + 1..(i + p + 1).min(self.n) {
            let k = self.at(r, i);
            self.a[k] = 0.0;
        }
        let k = self.at(i, i);
        self.a[k] = 1.0;
    }

    /// Factorisation L D Lᵀ in place (L unit lower triangular, D diagonal):
    /// the strict lower band holds L, the diagonal D. Right-looking: each
    /// column, once scaled, updates the triangle of the band below it, so
    /// the only serial dependence is pivot to pivot (one division and one
    /// multiply–add a column); the inner products of a left-looking
    /// Cholesky are chains of dependent additions, and the square roots
    /// sit on that chain too (this was 2–4× slower at 512 unknowns).
    pub fn factor(&mut self) -> Result<(), BandError> {
        let (n, p) = (self.n, self.p);
        let w = p + 1;
        // Column k's entries below the diagonal, unscaled (c) and scaled
        // by 1/D_k (l).
        let (c, l) = self.col.split_at_mut(w);
        for k in 0..n {
            let d = self.a[k * w + p];
            if !(d > 0.0 && d.is_finite()) {
                return Err(BandError::NotPositive { row: k, pivot: d });
            }
            let inv = 1.0 / d;
            self.dinv[k] = inv;
            let m = p.min(n - 1 - k);
            for r in 1..=m {
                let idx = (k + r) * w + p - r;
                c[r] = self.a[idx];
                l[r] = c[r] * inv;
                self.a[idx] = l[r];
            }
            // A(k + r, k + s) −= L(k + r, k) D_k L(k + s, k), 1 ≤ s ≤ r:
            // row k + r, columns k + 1 ..= k + r, contiguous.
            for r in 1..=m {
                let lr = l[r];
                let row = (k + r) * w + p - r;
                for (dst, cs) in self.a[row + 1..=row + r].iter_mut().zip(&c[1..=r]) {
                    *dst -= lr * cs;
                }
            }
        }
        Ok(())
    }

    /// Solves (L D Lᵀ) x = b in place after [`BandMatrix::factor`]; `b`
    /// holds at least `size()` entries. Both sweeps go by columns of L
    /// (each solved unknown updates the next p), so the serial dependence
    /// is one multiply–add an unknown.
    pub fn solve(&self, b: &mut [f64]) {
        let (n, p) = (self.n, self.p);
        let w = p + 1;
        let b = &mut b[..n];
        // L y = b: y_k done, subtract L(k + r, k) y_k below it.
        for k in 0..n {
            let yk = b[k];
            let m = p.min(n - 1 - k);
            for r in 1..=m {
                b[k + r] -= self.a[(k + r) * w + p - r] * yk;
            }
        }
        for (bk, inv) in b.iter_mut().zip(&self.dinv[..n]) {
            *bk *= inv;
        }
        // Lᵀ x = z: x_i done, subtract L(i, k) x_i from x_k, k in i − p .. i
        // (row i of L, contiguous).
        for i in (0..n).rev() {
            let xi = b[i];
            let k0 = i.saturating_sub(p);
            let row = i * w + (k0 + p - i);
            for (bk, lik) in b[k0..i].iter_mut().zip(&self.a[row..row + (i - k0)]) {
                *bk -= lik * xi;
            }
        }
    }

    /// y = A x for the (unfactored) symmetric matrix.
    pub fn mul(&self, x: &[f64], y: &mut [f64]) {
        let n = self.n;
        y[..n].fill(0.0);
        for i in 0..n {
            y[i] += self.get(i, i) * x[i];
            for j in i.saturating_sub(self.p)..i {
                let v = self.get(i, j);
                y[i] += v * x[j];
                y[j] += v * x[i];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn banded_cholesky_solves_a_random_spd_system() {
        let (n, p) = (37, 10);
        let mut m = BandMatrix::new(40, p);
        m.reset(n);
        let mut s = 12345u64;
        let mut rnd = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        for i in 0..n {
            for j in i.saturating_sub(p)..i {
                m.add(i, j, rnd());
            }
            m.add(i, i, 2.0 * p as f64 + 1.0);
        }
        m.pin(5);
        assert_eq!(m.get(5, 4), 0.0);
        assert_eq!(m.get(7, 5), 0.0);
        let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
        let mut b = vec![0.0; n];
        m.mul(&x, &mut b);
        let a = m.clone();
        m.factor().unwrap();
        m.solve(&mut b);
        for i in 0..n {
            assert!((b[i] - x[i]).abs() < 1e-12, "{i}: {} vs {}", b[i], x[i]);
        }
        let mut bad = a;
        bad.add(3, 3, -1e3);
        assert!(matches!(bad.factor(), Err(BandError::NotPositive { row: 3, .. })));
    }

    /// Sizes below, at and just above the bandwidth, against a dense
    /// Gaussian elimination of the same matrix.
    #[test]
    fn banded_ldlt_matches_a_dense_solve_at_small_sizes() {
        let p = 4;
        for n in [1, 2, 4, 5, 6, 11] {
            let mut m = BandMatrix::new(12, p);
            m.reset(n);
            for i in 0..n {
                for j in i.saturating_sub(p)..i {
                    m.add(i, j, ((i * 7 + j * 3) % 5) as f64 * 0.3 - 0.6);
                }
                m.add(i, i, 4.0 + i as f64 * 0.1);
            }
            let mut dense: Vec<Vec<f64>> = (0..n).map(|i| (0..n).map(|j| m.get(i, j)).collect()).collect();
            let mut rhs: Vec<f64> = (0..n).map(|i| 1.0 + (i as f64).cos()).collect();
            let mut b = rhs.clone();
            m.factor().unwrap();
            m.solve(&mut b);
            for k in 0..n {
                for i in k + 1..n {
                    let f = dense[i][k] / dense[k][k];
                    for j in k..n {
                        dense[i][j] -= f * dense[k][j];
                    }
                    rhs[i] -= f * rhs[k];
                }
            }
            for i in (0..n).rev() {
                let s: f64 = (i + 1..n).map(|j| dense[i][j] * rhs[j]).sum();
                rhs[i] = (rhs[i] - s) / dense[i][i];
            }
            for i in 0..n {
                assert!((b[i] - rhs[i]).abs() < 1e-13, "n {n}, {i}: {} vs {}", b[i], rhs[i]);
            }
        }
    }
}
