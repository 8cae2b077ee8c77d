//! Contact between the tool (a sphere at the stylus tip) and the deformed
//! vessel surface, as an area-weighted penalty on the surface nodes:
//!
//! ```text
//! dᵢ = ρ − ‖xᵢ − c‖ > 0,   nᵢ = (xᵢ − c)/‖xᵢ − c‖,   fᵢ = k_p Aᵢ dᵢ nᵢ,   F_tool = −Σ fᵢ
//! ```
//!
//! with c, ρ the tool centre and radius, xᵢ = Xᵢ + ūᵢ + Φᵢ δq the deformed
//! node, Aᵢ its share of the surface area (a third of its triangles' areas)
//! and k_p a pressure stiffness (Pa/m), so the force does not depend on the
//! mesh resolution. fᵢ pushes the tissue, F_tool is the reaction on the tool.
//!
//! A uniform grid over the surface nodes' rest positions (built at start)
//! gives the candidates near the tool; only those nodes are reconstructed
//! from the reduced coordinates each tick, so the cost follows the contact
//! patch, not the mesh. A node can be found only while its displacement stays
//! under the search margin, which is therefore part of the configuration.
//!
//! For the implicit reduced step the contact also gives its reduced stiffness
//! K_c = Σ k_p Aᵢ (Φᵢᵀnᵢ)(Φᵢᵀnᵢ)ᵀ (the normal part of −∂f/∂q, positive
//! semi-definite); see [`crate::reduced::ReducedDynamics::step_with_contact`].
//!
//! **Contact anywhere** ([`evaluate_with`] with a
//! [`LocalCompliance`]): the reduced model alone is too stiff where its basis
//! has no static mode. The residual compliance ΔW (what the basis misses of
//! K⁻¹, see [`crate::reduced::compliance`]) acts in series with the penalty:
//! the normal forces p of the touched nodes solve the small system
//!
//! ```text
//! (K_p⁻¹ + S) p = d,   S_ab = n_aᵀ ΔW_ab n_b,   p ≥ 0 (nodes with p < 0 leave)
//! ```
//!
//! (d the penetrations of the reduced surface, K_p = diag(k_p A_a)), which
//! couples the nodes of a patch and of nearby patches; the reduced stiffness
//! becomes K_c = G (K_p⁻¹ + S)⁻¹ Gᵀ with G = [Φ_aᵀ n_a]. At static
//! equilibrium the patch then sees exactly (K_p⁻¹ + (K⁻¹)_SS)⁻¹: the full
//! model's local stiffness, at any surface point, several patches at once,
//! for a cost that follows the number of touched nodes (at most
//! [`MAX_COMPLIANT_NODES`] are corrected; more are counted).

use crate::math::Vec3;
use crate::mesh::TetMesh;
use crate::reduced::compliance::LocalCompliance;
use nalgebra::{SMatrix, SVector};

/// Candidate capacity of one query (a larger patch is truncated and counted).
pub const MAX_CANDIDATES: usize = 4096;
/// Capacity of the touched-node list of one tick.
pub const MAX_CONTACT_NODES: usize = 256;
/// Tool spheres one contact evaluation takes ([`evaluate_spheres`]).
pub const MAX_SPHERES: usize = 32;
/// Touched nodes whose residual compliance is applied in one tick (the
/// deepest ones; the others keep the plain penalty and are counted).
pub const MAX_COMPLIANT_NODES: usize = 32;

/// Contact parameters.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ContactParams {
    /// Tool sphere radius ρ (m).
    pub tool_radius_m: f64,
    /// Pressure stiffness k_p (Pa/m = N/m³): force per node = k_p · area · depth.
    pub pressure_stiffness: f64,
    /// How far a surface node may move from rest and still be found (m).
    pub search_margin_m: f64,
}

impl Default for ContactParams {
    fn default() -> Self {
        ContactParams {
            tool_radius_m: 3e-3,
            pressure_stiffness: 1e8,
            search_margin_m: 8e-3,
        }
    }
}

/// The spatial index of the surface nodes (rest positions) and their areas.
#[derive(Debug, Clone)]
pub struct SurfaceIndex {
    origin: Vec3,
    cell: f64,
    dims: [usize; 3],
    cell_start: Vec<u32>,
    nodes: Vec<u32>,
    rest: Vec<Vec3>,
    area: Vec<f64>,
    normal: Vec<Vec3>,
    reach: f64,
}

