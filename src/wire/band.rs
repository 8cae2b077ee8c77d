//! A symmetric positive-definite banded matrix with a fixed half-bandwidth
//! and its L D Lᵀ factorisation in place: O(n p²) to factor, O(n p) to
//! solve, storage sized once at construction (nothing allocates after).
//!
//! The wire's implicit step assembles its Hessian here: with positions and
//! twists interleaved per node (x₀ θ₀ x₁ θ₁ …, four unknowns a node) every
//! energy term of a rod touches at most three consecutive nodes, so the
//! matrix is banded with half-bandwidth 10 whatever the node count.

/// The half-bandwidth whose factorisation and solve run on fixed-size
/// windows (the wire's: x and θ interleaved, four unknowns a node).
pub const FAST_BAND: usize = 10;

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
/// is contiguous in column order (the factorisation's updates and the
/// backward solve run over contiguous slices of a row).
#[derive(Debug, Clone)]
pub struct BandMatrix {
    n: usize,
    cap: usize,
    p: usize,
    a: Vec<f64>,
    /// 1 / D after [`BandMatrix::factor`].
    dinv: Vec<f64>,
    /// Column scratch of the factorisation: p + 1.
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
            col: vec![0.0; p + 1],
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

    /// Adds Σ_q `w[q]` `v[q]` `v[q]`ᵀ (a symmetric block of rank ≤ R) at
    /// rows and columns `base..base + K`, straight into the band (a
    /// Gauss–Newton Hessian). `K` must not exceed the bandwidth + 1 and
    /// `base + K` the size (checked in debug builds; ignored otherwise).
    #[inline]
    pub fn add_gram<const K: usize, const R: usize>(&mut self, base: usize, v: &[[f64; K]; R], w: &[f64; R]) {
        let (p, wd) = (self.p, self.p + 1);
        debug_assert!(K <= wd && base + K <= self.n);
        if K == 0 || K > wd || base + K > self.n {
            return;
        }
        // Row base + r, columns base..=base + r, starts at first + r p.
        let first = base * wd + p;
        let win = &mut self.a[first..first + (K - 1) * p + K];
        for r in 0..K {
            let mut s = [0.0; R];
            for q in 0..R {
                s[q] = w[q] * v[q][r];
            }
            let row = &mut win[r * p..r * p + r + 1];
            for c in 0..r + 1 {
                let mut acc = 0.0;
                for q in 0..R {
                    acc += s[q] * v[q][c];
                }
                row[c] += acc;
            }
        }
    }

