//! The local residual compliance: what the reduced basis misses of the full
//! model's static response, near every surface node, so that the haptic
//! loop renders the right stiffness wherever the tool touches.
//!
//! A reduced model u ≈ Φ q is stiffer than the full one: a force f at the
//! surface moves the full model by K⁻¹ f but the reduced one only by
//! Φ K_r⁻¹ Φᵀ f (K_r = ΦᵀKΦ, the Ritz approximation, which never
//! over-estimates compliance). The difference
//!
//! ```text
//! ΔW = K⁻¹ − Φ K_r⁻¹ Φᵀ        (positive semi-definite)
//! ```
//!
//! is the *residual* compliance, the static correction of the
//! mode-acceleration method. It is local: the low modes carry the far
//! field, so ΔW_ij dies out within a few wall thicknesses of node i. We keep
//! the 3×3 blocks ΔW_ij for every surface node i and every surface node j
//! within `couple_radius_m` or in i's surface 2-ring (the nodes of the
//! triangles around its neighbours), which covers one contact patch, however
//! coarse the mesh, and the coupling between nearby patches.
//!
//! **Computation by probing.** The nodes are coloured so that two nodes of a
//! colour are at least `separation_m` apart (greedy, on a spatial grid). For
//! each colour and axis one right-hand side b = Σ eᵢ (unit loads at all the
//! colour's nodes along the axis) gives r = K⁻¹ b − Φ K_r⁻¹ Φᵀ b with one
//! solve on a sparse Cholesky factor of K; near node i, r is ΔW·eᵢ because
//! the residual response of the other nodes of the colour has died out by
//! then. The cost is 3 × (number of colours) solves instead of 3 per node
//! (measured in docs/BENCHMARKS.md, "Contact anywhere"); the truncation
//! error is measured against exact columns in the tests.
//!
//! **Use.** The loop adds ΔW in series with the contact penalty
//! ([`crate::haptics::contact`]): the node forces of a patch solve
//! (K_p⁻¹ + S) p = d, S_ab = n_aᵀ ΔW_ab n_b, so the patch's static stiffness
//! is the full model's at once, and the reduced dynamics carries the rest.

use crate::math::{Mat3, Vec3};
use crate::mesh::TetMesh;
use crate::model::BlockTangent;
use crate::reduced::ModalBasis;
use crate::solver::linear::{project_fixed, CholeskySolver};
use nalgebra::{DMatrix, DVector};

/// Probing right-hand sides solved together (one block triangular solve).
const PROBE_BATCH: usize = 48;

/// How the table is built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ComplianceParams {
    /// Blocks ΔW_ij are kept for surface nodes j within this distance of i
    /// (rest positions, m).
    pub couple_radius_m: f64,
    /// Two nodes probed by the same right-hand side are at least this far
    /// apart (m); larger is more exact and slower.
    pub separation_m: f64,
}

impl Default for ComplianceParams {
    fn default() -> Self {
        ComplianceParams {
            couple_radius_m: 6e-3,
            separation_m: 40e-3,
        }
    }
}

/// What building the table cost.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct ComplianceStats {
    /// Colours (right-hand sides per axis).
    pub colours: usize,
    /// Sparse triangular solves.
    pub solves: usize,
    /// Stored 3×3 blocks.
    pub blocks: usize,
    /// Wall time (s).
    pub seconds: f64,
}

/// ΔW near every surface node: for node i, the blocks ΔW_ij of the surface
/// nodes j within the coupling radius (sorted by j, i itself included).
#[derive(Debug, Clone)]
pub struct LocalCompliance {
    offsets: Vec<u32>,
    cols: Vec<u32>,
    blocks: Vec<Mat3>,
    /// The largest rest distance between i and j over the stored blocks.
    reach: f64,
    /// Unique to the computation that built it (copies share it): lets a
    /// user keep blocks it looked up and know when they are stale.
    id: u64,
}

impl PartialEq for LocalCompliance {
    /// Same blocks (the identity is not compared).
    fn eq(&self, other: &Self) -> bool {
        self.offsets == other.offsets
            && self.cols == other.cols
            && self.blocks == other.blocks
            && self.reach == other.reach
    }
}

/// The next [`LocalCompliance::id`] (0 is never given).
static NEXT_TABLE_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

/// A uniform grid over points for radius queries (build-time only).
struct Grid {
    lo: Vec3,
    cell: f64,
    dims: [usize; 3],
    cells: std::collections::HashMap<usize, Vec<u32>>,
}