impl SurfaceIndex {
    /// Indexes the surface nodes of `mesh` for a tool of radius `params.tool_radius_m`
    /// and displacements up to `params.search_margin_m`.
    pub fn new(mesh: &TetMesh, params: &ContactParams) -> SurfaceIndex {
        let rest = mesh.rest().to_vec();
        let mut area = vec![0.0; rest.len()];
        for t in mesh.surface() {
            let [a, b, c] = t.map(|i| rest[i as usize]);
            let w = (b - a).cross(&(c - a)).norm() / 6.0;
            for &i in t {
                area[i as usize] += w;
            }
        }
        let normal = mesh.surface_vertex_normals();
        let surface = mesh.surface_nodes();
        let reach = params.tool_radius_m + params.search_margin_m;
        let (mut lo, mut hi) = (Vec3::repeat(f64::INFINITY), Vec3::repeat(f64::NEG_INFINITY));
        for &i in &surface {
            lo = lo.inf(&rest[i as usize]);
            hi = hi.sup(&rest[i as usize]);
        }
        if surface.is_empty() {
            lo = Vec3::zeros();
            hi = Vec3::zeros();
        }
        // Cells about the query size; coarser if the grid would be huge.
        let mut cell = reach.max(1e-6);
        let ext = hi - lo;
        let dims = loop {
            let d = [0, 1, 2].map(|k| ((ext[k] / cell).floor() as usize + 1).max(1));
            if d[0] * d[1] * d[2] <= 1 << 22 {
                break d;
            }
            cell *= 2.0;
        };
        let ncell = dims[0] * dims[1] * dims[2];
        let cell_of = |x: &Vec3| -> usize {
            let idx = [0, 1, 2].map(|k| (((x[k] - lo[k]) / cell).floor().max(0.0) as usize).min(dims[k] - 1));
            (idx[2] * dims[1] + idx[1]) * dims[0] + idx[0]
        };
        let mut count = vec![0u32; ncell + 1];
        for &i in &surface {
            count[cell_of(&rest[i as usize]) + 1] += 1;
        }
        for c in 0..ncell {
            count[c + 1] += count[c];
        }
        let mut fill = count.clone();
        let mut nodes = vec![0u32; surface.len()];
        for &i in &surface {
            let c = cell_of(&rest[i as usize]);
            nodes[fill[c] as usize] = i;
            fill[c] += 1;
        }
        SurfaceIndex {
            origin: lo,
            cell,
            dims,
            cell_start: count,
            nodes,
            rest,
            area,
            normal,
            reach,
        }
    }

    /// Number of indexed surface nodes.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// Whether no node is indexed.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// Rest position of node `i`.
    pub fn rest(&self, i: u32) -> Vec3 {
        self.rest[i as usize]
    }

    /// Surface area share of node `i` (m², 0 for interior nodes).
    pub fn area(&self, i: u32) -> f64 {
        self.area[i as usize]
    }

    /// Outward rest normal of surface node `i`.
    pub fn normal(&self, i: u32) -> Vec3 {
        self.normal[i as usize]
    }

    /// The surface nodes whose rest position is within tool radius + margin
    /// of `center`, into `out` (cleared first). Returns false if `out`
    /// overflowed (the list is then truncated). Allocates nothing.
    pub fn query<const N: usize>(&self, center: &Vec3, out: &mut heapless::Vec<u32, N>) -> bool {
        out.clear();
        if self.nodes.is_empty() || !center.iter().all(|v| v.is_finite()) {
            return true;
        }
        let r2 = self.reach * self.reach;
        let mut range = [(0usize, 0usize); 3];
        for k in 0..3 {
            let a = ((center[k] - self.reach - self.origin[k]) / self.cell).floor();
            let b = ((center[k] + self.reach - self.origin[k]) / self.cell).floor();
            if b < 0.0 || a > (self.dims[k] - 1) as f64 {
                return true;
            }
            range[k] = (a.max(0.0) as usize, (b as usize).min(self.dims[k] - 1));
        }
        let mut ok = true;
        for z in range[2].0..=range[2].1 {
            for y in range[1].0..=range[1].1 {
                for x in range[0].0..=range[0].1 {
                    let c = (z * self.dims[1] + y) * self.dims[0] + x;
                    let (a, b) = (self.cell_start[c] as usize, self.cell_start[c + 1] as usize);
                    for &i in &self.nodes[a..b] {
                        if (self.rest[i as usize] - center).norm_squared() <= r2 && out.push(i).is_err() {
                            ok = false;
                        }
                    }
                }
            }
        }
        ok
    }
}