    /// Adds the symmetric 3 × 3 block `m` at (a, a) and (b, b) and −`m` at
    /// (b, a) (and so at (a, b)), with a + 3 ≤ b and b + 2 within the band
    /// of a (the Hessian of a spring between two points whose coordinates
    /// start at a and b); checked in debug builds, ignored otherwise.
    #[inline]
    #[allow(clippy::needless_range_loop)] // rows and columns of two blocks
    pub fn add_spring3(&mut self, a: usize, b: usize, m: &[[f64; 3]; 3]) {
        let (p, w) = (self.p, self.p + 1);
        debug_assert!(a + 3 <= b && b + 2 - a <= p && b + 3 <= self.n);
        if a + 3 > b || b + 2 - a > p || b + 3 > self.n {
            return;
        }
        for r in 0..3 {
            let ra = (a + r) * w + p - (a + r);
            let rb = (b + r) * w + p - (b + r);
            for c in 0..r + 1 {
                self.a[ra + a + c] += m[r][c];
                self.a[rb + b + c] += m[r][c];
            }
            for c in 0..3 {
                self.a[rb + a + c] -= m[r][c];
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
    /// sit on that chain too. The wire's bandwidth ([`FAST_BAND`]) has its
    /// own loops, whose lengths the compiler knows.
    pub fn factor(&mut self) -> Result<(), BandError> {
        if self.p == FAST_BAND {
            return self.factor_fast::<false>().map(|_| ());
        }
        self.factor_general::<false>().map(|_| ())
    }

    /// [`BandMatrix::factor`] (`INDEFINITE` false: every pivot must be
    /// positive) or [`BandMatrix::factor_indefinite`] (true: any nonzero
    /// pivot, the most negative one returned) for any bandwidth.
    fn factor_general<const INDEFINITE: bool>(&mut self) -> Result<Option<(usize, f64)>, BandError> {
        let (n, p) = (self.n, self.p);
        let w = p + 1;
        // Column k's entries below the diagonal, unscaled.
        let c = &mut self.col[..w];
        let mut worst: Option<(usize, f64)> = None;
        for k in 0..n {
            let d = self.a[k * w + p];
            pivot_check::<INDEFINITE>(k, d, &mut worst)?;
            let inv = 1.0 / d;
            self.dinv[k] = inv;
            let m = p.min(n - 1 - k);
            // (Exclusive ranges: an inclusive one's loop does not compile
            // to a counted loop.)
            for r in 1..m + 1 {
                // L(k + r, k), then A(k + r, k + s) −= L(k + r, k) D_k
                // L(k + s, k) for 1 ≤ s ≤ r: row k + r from column k + 1
                // to its diagonal, contiguous.
                let idx = (k + r) * w + p - r;
                let cr = self.a[idx];
                c[r] = cr;
                let lr = cr * inv;
                self.a[idx] = lr;
                for (dst, cs) in self.a[idx + 1..idx + r + 1].iter_mut().zip(&c[1..r + 1]) {
                    *dst -= lr * cs;
                }
            }
        }
        Ok(worst)
    }

    /// [`BandMatrix::factor`] (`INDEFINITE` false) or
    /// [`BandMatrix::factor_indefinite`] (true) for p = [`FAST_BAND`]: the
    /// same operations in the same order, on fixed-size windows.
    #[allow(clippy::needless_range_loop)] // the band's index arithmetic
    fn factor_fast<const INDEFINITE: bool>(&mut self) -> Result<Option<(usize, f64)>, BandError> {
        const P: usize = FAST_BAND;
        const W: usize = P + 1;
        let n = self.n;
        let mut c = [0.0; P];
        let mut worst: Option<(usize, f64)> = None;
        for k in 0..n {
            let d = self.a[k * W + P];
            pivot_check::<INDEFINITE>(k, d, &mut worst)?;
            let inv = 1.0 / d;
            self.dinv[k] = inv;
            let base = k * W + P;
            if k + P < n {
                // Rows k..=k + P from A(k, k): A(k + r, k + s) at r P + s.
                let Ok(blk) = <&mut [f64; P * W + 1]>::try_from(&mut self.a[base..base + P * W + 1]) else {
                    return Err(BandError::NotPositive {
                        row: k,
                        pivot: f64::NAN,
                    });
                };
                for r in 0..P {
                    let idx = (r + 1) * P;
                    let cr = blk[idx];
                    c[r] = cr;
                    let lr = cr * inv;
                    blk[idx] = lr;
                    for s in 0..r + 1 {
                        blk[idx + 1 + s] -= lr * c[s];
                    }
                }
            } else {
                for r in 0..n - 1 - k {
                    let idx = base + (r + 1) * P;
                    let cr = self.a[idx];
                    c[r] = cr;
                    let lr = cr * inv;
                    self.a[idx] = lr;
                    for s in 0..r + 1 {
                        self.a[idx + 1 + s] -= lr * c[s];
                    }
                }
            }
        }
        Ok(worst)
    }

    /// Solves (L D Lᵀ) x = b in place after [`BandMatrix::factor`]; `b`
    /// holds at least `size()` entries. Both sweeps go by columns of L
    /// (each solved unknown updates the next p), so the serial dependence
    /// is one multiply–add an unknown.
    pub fn solve(&self, b: &mut [f64]) {
        let (n, p) = (self.n, self.p);
        let w = p + 1;
        let b = &mut b[..n];
        let fast = p == FAST_BAND;
        // L y = b: y_k done, subtract L(k + r, k) y_k below it; L(k + r, k)
        // is at k w + p + r p.
        for k in 0..n {
            let yk = b[k];
            let base = k * w + p;
            if fast && k + FAST_BAND < n {
                const P: usize = FAST_BAND;
                let (Ok(col), Ok(dst)) = (
                    <&[f64; P * P + 1]>::try_from(&self.a[base..base + P * P + 1]),
                    <&mut [f64; P]>::try_from(&mut b[k + 1..k + 1 + P]),
                ) else {
                    return;
                };
                for r in 0..P {
                    dst[r] -= col[(r + 1) * P] * yk;
                }
            } else {
                for r in 1..p.min(n - 1 - k) + 1 {
                    b[k + r] -= self.a[base + r * p] * yk;
                }
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
            if fast && i >= FAST_BAND {
                const P: usize = FAST_BAND;
                let (Ok(l), Ok(dst)) = (
                    <&[f64; P]>::try_from(&self.a[row..row + P]),
                    <&mut [f64; P]>::try_from(&mut b[k0..i]),
                ) else {
                    return;
                };
                for t in 0..P {
                    dst[t] -= l[t] * xi;
                }
            } else {
                for (bk, lik) in b[k0..i].iter_mut().zip(&self.a[row..row + (i - k0)]) {
                    *bk -= lik * xi;
                }
            }
        }
    }

    /// Makes this matrix a copy of `o` (same bandwidth, size within this
    /// capacity), without allocating.
    pub fn copy_from(&mut self, o: &BandMatrix) {
        debug_assert_eq!(self.p, o.p);
        self.n = o.n.min(self.cap);
        let len = self.n * (self.p + 1);
        self.a[..len].copy_from_slice(&o.a[..len]);
    }

    /// L D Lᵀ in place (as [`BandMatrix::factor`], without pivoting) of a
    /// symmetric matrix that may be indefinite: a pivot may be negative,
    /// only a zero or non-finite one fails. Returns the most negative
    /// pivot's row and value, if any.
    ///
    /// Why: by Sylvester's law of inertia D has as many negative entries
    /// as the matrix has negative eigenvalues, and for a negative pivot
    /// d_k the vector v with Lᵀ v = e_k ([`BandMatrix::unit_back_solve`])
    /// is a direction of negative curvature, vᵀ A v = d_k (the modified
    /// Cholesky's test: Gill, Murray and Wright, *Practical
    /// Optimization*, 1981, §4.4.2). The wire's buckling check uses it
    /// on the static Hessian.
    pub fn factor_indefinite(&mut self) -> Result<Option<(usize, f64)>, BandError> {
        if self.p == FAST_BAND {
            return self.factor_fast::<true>();
        }
        self.factor_general::<true>()
    }

    /// After a factorisation: v with Lᵀ v = e_k (zero beyond k), into
    /// `v[..size()]`. For a negative pivot d_k, vᵀ A v = d_k.
    pub fn unit_back_solve(&self, k: usize, v: &mut [f64]) {
        let (n, p) = (self.n, self.p);
        let w = p + 1;
        let v = &mut v[..n];
        v.fill(0.0);
        if k >= n {
            return;
        }
        v[k] = 1.0;
        for i in (0..k + 1).rev() {
            let xi = v[i];
            let k0 = i.saturating_sub(p);
            let row = i * w + (k0 + p - i);
            for (bk, lik) in v[k0..i].iter_mut().zip(&self.a[row..row + (i - k0)]) {
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

/// The pivot rule of both factorisation loops: a positive finite pivot for
/// the definite factorisation; for the indefinite one any nonzero finite
/// pivot, keeping the most negative in `worst`.
#[inline(always)]
fn pivot_check<const INDEFINITE: bool>(k: usize, d: f64, worst: &mut Option<(usize, f64)>) -> Result<(), BandError> {
    if INDEFINITE {
        if d == 0.0 || !d.is_finite() {
            return Err(BandError::NotPositive { row: k, pivot: d });
        }
        if d < 0.0 && worst.is_none_or(|(_, v)| d < v) {
            *worst = Some((k, d));
        }
    } else if !(d > 0.0 && d.is_finite()) {
        return Err(BandError::NotPositive { row: k, pivot: d });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_indefinite_band_gives_its_negative_curvature() {
        // A chain of springs under compression: tridiagonal 2 − c on the
        // diagonal, −1 off it; its least eigenvalue is 2 − c − 2 cos(π/(n+1)).
        let n = 30;
        for (c, negative) in [(0.0, false), (0.05, true)] {
            let mut m = BandMatrix::new(n, 10);
            m.reset(n);
            for i in 0..n {
                m.add(i, i, 2.0 - c);
                if i > 0 {
                    m.add(i, i - 1, -1.0);
                }
            }
            let a = m.clone();
            // The general loop (a wider band) finds the same pivot as the
            // fixed-window one the wire's bandwidth takes.
            let mut wide = BandMatrix::new(n, FAST_BAND + 1);
            wide.reset(n);
            for i in 0..n {
                for j in i.saturating_sub(1)..i + 1 {
                    wide.add(i, j, m.get(i, j));
                }
            }
            let worst = m.factor_indefinite().expect("no zero pivot");
            assert_eq!(wide.factor_indefinite().expect("no zero pivot"), worst);
            assert_eq!(worst.is_some(), negative, "c = {c}");
            if let Some((k, d)) = worst {
                let mut v = vec![0.0; n];
                m.unit_back_solve(k, &mut v);
                let mut av = vec![0.0; n];
                a.mul(&v, &mut av);
                let q: f64 = v.iter().zip(&av).map(|(x, y)| x * y).sum();
                assert!((q - d).abs() <= 1e-9 * d.abs(), "vᵀAv {q} against the pivot {d}");
            }
        }
    }

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
    #[allow(clippy::needless_range_loop)] // the textbook elimination
    fn banded_ldlt_matches_a_dense_solve_at_small_sizes() {
        for (p, n) in [4, 10]
            .into_iter()
            .flat_map(|p| [1, 2, 4, 5, 6, 10, 11, 12, 23].map(|n| (p, n)))
        {
            let mut m = BandMatrix::new(24, p);
            m.reset(n);
            for i in 0..n {
                for j in i.saturating_sub(p)..i {
                    m.add(i, j, ((i * 7 + j * 3) % 5) as f64 * 0.3 - 0.6);
                }
                m.add(i, i, 1.2 * p as f64 + 1.0 + i as f64 * 0.1);
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
                assert!(
                    (b[i] - rhs[i]).abs() < 1e-13,
                    "p {p}, n {n}, {i}: {} vs {}",
                    b[i],
                    rhs[i]
                );
            }
        }
    }
}