impl Grid {
    fn new(points: &[Vec3], ids: &[u32], cell: f64) -> Grid {
        let mut lo = Vec3::repeat(f64::INFINITY);
        let mut hi = Vec3::repeat(f64::NEG_INFINITY);
        for &i in ids {
            lo = lo.inf(&points[i as usize]);
            hi = hi.sup(&points[i as usize]);
        }
        if ids.is_empty() {
            lo = Vec3::zeros();
            hi = Vec3::zeros();
        }
        let cell = cell.max(1e-9);
        let dims = [0, 1, 2].map(|k| ((hi[k] - lo[k]) / cell).floor() as usize + 1);
        let mut g = Grid {
            lo,
            cell,
            dims,
            cells: std::collections::HashMap::new(),
        };
        for &i in ids {
            let c = g.key(&points[i as usize]);
            g.cells.entry(c).or_default().push(i);
        }
        g
    }

    fn coord(&self, x: &Vec3) -> [usize; 3] {
        [0, 1, 2].map(|k| (((x[k] - self.lo[k]) / self.cell).floor().max(0.0) as usize).min(self.dims[k] - 1))
    }

    fn key(&self, x: &Vec3) -> usize {
        let c = self.coord(x);
        (c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]
    }

    /// Ids within `r` of `x` (r ≤ cell).
    fn near(&self, points: &[Vec3], x: &Vec3, r: f64, out: &mut Vec<u32>) {
        out.clear();
        let c = self.coord(x);
        for dz in -1i64..=1 {
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let q = [c[0] as i64 + dx, c[1] as i64 + dy, c[2] as i64 + dz];
                    if (0..3).any(|k| q[k] < 0 || q[k] >= self.dims[k] as i64) {
                        continue;
                    }
                    let key = (q[2] as usize * self.dims[1] + q[1] as usize) * self.dims[0] + q[0] as usize;
                    if let Some(v) = self.cells.get(&key) {
                        out.extend(v.iter().copied().filter(|&j| (points[j as usize] - x).norm() <= r));
                    }
                }
            }
        }
    }
}