/// One touched node.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeContact {
    /// Mesh node.
    pub node: u32,
    /// Force on the tissue at the node (N).
    pub force: Vec3,
    /// The tool sphere that touches it ([`evaluate_spheres`]; 0: the tool).
    pub sphere: u16,
}

/// What contact produced in one tick. Fixed capacity, reused every tick.
#[derive(Debug, Clone)]
pub struct ContactOutput<const R: usize> {
    /// Reaction on the tool (N).
    pub tool_force: Vec3,
    /// Reduced force Σ Φᵢᵀ fᵢ.
    pub reduced_force: SVector<f64, R>,
    /// Reduced contact stiffness K_c.
    pub reduced_stiffness: SMatrix<f64, R, R>,
    /// Touched nodes and their forces.
    pub nodes: heapless::Vec<NodeContact, MAX_CONTACT_NODES>,
    /// Deepest penetration (m), into the surface as the residual compliance
    /// deflects it when that is on.
    pub max_depth: f64,
    /// Candidates examined.
    pub candidates: usize,
    /// The candidate or touched-node list overflowed (contact truncated).
    pub truncated: bool,
    /// Touched nodes left without the compliance correction (beyond
    /// [`MAX_COMPLIANT_NODES`]).
    pub uncorrected: usize,
    /// Touched nodes the compliance correction released (p < 0).
    pub released: usize,
    /// Reaction on each tool sphere (N), in the order given.
    pub sphere_forces: heapless::Vec<Vec3, MAX_SPHERES>,
    active: heapless::Vec<ActiveNode, MAX_CONTACT_NODES>,
}

/// A penetrating node, before its force is known.
#[derive(Debug, Clone, Copy, PartialEq)]
struct ActiveNode {
    node: u32,
    n: Vec3,
    k: f64,
    depth: f64,
    sphere: u16,
}

impl<const R: usize> Default for ContactOutput<R> {
    fn default() -> Self {
        ContactOutput {
            tool_force: Vec3::zeros(),
            reduced_force: SVector::zeros(),
            reduced_stiffness: SMatrix::zeros(),
            nodes: heapless::Vec::new(),
            max_depth: 0.0,
            candidates: 0,
            truncated: false,
            uncorrected: 0,
            released: 0,
            sphere_forces: heapless::Vec::new(),
            active: heapless::Vec::new(),
        }
    }
}

/// Scratch of the contact query (fixed capacity).
pub type Candidates = heapless::Vec<u32, MAX_CANDIDATES>;

/// Evaluates the penalty contact of the tool at `center` against the surface
/// whose node `i` sits at `position(i)` (deformed) with Φ rows `rows(i)`.
/// Fills `out`; allocates nothing.
pub fn evaluate<const R: usize>(
    index: &SurfaceIndex,
    params: &ContactParams,
    center: &Vec3,
    position: impl Fn(u32) -> Vec3,
    rows: impl Fn(u32) -> Option<SMatrix<f64, 3, R>>,
    scratch: &mut Candidates,
    out: &mut ContactOutput<R>,
) {
    evaluate_with(index, params, center, position, rows, None, scratch, out)
}

/// As [`evaluate`], with the residual `compliance` of the model in series
/// with the penalty (module doc, "Contact anywhere"). Allocates nothing.
#[allow(clippy::too_many_arguments)]
pub fn evaluate_with<const R: usize>(
    index: &SurfaceIndex,
    params: &ContactParams,
    center: &Vec3,
    position: impl Fn(u32) -> Vec3,
    rows: impl Fn(u32) -> Option<SMatrix<f64, 3, R>>,
    compliance: Option<&LocalCompliance>,
    scratch: &mut Candidates,
    out: &mut ContactOutput<R>,
) {
    evaluate_spheres(
        index,
        params,
        std::slice::from_ref(center),
        position,
        rows,
        compliance,
        scratch,
        out,
    )
}

/// Several tool spheres at once (the points where an instrument touches
/// the wall, up to [`MAX_SPHERES`]; more are ignored and flagged as
/// truncated), all of radius `params.tool_radius_m`: their touched nodes
/// form one coupled contact problem, so nearby patches load each other
/// through the residual compliance. `out.sphere_forces[s]` is the reaction
/// on sphere s. A node inside several spheres belongs to the one it
/// penetrates deepest. Allocates nothing.
#[allow(clippy::too_many_arguments)]
pub fn evaluate_spheres<const R: usize>(
    index: &SurfaceIndex,
    params: &ContactParams,
    centers: &[Vec3],
    position: impl Fn(u32) -> Vec3,
    rows: impl Fn(u32) -> Option<SMatrix<f64, 3, R>>,
    compliance: Option<&LocalCompliance>,
    scratch: &mut Candidates,
    out: &mut ContactOutput<R>,
) {
    out.tool_force = Vec3::zeros();
    out.reduced_force = SVector::zeros();
    out.reduced_stiffness = SMatrix::zeros();
    out.nodes.clear();
    out.active.clear();
    out.sphere_forces.clear();
    out.max_depth = 0.0;
    out.uncorrected = 0;
    out.released = 0;
    out.truncated = centers.len() > MAX_SPHERES;
    out.candidates = 0;
    let rho = params.tool_radius_m;
    for (s, center) in centers.iter().take(MAX_SPHERES).enumerate() {
        let _ = out.sphere_forces.push(Vec3::zeros());
        out.truncated |= !index.query(center, scratch);
        out.candidates += scratch.len();
        for &i in scratch.iter() {
            let x = position(i);
            let d = x - center;
            let dist = d.norm();
            let depth = rho - dist;
            if depth.is_nan() || depth <= 0.0 {
                continue;
            }
            let n = if dist > 1e-9 * rho { d / dist } else { index.normal(i) };
            let k = params.pressure_stiffness * index.area(i);
            out.max_depth = out.max_depth.max(depth);
            let node = ActiveNode {
                node: i,
                n,
                k,
                depth,
                sphere: s as u16,
            };
            match out.active.iter_mut().find(|a| a.node == i) {
                Some(a) if a.depth < depth => *a = node,
                Some(_) => {}
                None => {
                    if out.active.push(node).is_err() {
                        out.truncated = true;
                    }
                }
            }
        }
    }
    let corrected = match compliance {
        Some(w) if !out.active.is_empty() => {
            // The deepest nodes first: they carry the patch.
            out.active
                .sort_unstable_by(|a, b| b.depth.total_cmp(&a.depth).then(a.node.cmp(&b.node)));
            let m = out.active.len().min(MAX_COMPLIANT_NODES);
            out.uncorrected = out.active.len() - m;
            series_patch(w, &rows, m, out);
            m
        }
        _ => 0,
    };
    // Nodes without the correction: the plain penalty.
    for a in corrected..out.active.len() {
        let ActiveNode {
            node,
            n,
            k,
            depth,
            sphere,
        } = out.active[a];
        push_force(out, node, sphere, n * (k * depth));
        if let Some(phi) = rows(node) {
            let g = phi.tr_mul(&n);
            out.reduced_stiffness += g * g.transpose() * k;
        }
    }
    let mut fr = SVector::<f64, R>::zeros();
    for c in out.nodes.iter() {
        if let Some(phi) = rows(c.node) {
            fr += phi.tr_mul(&c.force);
        }
    }
    out.reduced_force = fr;
}

/// Records the force `f` on the tissue at `node`: tool reaction, reduced
/// force, the touched-node list.
fn push_force<const R: usize>(out: &mut ContactOutput<R>, node: u32, sphere: u16, f: Vec3) {
    out.tool_force -= f;
    if let Some(s) = out.sphere_forces.get_mut(sphere as usize) {
        *s -= f;
    }
    if out.nodes.push(NodeContact { node, force: f, sphere }).is_err() {
        out.truncated = true;
    }
}

#[allow(clippy::needless_range_loop)] // index arithmetic reads as the formula
/// In-place Cholesky of the leading m × m block of `a` (lower triangle);
/// false if not positive definite.
fn cholesky_in_place(a: &mut [[f64; MAX_COMPLIANT_NODES]; MAX_COMPLIANT_NODES], m: usize) -> bool {
    for j in 0..m {
        let mut s = a[j][j];
        for k in 0..j {
            s -= a[j][k] * a[j][k];
        }
        if !(s > 0.0 && s.is_finite()) {
            return false;
        }
        let d = s.sqrt();
        a[j][j] = d;
        for i in j + 1..m {
            let mut s = a[i][j];
            for k in 0..j {
                s -= a[i][k] * a[j][k];
            }
            a[i][j] = s / d;
        }
    }
    true
}