impl LocalCompliance {
    /// Builds the table for `basis` at the tangent `k` (the full model's K at
    /// the basis's linearization point; fixed nodes as in the basis) over the
    /// surface nodes of `mesh`.
    pub fn compute(
        mesh: &TetMesh,
        k: &BlockTangent,
        basis: &ModalBasis,
        params: &ComplianceParams,
    ) -> Result<(LocalCompliance, ComplianceStats), String> {
        let t0 = std::time::Instant::now();
        let n = mesh.num_nodes();
        if basis.phi.nrows() != 3 * n || k.diag.len() != n {
            return Err(format!(
                "local compliance: basis ({} rows) or tangent ({} nodes) does not match the mesh ({n} nodes)",
                basis.phi.nrows(),
                k.diag.len()
            ));
        }
        if !(params.couple_radius_m > 0.0 && params.separation_m >= 2.0 * params.couple_radius_m) {
            return Err(format!(
                "local compliance: need couple_radius_m > 0 and separation_m >= 2 couple_radius_m, got {} and {}",
                params.couple_radius_m, params.separation_m
            ));
        }
        let rest = mesh.rest();
        let mut fixed = vec![false; n];
        for &f in &basis.fixed {
            if let Some(m) = fixed.get_mut(f as usize) {
                *m = true;
            }
        }
        let surface: Vec<u32> = mesh
            .surface_nodes()
            .into_iter()
            .filter(|&i| !fixed[i as usize])
            .collect();

        // K with the fixed rows pinned, factored once.
        let mut kf = k.clone();
        project_fixed(&mut kf, &fixed);
        let mut chol = CholeskySolver::new(&kf)?;
        chol.factor(&kf)
            .map_err(|e| format!("local compliance: factor of K: {e:?}"))?;
        // K_r = Φᵀ K Φ and its inverse (dense, r × r).
        let phi = &basis.phi;
        let r = phi.ncols();
        let mut kphi = DMatrix::zeros(3 * n, r);
        {
            let rows = crate::solver::linear::BlockRows::new(n, &kf.edges);
            let mut x = vec![Vec3::zeros(); n];
            let mut y = vec![Vec3::zeros(); n];
            for c in 0..r {
                for i in 0..n {
                    x[i] = Vec3::new(phi[(3 * i, c)], phi[(3 * i + 1, c)], phi[(3 * i + 2, c)]);
                }
                rows.mul(&kf, &x, &mut y, false);
                for i in 0..n {
                    for a in 0..3 {
                        kphi[(3 * i + a, c)] = y[i][a];
                    }
                }
            }
        }
        let kr = phi.transpose() * &kphi;
        let kr = (&kr + kr.transpose()) * 0.5;
        let kr_inv = kr
            .cholesky()
            .ok_or("local compliance: the reduced stiffness is not positive definite")?
            .inverse();

        // Neighbours within the coupling radius, and the colouring.
        let near_grid = Grid::new(rest, &surface, params.couple_radius_m);
        let mut nbrs: Vec<Vec<u32>> = vec![Vec::new(); n];
        let mut tmp = Vec::new();
        // The surface 1-ring of every node (triangle mates).
        let mut ring: Vec<Vec<u32>> = vec![Vec::new(); n];
        for t in mesh.surface() {
            for &a in t {
                for &b in t {
                    if !fixed[b as usize] {
                        ring[a as usize].push(b);
                    }
                }
            }
        }
        for r in ring.iter_mut() {
            r.sort_unstable();
            r.dedup();
        }
        let mut reach = 0.0f64;
        for &i in &surface {
            near_grid.near(rest, &rest[i as usize], params.couple_radius_m, &mut tmp);
            // A contact patch spans the triangles around its point: keep
            // the surface 2-ring too, however coarse the mesh.
            for &v in &ring[i as usize] {
                tmp.extend_from_slice(&ring[v as usize]);
            }
            tmp.sort_unstable();
            tmp.dedup();
            for &j in &tmp {
                reach = reach.max((rest[j as usize] - rest[i as usize]).norm());
            }
            nbrs[i as usize] = tmp.clone();
        }
        // Probes of one colour far enough apart for the farthest block kept.
        let separation = params.separation_m.max(2.0 * reach);
        let colour_grid = Grid::new(rest, &surface, separation);
        let mut colour_of = vec![u32::MAX; n];
        let mut colours: Vec<Vec<u32>> = Vec::new();
        for &i in &surface {
            colour_grid.near(rest, &rest[i as usize], separation, &mut tmp);
            let mut used: Vec<u32> = tmp
                .iter()
                .map(|&j| colour_of[j as usize])
                .filter(|&c| c != u32::MAX)
                .collect();
            used.sort_unstable();
            used.dedup();
            let c = (0..).find(|c| used.binary_search(c).is_err()).unwrap_or(0);
            colour_of[i as usize] = c;
            if c as usize == colours.len() {
                colours.push(Vec::new());
            }
            colours[c as usize].push(i);
        }

        // Probe: per colour and axis, r = K⁻¹ b − Φ K_r⁻¹ Φᵀ b.
        let mut offsets = vec![0u32; n + 1];
        for i in 0..n {
            offsets[i + 1] = offsets[i] + nbrs[i].len() as u32;
        }
        let cols: Vec<u32> = nbrs.iter().flatten().copied().collect();
        let mut blocks = vec![Mat3::zeros(); cols.len()];
        // Right-hand sides (colour, axis), solved PROBE_BATCH at a time.
        let probes: Vec<(usize, usize)> = (0..colours.len()).flat_map(|c| (0..3).map(move |a| (c, a))).collect();
        let dofs = 3 * n;
        let mut block = vec![0.0; dofs * PROBE_BATCH.min(probes.len().max(1))];
        let mut solves = 0;
        for batch in probes.chunks(PROBE_BATCH) {
            let width = batch.len();
            let xs = &mut block[..dofs * width];
            xs.iter_mut().for_each(|v| *v = 0.0);
            for (col, &(colour, axis)) in batch.iter().enumerate() {
                for &i in &colours[colour] {
                    xs[col * dofs + 3 * i as usize + axis] = 1.0;
                }
            }
            chol.solve_factored_columns(xs)
                .map_err(|e| format!("local compliance: solve: {e:?}"))?;
            solves += width;
            for (col, &(colour, axis)) in batch.iter().enumerate() {
                let x = &xs[col * dofs..(col + 1) * dofs];
                let members = &colours[colour];
                // Φᵀ b is the sum of the probed nodes' rows.
                let mut pb = DVector::zeros(r);
                for &i in members {
                    for c in 0..r {
                        pb[c] += phi[(3 * i as usize + axis, c)];
                    }
                }
                let q = &kr_inv * pb;
                for &i in members {
                    // Column `axis` of ΔW_ji for every neighbour j of i.
                    for &j in &nbrs[i as usize] {
                        let ju = j as usize;
                        let (lo, hi) = (offsets[ju] as usize, offsets[ju + 1] as usize);
                        if let Ok(p) = cols[lo..hi].binary_search(&i) {
                            for a in 0..3 {
                                let red: f64 = (0..r).map(|c| phi[(3 * ju + a, c)] * q[c]).sum();
                                blocks[lo + p][(a, axis)] = x[3 * ju + a] - red;
                            }
                        }
                    }
                }
            }
        }
        // Symmetrize: ΔW_ij = ΔW_jiᵀ.
        for i in 0..n {
            for p in offsets[i] as usize..offsets[i + 1] as usize {
                let j = cols[p] as usize;
                if j < i {
                    continue;
                }
                let (lo, hi) = (offsets[j] as usize, offsets[j + 1] as usize);
                if let Ok(q) = cols[lo..hi].binary_search(&(i as u32)) {
                    let s = (blocks[p] + blocks[lo + q].transpose()) * 0.5;
                    blocks[p] = s;
                    blocks[lo + q] = s.transpose();
                }
            }
        }
        let stats = ComplianceStats {
            colours: colours.len(),
            solves,
            blocks: blocks.len(),
            seconds: t0.elapsed().as_secs_f64(),
        };
        Ok((
            LocalCompliance {
                offsets,
                cols,
                blocks,
                reach,
                id: NEXT_TABLE_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
            },
            stats,
        ))
    }