#[allow(clippy::needless_range_loop)] // index arithmetic reads as the formula
/// Solves L Lᵀ x = b in place (leading m entries).
fn cholesky_solve(l: &[[f64; MAX_COMPLIANT_NODES]; MAX_COMPLIANT_NODES], m: usize, b: &mut [f64; MAX_COMPLIANT_NODES]) {
    for i in 0..m {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i][k] * b[k];
        }
        b[i] = s / l[i][i];
    }
    for i in (0..m).rev() {
        let mut s = b[i];
        for k in i + 1..m {
            s -= l[k][i] * b[k];
        }
        b[i] = s / l[i][i];
    }
}

/// The first `m` active nodes with the residual compliance in series:
/// (K_p⁻¹ + S) p = d, p ≥ 0; forces p n, K_c = G (K_p⁻¹ + S)⁻¹ Gᵀ.
fn series_patch<const R: usize>(
    w: &LocalCompliance,
    rows: &impl Fn(u32) -> Option<SMatrix<f64, 3, R>>,
    m: usize,
    out: &mut ContactOutput<R>,
) {
    const C: usize = MAX_COMPLIANT_NODES;
    let mut on = [false; C];
    on[..m].iter_mut().for_each(|o| *o = true);
    let mut p = [0.0f64; C];
    let mut l = [[0.0f64; C]; C];
    let mut ok = false;
    // Each pass releases the node pulled hardest; at most m passes.
    for _ in 0..m {
        for a in 0..m {
            for b in 0..=a {
                l[a][b] = if !(on[a] && on[b]) {
                    (a == b) as u8 as f64
                } else {
                    let (na, nb) = (&out.active[a], &out.active[b]);
                    let s = w
                        .block(na.node, nb.node)
                        .map(|blk| na.n.dot(&(blk * nb.n)))
                        .unwrap_or(0.0);
                    s + if a == b { 1.0 / na.k } else { 0.0 }
                };
            }
        }
        for a in 0..m {
            p[a] = if on[a] { out.active[a].depth } else { 0.0 };
        }
        if !cholesky_in_place(&mut l, m) {
            break;
        }
        cholesky_solve(&l, m, &mut p);
        let worst = (0..m)
            .filter(|&a| on[a] && p[a] < 0.0)
            .min_by(|&a, &b| p[a].total_cmp(&p[b]));
        match worst {
            Some(a) => {
                on[a] = false;
                out.released += 1;
            }
            None => {
                ok = true;
                break;
            }
        }
    }
    if !ok {
        // Not positive definite (a corrupt table): the plain penalty.
        for a in 0..m {
            let ActiveNode {
                node,
                n,
                k,
                depth,
                sphere,
            } = out.active[a];
            push_force(out, node, sphere, n * (k * depth));
            if let Some(phi) = rows(node) {
                let g = phi.tr_mul(&n);
                out.reduced_stiffness += g * g.transpose() * k;
            }
        }
        return;
    }
    // The penetration into the surface as the residual compliance moves it.
    out.max_depth = (0..m)
        .filter(|&a| on[a])
        .map(|a| p[a] / out.active[a].k)
        .chain(out.active[m..].iter().map(|a| a.depth))
        .fold(0.0, f64::max);
    // Forces, and h_a = Σ_b (K_p⁻¹ + S)⁻¹_ab g_b column by column of the inverse.
    let mut g = [SVector::<f64, R>::zeros(); C];
    for a in 0..m {
        let ActiveNode { node, n, sphere, .. } = out.active[a];
        if on[a] {
            push_force(out, node, sphere, n * p[a]);
        }
        if let Some(phi) = rows(node) {
            g[a] = phi.tr_mul(&n);
        }
    }
    for b in 0..m {
        if !on[b] {
            continue;
        }
        let mut col = [0.0f64; C];
        col[b] = 1.0;
        cholesky_solve(&l, m, &mut col);
        let mut h = SVector::<f64, R>::zeros();
        for a in 0..m {
            if on[a] {
                h += g[a] * col[a];
            }
        }
        out.reduced_stiffness += h * g[b].transpose();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::block::block;

    fn plate() -> TetMesh {
        block([20, 20, 1], [0.04, 0.04, 0.002]).unwrap()
    }

    #[test]
    fn queries_find_exactly_the_nodes_within_reach() {
        let mesh = plate();
        let p = ContactParams::default();
        let idx = SurfaceIndex::new(&mesh, &p);
        let mut out: heapless::Vec<u32, 4096> = heapless::Vec::new();
        for c in [
            Vec3::new(0.02, 0.02, 0.005),
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.5, 0.0, 0.0),
        ] {
            assert!(idx.query(&c, &mut out));
            let reach = p.tool_radius_m + p.search_margin_m;
            let mut want: Vec<u32> = mesh
                .surface_nodes()
                .into_iter()
                .filter(|&i| (mesh.rest()[i as usize] - c).norm() <= reach)
                .collect();
            let mut got: Vec<u32> = out.iter().copied().collect();
            want.sort_unstable();
            got.sort_unstable();
            assert_eq!(got, want);
        }
        let mut small: heapless::Vec<u32, 4> = heapless::Vec::new();
        assert!(!idx.query(&Vec3::new(0.02, 0.02, 0.0), &mut small));
        assert!(idx.query(&Vec3::new(f64::NAN, 0.0, 0.0), &mut small));
        assert!(small.is_empty());
    }

    #[test]
    fn a_sphere_pressed_into_a_flat_wall_gives_the_pressure_times_the_cap_area() {
        // On a flat wall Σ k_p Aᵢ dᵢ nᵢ is a quadrature of the integral over the
        // contact disk of k_p (ρ − s) n, s = √(r² + z₀²) the distance to the
        // centre at height z₀ = ρ − h above the wall; its vertical part is
        // k_p ∫₀ᵃ (ρ − s)(z₀/s) 2πr dr with a = √(ρ² − z₀²).
        let mesh = block([80, 80, 1], [0.04, 0.04, 0.002]).unwrap();
        let p = ContactParams {
            tool_radius_m: 3e-3,
            pressure_stiffness: 1e8,
            search_margin_m: 2e-3,
        };
        let idx = SurfaceIndex::new(&mesh, &p);
        let h = 1e-3;
        let c = Vec3::new(0.02, 0.02, 0.002 + p.tool_radius_m - h);
        let mut scratch = Candidates::new();
        let mut out = ContactOutput::<4>::default();
        evaluate(
            &idx,
            &p,
            &c,
            |i| mesh.rest()[i as usize],
            |_| None,
            &mut scratch,
            &mut out,
        );
        let (rho, z0) = (p.tool_radius_m, p.tool_radius_m - h);
        let a = (rho * rho - z0 * z0).sqrt();
        let steps = 100_000;
        let integral: f64 = (0..steps)
            .map(|k| {
                let r = (k as f64 + 0.5) * a / steps as f64;
                let s = (r * r + z0 * z0).sqrt();
                (rho - s) * (z0 / s) * 2.0 * std::f64::consts::PI * r * a / steps as f64
            })
            .sum();
        let want = p.pressure_stiffness * integral;
        // Within the quadrature error of a 0.5 mm node grid.
        let fz = out.tool_force.z;
        assert!(fz > 0.0, "the wall pushes the tool up");
        assert!((fz - want).abs() <= 0.05 * want, "{fz} vs {want}");
        assert!(out.tool_force.x.abs() <= 1e-3 * fz && out.tool_force.y.abs() <= 1e-3 * fz);
        assert!((out.max_depth - h).abs() <= 1e-12);
        assert!(!out.truncated);
        // Newton's third law: the node forces sum to minus the tool force.
        let sum: Vec3 = out.nodes.iter().map(|n| n.force).sum();
        assert!((sum + out.tool_force).norm() <= 1e-12 * fz);
    }

    #[test]
    fn the_reduced_force_and_stiffness_come_from_the_basis_rows() {
        let mesh = plate();
        let p = ContactParams::default();
        let idx = SurfaceIndex::new(&mesh, &p);
        let c = Vec3::new(0.02, 0.02, 0.002 + p.tool_radius_m - 5e-4);
        let mut scratch = Candidates::new();
        let mut out = ContactOutput::<2>::default();
        // One mode moving every node along z by 1, one along x by 1.
        let rows = |_| Some(SMatrix::<f64, 3, 2>::new(0.0, 1.0, 0.0, 0.0, 1.0, 0.0));
        evaluate(&idx, &p, &c, |i| mesh.rest()[i as usize], rows, &mut scratch, &mut out);
        let fz: f64 = out.nodes.iter().map(|n| n.force.z).sum();
        let fx: f64 = out.nodes.iter().map(|n| n.force.x).sum();
        assert!((out.reduced_force[0] - fz).abs() <= 1e-12 * fz.abs());
        assert!((out.reduced_force[1] - fx).abs() <= 1e-12 * fz.abs());
        assert!(out.reduced_stiffness[(0, 0)] > 0.0);
        let k = out.reduced_stiffness;
        assert!((k - k.transpose()).norm() <= 1e-12 * k.norm());
    }
}