    /// The largest rest distance between two nodes with a stored block
    /// (m): nodes farther apart than this have none (ΔW_ij taken as 0).
    pub fn reach(&self) -> f64 {
        self.reach
    }

    /// An identity unique to the computation that built this table (never
    /// 0; a clone keeps it): blocks looked up from a table with the same id
    /// are still valid.
    pub fn id(&self) -> u64 {
        self.id
    }

    /// ΔW_ij (m/N) if j is within the coupling radius of i or in its surface
    /// 2-ring, else None.
    /// Allocates nothing.
    pub fn block(&self, i: u32, j: u32) -> Option<&Mat3> {
        let i = i as usize;
        if i + 1 >= self.offsets.len() {
            return None;
        }
        let (lo, hi) = (self.offsets[i] as usize, self.offsets[i + 1] as usize);
        self.cols[lo..hi].binary_search(&j).ok().map(|p| &self.blocks[lo + p])
    }

    /// The stored blocks of row i: (j, ΔW_ij) for every j kept near i
    /// (none for a node outside the table). Allocates nothing.
    pub fn row(&self, i: u32) -> impl Iterator<Item = (u32, &Mat3)> {
        let i = i as usize;
        let (lo, hi) = if i + 1 < self.offsets.len() {
            (self.offsets[i] as usize, self.offsets[i + 1] as usize)
        } else {
            (0, 0)
        };
        self.cols[lo..hi].iter().copied().zip(&self.blocks[lo..hi])
    }

    /// Stored blocks.
    pub fn num_blocks(&self) -> usize {
        self.blocks.len()
    }
}

/// Exact static compliance blocks (K⁻¹)_ij of a tangent with fixed nodes
/// pinned, from one Cholesky factor: for checks and experiments (not the
/// haptic loop).
pub struct ExactCompliance {
    chol: CholeskySolver,
    mask: Vec<bool>,
    b: Vec<Vec3>,
    x: Vec<Vec3>,
}

impl ExactCompliance {
    /// Factors `k` with the `fixed` nodes pinned.
    pub fn new(k: &BlockTangent, fixed: &[u32]) -> Result<ExactCompliance, String> {
        let n = k.diag.len();
        let mut mask = vec![false; n];
        for &f in fixed {
            if let Some(m) = mask.get_mut(f as usize) {
                *m = true;
            }
        }
        let mut kf = k.clone();
        project_fixed(&mut kf, &mask);
        let mut chol = CholeskySolver::new(&kf)?;
        chol.factor(&kf).map_err(|e| format!("factor: {e:?}"))?;
        Ok(ExactCompliance {
            chol,
            mask,
            b: vec![Vec3::zeros(); n],
            x: vec![Vec3::zeros(); n],
        })
    }

    /// (K⁻¹)_SS for S = `nodes`: a 3m × 3m matrix, node-major; 3m solves.
    pub fn blocks(&mut self, nodes: &[u32]) -> Result<DMatrix<f64>, String> {
        let m = nodes.len();
        let mut w = DMatrix::zeros(3 * m, 3 * m);
        for (cj, &j) in nodes.iter().enumerate() {
            for axis in 0..3 {
                self.b.iter_mut().for_each(|v| *v = Vec3::zeros());
                if !self.mask.get(j as usize).copied().unwrap_or(true) {
                    self.b[j as usize][axis] = 1.0;
                }
                self.chol
                    .solve_factored(&self.b, &mut self.x)
                    .map_err(|e| format!("solve: {e:?}"))?;
                for (ci, &i) in nodes.iter().enumerate() {
                    for a in 0..3 {
                        let fixed = self.mask.get(i as usize).copied().unwrap_or(true);
                        w[(3 * ci + a, 3 * cj + axis)] = if fixed { 0.0 } else { self.x[i as usize][a] };
                    }
                }
            }
        }
        Ok(w)
    }
}
