//! Contact between the tool (spheres: the stylus tip, or points of an
//! instrument) and the deformed vessel surface, as a pressure integrated over
//! the surface triangles:
//!
//! ```text
//! p(x) = k_p (ρ − ‖x − c‖)₊,   f = ∫ p(x) n(x) dA,   n(x) = (x − c)/‖x − c‖,   F_tool = −f
//! ```
//!
//! with c, ρ the sphere's centre and radius, x on the deformed surface
//! (nodes at Xᵢ + ūᵢ + Φᵢ δq, triangles linear between them) and k_p a
//! pressure stiffness (Pa/m), so the force does not depend on the mesh
//! resolution. The integral is a fixed sub-triangle quadrature per triangle
//! (points about ρ / [`SAMPLES_PER_RADIUS`] apart), lumped to the triangle's
//! nodes with the barycentric weights; the force is therefore continuous as
//! the tool slides (a penalty at the nodes alone loses the contact between
//! nodes). f pushes the tissue, F_tool is the reaction on the tool.
//!
//! A uniform grid over the surface nodes' rest positions (built at start)
//! gives the candidates near the tool; only those nodes are reconstructed
//! from the reduced coordinates each tick, so the cost follows the contact
//! patch, not the mesh. A node can be found only while its displacement stays
//! under the search margin, which is therefore part of the configuration.
//! Between ticks each sphere keeps the triangles it found (all within the
//! tool radius plus [`COHERENCE_SLACK_M`]) and searches again only once it,
//! or the surface under it by the bound of [`Motion`], has moved the slack:
//! a held or slowly sliding patch costs its triangles, not a grid search.
//! Each kept triangle also keeps its distance from the sphere's centre at
//! the search; a tick skips, without reconstructing its nodes, every kept
//! triangle whose distance less the motion since still exceeds the tool
//! radius (it cannot touch the sphere: the distance from a point to a
//! triangle changes by at most the largest move of the point or of a
//! vertex).
//!
//! For the implicit reduced step the contact also gives its reduced stiffness
//! K_c = Σ_a k_a (Φ_aᵀn_a)(Φ_aᵀn_a)ᵀ (k_a the node's share of the pressure
//! stiffness, n_a the direction of its force; positive semi-definite); see
//! [`crate::reduced::ReducedDynamics::step_with_contact`].
//!
//! **Contact anywhere** ([`evaluate_with`] with a [`LocalCompliance`]): the
//! reduced model alone is too stiff where its basis has no static mode. The
//! residual compliance ΔW (what the basis misses of K⁻¹, see
//! [`crate::reduced::compliance`]) acts in series with the pressure. Each
//! sphere's pressed distribution is a patch with one unknown, its force
//! magnitude P, and its distribution e_a = f_a / F as the load shape:
//!
//! ```text
//! δ = S P,   S_pq = Σ_ab e_aᵀ ΔW_ab e_b,   P_p = F_p(δ_p) = Σ_i k_i (ρ − r_i)₊ (w_i·a) / r_i,   P ≥ 0
//! ```
//!
//! (w_i = v_i + u_i δ_p the quadrature point's offset from the sphere's
//! centre moved by its share u_i of the patch's dent, r_i = |w_i|,
//! k_i = k_p dA, a the patch's force direction: `patch_law`), solved by
//! Newton's method, which couples the patches; the node forces are then the
//! points' pressures at the solution (`redistribute`); the reduced stiffness becomes K_c = G (K⁻¹ + S)⁻¹ Gᵀ with
//! G = [Σ_a Φ_aᵀ e_a] and K = dF/dδ. At static equilibrium a patch then sees
//! the full model's local compliance in series with the pressure, at any
//! surface point, several patches at once, for a cost that follows the
//! patches, not the mesh (at most [`MAX_COMPLIANT_PATCHES`] are corrected;
//! more are counted).

use crate::math::{Mat3, Vec3};
use crate::mesh::TetMesh;
use crate::reduced::compliance::LocalCompliance;
use nalgebra::{SMatrix, SVector};

/// How far a sphere plus the surface under it may move before the
/// sphere's triangles are searched again (m): a search keeps every triangle
/// that comes within the tool radius plus this slack, and while the sphere
/// has moved less than the slack minus the bound on the surface's motion
/// ([`Motion`]) the kept list holds every triangle a full search would find.
pub const COHERENCE_SLACK_M: f64 = 1e-3;

/// Triangles kept per sphere between searches (a sphere over more is
/// searched every tick).
pub const KEPT_TRIANGLES: usize = 192;

/// Nodes of a patch whose node-pair blocks of the residual compliance are
/// kept from one evaluation to the next (a patch over more looks them up
/// every time): the self-coupling S_pp needs every pair, so a held patch
/// reads them from its own contiguous copy, not the table's rows.
pub const PAIR_CACHE_NODES: usize = 16;

/// How far the surface can have moved since a sphere's triangles were
/// searched: the reduced state q of the positions' model and a bound B on
/// ‖Φᵢ‖ over its nodes (no node moves more than B ‖q − q₀‖ when q changes
/// from q₀), e.g. [`crate::reduced::ReducedDynamics::row_bound`]. Given to
/// [`evaluate_spheres`], it lets a sphere reuse the triangles it found on an
/// earlier tick; the caller must call [`ContactOutput::forget`] whenever
/// the positions stop following `rest + offset + Φ q` of one model (a new
/// model, a new offset).
#[derive(Debug, Clone, Copy)]
pub struct Motion<'a, const R: usize> {
    /// The current reduced state.
    pub q: &'a SVector<f64, R>,
    /// max ‖Φᵢ‖ (m per unit of q).
    pub row_bound: f64,
    /// ūᵢ per mesh node when the positions are `rest + ū + Φ q` (None: not
    /// known). A search then passes over every candidate whose `rest + ū`
    /// is farther from the sphere than its reach plus `row_bound` ‖q‖
    /// without reconstructing it: Φᵢ q cannot bring it within reach, so the
    /// triangles found are the same, for fewer deformed positions.
    pub offset: Option<&'a [Vec3]>,
}

/// Which nodes' pair blocks a sphere keeps, and from which table.
#[derive(Debug, Clone, Copy, Default)]
struct PairKey {
    /// [`LocalCompliance::id`]; 0: nothing kept.
    table: u64,
    len: u16,
    nodes: [u32; PAIR_CACHE_NODES],
}

/// One sphere's triangles from its last search.
#[derive(Debug, Clone, Copy)]
struct Kept<const R: usize> {
    valid: bool,
    center: Vec3,
    q: SVector<f64, R>,
    len: u16,
    /// How far the surface may already have moved, besides Φ (q − `q`),
    /// since the search (m): the change of the offset ū at the swaps the
    /// triangles were carried over ([`ContactOutput::carry_from`]).
    carried: f64,
}

/// Candidate capacity of one query (a larger patch is truncated and counted).
pub const MAX_CANDIDATES: usize = 4096;
// `ContactOutput::searched` holds one bit per sphere.
const _: () = assert!(MAX_SPHERES <= 32);
/// Capacity of the touched-node list of one tick.
pub const MAX_CONTACT_NODES: usize = 256;
/// Tool spheres one contact evaluation takes ([`evaluate_spheres`]).
pub const MAX_SPHERES: usize = 32;
/// Contact patches (one per touching sphere) whose residual compliance is
/// applied in one tick; more keep the plain penalty and are counted.
pub const MAX_COMPLIANT_PATCHES: usize = MAX_SPHERES;
/// Surface triangles one sphere may touch in one tick (more are dropped and
/// flagged as truncated).
pub const MAX_TRIANGLES: usize = 1024;
/// Quadrature points per tool radius along a triangle edge: the pressure is
/// sampled at sub-triangle centroids about ρ / 3 apart. (4 per radius
/// rendered the same stiffness within 1 % at 120 points of the branched
/// arch, with more samples to solve each tick.)
pub const SAMPLES_PER_RADIUS: f64 = 3.0;
/// Most sub-triangle levels per edge (level² samples per triangle).
pub const MAX_LEVEL: usize = 16;
/// Pressed pressure samples kept per tick for the series solve (more are
/// left out of the patch's law and flagged as truncated).
pub const MAX_SAMPLES: usize = 8192;

/// Contact parameters.
// `default`: a `[contact]` table that gives some keys takes the others'
// defaults, as every other table of the service file does.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
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
    /// Beside `nodes` (the grid's order, cell by cell), each node's rest
    /// position and longest surface edge: what a query and the search's
    /// first filter read of every node in the cells they scan, so that
    /// they walk a few contiguous runs of memory (one per row of cells)
    /// instead of one cache line per node of the mesh-ordered arrays.
    slots: Vec<Slot>,
    rest: Vec<Vec3>,
    area: Vec<f64>,
    normal: Vec<Vec3>,
    reach: f64,
    tris: Vec<[u32; 3]>,
    tri_area: Vec<f64>,
    tri_level: Vec<u8>,
    node_tri_start: Vec<u32>,
    node_tris: Vec<u32>,
    max_edge: f64,
    /// The search margin (m).
    margin: f64,
}

impl SurfaceIndex {
    /// Indexes the surface nodes and triangles of `mesh` for a tool of
    /// radius `params.tool_radius_m` and displacements up to
    /// `params.search_margin_m`.
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
        // A triangle can touch the tool while its nearest vertex is up to
        // one edge away from the contact.
        let longest = mesh
            .surface()
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| rest[i as usize]);
                (b - a).norm().max((c - b).norm()).max((a - c).norm())
            })
            .fold(0.0, f64::max);
        let reach = params.tool_radius_m + params.search_margin_m + longest + COHERENCE_SLACK_M;
        let (mut lo, mut hi) = (Vec3::repeat(f64::INFINITY), Vec3::repeat(f64::NEG_INFINITY));
        for &i in &surface {
            lo = lo.inf(&rest[i as usize]);
            hi = hi.sup(&rest[i as usize]);
        }
        if surface.is_empty() {
            lo = Vec3::zeros();
            hi = Vec3::zeros();
        }
        // Cells of half the query size (a query scans 4-5 per axis, about
        // half the volume whole-size cells would); coarser if the grid
        // would be huge.
        let mut cell = (0.5 * reach).max(1e-6);
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
        // Triangles, their quadrature level and the node -> triangle lists.
        let tris: Vec<[u32; 3]> = mesh.surface().to_vec();
        let spacing = params.tool_radius_m / SAMPLES_PER_RADIUS;
        let mut tri_area = Vec::with_capacity(tris.len());
        let mut tri_level = Vec::with_capacity(tris.len());
        let mut max_edge = 0.0f64;
        let mut start = vec![0u32; rest.len() + 1];
        let mut reach_of = vec![0.0f64; rest.len()];
        for t in &tris {
            let [a, b, c] = t.map(|i| rest[i as usize]);
            tri_area.push((b - a).cross(&(c - a)).norm() / 2.0);
            let edge = (b - a).norm().max((c - b).norm()).max((a - c).norm());
            max_edge = max_edge.max(edge);
            for &i in t {
                reach_of[i as usize] = reach_of[i as usize].max(edge);
            }
            let level = (edge / spacing.max(1e-12)).ceil().clamp(1.0, MAX_LEVEL as f64);
            tri_level.push(level as u8);
            for &i in t {
                start[i as usize + 1] += 1;
            }
        }
        for i in 0..rest.len() {
            start[i + 1] += start[i];
        }
        let mut fill = start.clone();
        let mut node_tris = vec![0u32; start[rest.len()] as usize];
        for (k, t) in tris.iter().enumerate() {
            for &i in t {
                node_tris[fill[i as usize] as usize] = k as u32;
                fill[i as usize] += 1;
            }
        }
        let slots = nodes
            .iter()
            .map(|&i| Slot {
                rest: rest[i as usize],
                reach: reach_of[i as usize],
            })
            .collect();
        SurfaceIndex {
            origin: lo,
            cell,
            dims,
            cell_start: count,
            nodes,
            slots,
            rest,
            area,
            normal,
            reach,
            tris,
            tri_area,
            tri_level,
            node_tri_start: start,
            node_tris,
            max_edge,
            margin: params.search_margin_m,
        }
    }

    /// The surface triangles that have node `i` as a vertex.
    pub fn triangles_of(&self, i: u32) -> &[u32] {
        let i = i as usize;
        match (self.node_tri_start.get(i), self.node_tri_start.get(i + 1)) {
            (Some(&a), Some(&b)) => &self.node_tris[a as usize..b as usize],
            _ => &[],
        }
    }

    /// Longest surface edge at rest (m).
    pub fn max_edge(&self) -> f64 {
        self.max_edge
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

    /// The surface nodes whose rest position is within the reach (tool
    /// radius, margin, longest surface edge and [`COHERENCE_SLACK_M`]) of
    /// `center`, into `out` (cleared first). Returns false if `out`
    /// overflowed (the list is then truncated). Allocates nothing.
    pub fn query<const N: usize>(&self, center: &Vec3, out: &mut heapless::Vec<u32, N>) -> bool {
        out.clear();
        let mut ok = true;
        self.scan(center, |slot| {
            if out.push(self.nodes[slot]).is_err() {
                ok = false;
            }
        });
        ok
    }

    /// Calls `f` with the slot (index into `nodes` and `slots`) of every
    /// surface node whose rest position is within the reach of `center`,
    /// cell by cell in the grid's order: each row of cells is one
    /// contiguous run of `slots`.
    #[inline(always)]
    fn scan(&self, center: &Vec3, mut f: impl FnMut(usize)) {
        if self.nodes.is_empty() || !center.iter().all(|v| v.is_finite()) {
            return;
        }
        let r2 = self.reach * self.reach;
        let mut range = [(0usize, 0usize); 3];
        for k in 0..3 {
            let a = ((center[k] - self.reach - self.origin[k]) / self.cell).floor();
            let b = ((center[k] + self.reach - self.origin[k]) / self.cell).floor();
            if b < 0.0 || a > (self.dims[k] - 1) as f64 {
                return;
            }
            range[k] = (a.max(0.0) as usize, (b as usize).min(self.dims[k] - 1));
        }
        for z in range[2].0..=range[2].1 {
            for y in range[1].0..=range[1].1 {
                // The cells x0..=x1 of this row are consecutive in the grid,
                // so their nodes are one run of slots.
                let row = (z * self.dims[1] + y) * self.dims[0];
                let (a, b) = (
                    self.cell_start[row + range[0].0] as usize,
                    self.cell_start[row + range[0].1 + 1] as usize,
                );
                for (k, slot) in self.slots[a..b].iter().enumerate() {
                    if (slot.rest - center).norm_squared() <= r2 {
                        f(a + k);
                    }
                }
            }
        }
    }

    /// The search's candidates near `center` into `out`, as slots (see
    /// [`SurfaceIndex::scan`]), in the query's order: the nodes a query
    /// finds whose rest position is also within `near` plus their longest
    /// surface edge of it. With `offset`, asks for each one's cache line of
    /// it (the search's next filter reads it). Returns the query's count
    /// and whether it fitted in `out` (a query that overflows keeps its
    /// first `N` nodes, and so does this).
    fn candidates<const N: usize>(
        &self,
        center: &Vec3,
        near: f64,
        offset: Option<&[Vec3]>,
        out: &mut heapless::Vec<u32, N>,
    ) -> (usize, bool) {
        out.clear();
        let mut count = 0usize;
        self.scan(center, |slot| {
            count += 1;
            let s = &self.slots[slot];
            let far = near + s.reach;
            if count <= N && at_most((s.rest - center).norm_squared(), far * far) {
                let _ = out.push(slot as u32);
                if let Some(o) = offset {
                    prefetch(o.get(self.nodes[slot] as usize));
                }
            }
        });
        (count, count <= N)
    }
}

/// A surface node's rest position and the longest edge of its surface
/// triangles (m), in the grid's order ([`SurfaceIndex`]); 32 bytes, aligned
/// so that one never straddles two cache lines.
#[derive(Debug, Clone, Copy)]
#[repr(C, align(32))]
struct Slot {
    rest: Vec3,
    reach: f64,
}

/// One touched node.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NodeContact {
    /// Mesh node.
    pub node: u32,
    /// Force on the tissue at the node (N).
    pub force: Vec3,
    /// The tool sphere that touches it ([`evaluate_spheres`]; 0: the tool).
    /// A node two spheres touch is listed once per sphere.
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
    /// Surface triangles examined, and pressure samples evaluated.
    pub triangles: usize,
    /// See `triangles`.
    pub samples: usize,
    /// Deformed node positions computed (each at most once per evaluation).
    pub positions: usize,
    /// The candidate, triangle or touched-node list overflowed (contact truncated).
    pub truncated: bool,
    /// Touching patches left without the compliance correction (beyond
    /// [`MAX_COMPLIANT_PATCHES`]).
    pub uncorrected: usize,
    /// Patches the compliance correction released (pulled into the tool).
    pub released: usize,
    /// The residual compliance corrected every touching patch this
    /// evaluation (false without a table, with more than
    /// [`MAX_COMPLIANT_PATCHES`] patches, or when the series solve fell
    /// back to the plain penalty).
    pub corrected: bool,
    /// Newton iterations of the series solve.
    pub iterations: usize,
    /// Spheres whose triangles were searched for on the grid this
    /// evaluation (the others reused their kept triangles, [`Motion`]).
    pub searches: usize,
    /// Time the residual-compliance series solve took this evaluation (ns;
    /// 0 without one), for the loop's phase timing.
    pub series_ns: i64,
    /// Time the triangle searches took this evaluation (ns; 0 without one),
    /// for the loop's phase timing.
    pub search_ns: i64,
    /// Patches whose node-pair blocks of the residual compliance were read
    /// from the table this evaluation (their touched nodes or the table
    /// changed); the other patches of the series solve reused the blocks
    /// they kept (at most [`PAIR_CACHE_NODES`] nodes; a larger patch reads
    /// the table every time and is counted every time).
    pub pair_lookups: usize,
    /// Reaction on each tool sphere (N), in the order given.
    pub sphere_forces: heapless::Vec<Vec3, MAX_SPHERES>,
    active: heapless::Vec<ActiveNode, MAX_CONTACT_NODES>,
    patches: heapless::Vec<Patch, MAX_SPHERES>,
    tris: heapless::Vec<u32, MAX_TRIANGLES>,
    /// Per surface triangle, the last visit's stamp ([`ContactOutput::for_index`]);
    /// empty: the visited list `tris` is searched instead.
    stamps: Vec<u32>,
    stamp: u32,
    /// The pressed samples' (depth, k_p dA) of every patch; fixed capacity
    /// [`MAX_SAMPLES`], never grown in [`evaluate_spheres`].
    samples_buf: Vec<Sample>,
    /// Beside `samples_buf`, where each sample sits (same capacity).
    samples_at: Vec<SampleAt>,
    /// Per mesh node, (tick stamp, deformed position) of this evaluation
    /// ([`ContactOutput::for_index`]; empty: no cache).
    cache: Vec<(u32, Vec3)>,
    tick: u32,
    /// Bit `s` set: sphere `s` searched on this evaluation (and kept what it
    /// found, if it could).
    searched: u32,
    /// Per sphere, its kept triangles (`kept_tris[s * KEPT_TRIANGLES..]`);
    /// empty: nothing is kept ([`Default`] output).
    kept: Vec<Kept<R>>,
    kept_tris: Vec<u32>,
    /// Distance from the sphere's centre to each kept triangle at the
    /// search (m), beside `kept_tris`.
    kept_dist: Vec<f64>,
    /// Per sphere, the nodes of its patch whose ΔW pair blocks it keeps,
    /// and the blocks (`pair_blocks[s * PAIR_CACHE_NODES² + a * len + b]`,
    /// zero where the table has none).
    pair_keys: Vec<PairKey>,
    pair_blocks: Vec<Mat3>,
    /// Per sphere, its patch's force from the last series solve (N): where
    /// the next solve starts (only a start: the solve is bracketed).
    last_force: [f64; MAX_SPHERES],
    /// [`LocalCompliance::id`] of the table `last_force` was solved with:
    /// with another table the solve starts from 0, so an output gives what
    /// a new one gives on its first evaluation with a table.
    last_table: u64,
}

impl<const R: usize> ContactOutput<R> {
    /// An output sized for `index`: a stamp per surface triangle, so a
    /// sphere's triangles are found in time proportional to the patch
    /// (allocated here, never in [`evaluate_spheres`]).
    pub fn for_index(index: &SurfaceIndex) -> ContactOutput<R> {
        ContactOutput {
            stamps: vec![0; index.tris.len()],
            cache: vec![(0, Vec3::zeros()); index.rest.len()],
            kept: vec![
                Kept {
                    valid: false,
                    center: Vec3::zeros(),
                    q: SVector::zeros(),
                    len: 0,
                    carried: 0.0,
                };
                MAX_SPHERES
            ],
            kept_tris: vec![0; MAX_SPHERES * KEPT_TRIANGLES],
            kept_dist: vec![0.0; MAX_SPHERES * KEPT_TRIANGLES],
            pair_keys: vec![PairKey::default(); MAX_SPHERES],
            pair_blocks: vec![Mat3::zeros(); MAX_SPHERES * PAIR_CACHE_NODES * PAIR_CACHE_NODES],
            ..Default::default()
        }
    }

    /// Drops every sphere's kept triangles: call it when the positions
    /// given to [`evaluate_spheres`] stop following one model (see
    /// [`Motion`]). Allocates nothing.
    pub fn forget(&mut self) {
        self.kept.iter_mut().for_each(|k| k.valid = false);
        self.pair_keys.iter_mut().for_each(|k| k.table = 0);
    }

    /// Takes over `from`'s kept triangles and pair blocks for positions that
    /// follow another model on the same Φ rows whose state is `from`'s
    /// moved by `shift` (q ← q + `shift`), and whose positions at q +
    /// `shift` are within `moved` (m) of `from`'s model's positions at q at
    /// every node: a model swap between basis refreshes (ū changes, and the
    /// shift follows the part of that change the basis spans). Each kept
    /// state moves by `shift` too, so the motion bound of [`Motion`] counts
    /// the state's change from there plus `moved`: each kept list holds
    /// every triangle a search would find while that bound stays under the
    /// slack, and the swap tick needs no search. Without room in either
    /// output, or with a `moved` that is not finite and ≥ 0 or a `shift`
    /// that is not finite, this forgets instead. Returns how many spheres'
    /// triangles were carried over. Allocates nothing.
    pub fn carry_from(&mut self, from: &ContactOutput<R>, moved: f64, shift: &SVector<f64, R>) -> usize {
        self.forget();
        if !(moved.is_finite() && moved >= 0.0 && shift.iter().all(|v| v.is_finite()))
            || self.kept.len() != from.kept.len()
            || self.kept_tris.len() != from.kept_tris.len()
            || self.kept_dist.len() != from.kept_dist.len()
            || self.pair_keys.len() != from.pair_keys.len()
            || self.pair_blocks.len() != from.pair_blocks.len()
        {
            return 0;
        }
        let mut carried_spheres = 0;
        for (s, k) in from.kept.iter().enumerate() {
            if !k.valid {
                continue;
            }
            if self.take_sphere_from(from, s, moved, k.q + shift) {
                carried_spheres += 1;
            }
        }
        // The pair blocks depend on the table and the nodes only.
        for (s, key) in from.pair_keys.iter().enumerate() {
            if key.table == 0 {
                continue;
            }
            let base = s * PAIR_CACHE_NODES * PAIR_CACHE_NODES;
            let n = key.len as usize * key.len as usize;
            self.pair_blocks[base..base + n].copy_from_slice(&from.pair_blocks[base..base + n]);
            self.pair_keys[s] = *key;
        }
        carried_spheres
    }

    /// During a cross-fade, takes over the triangles `from` found on this
    /// evaluation for each sphere whose own kept triangles no longer hold
    /// at `centers` under `motion` (this output's model and state), so that
    /// the old model does not search the same surface again on the tick the
    /// new one did. `from` follows a model on the same Φ rows whose
    /// positions at q + `shift` are within `moved` (m) of this output's
    /// model's positions at q at every node (the swap's bound, read the
    /// other way: [`ContactOutput::carry_from`]). Returns how many spheres
    /// took them over. Allocates nothing.
    pub fn adopt_searches(
        &mut self,
        from: &ContactOutput<R>,
        moved: f64,
        shift: &SVector<f64, R>,
        centers: &[Vec3],
        motion: &Motion<R>,
    ) -> usize {
        if !(moved.is_finite() && moved >= 0.0 && shift.iter().all(|v| v.is_finite()))
            || self.kept.len() != from.kept.len()
            || self.kept_tris.len() != from.kept_tris.len()
            || self.kept_dist.len() != from.kept_dist.len()
        {
            return 0;
        }
        let mut adopted = 0;
        for (s, center) in centers.iter().enumerate().take(self.kept.len().min(MAX_SPHERES)) {
            let k = from.kept[s];
            if from.searched & (1 << s) == 0 || !k.valid || self.may_reuse(s, center, motion).is_some() {
                continue;
            }
            if self.take_sphere_from(from, s, moved, k.q - shift) {
                adopted += 1;
            }
        }
        adopted
    }

    /// Takes `from`'s kept triangles of sphere `s` for a model whose
    /// positions differ from `from`'s by up to `moved` (m) more, with the
    /// kept state `q` in this output's coordinates; false (nothing taken)
    /// if the motion already allowed would pass the slack. The callers
    /// checked that both outputs have the same capacities.
    fn take_sphere_from(&mut self, from: &ContactOutput<R>, s: usize, moved: f64, q: SVector<f64, R>) -> bool {
        let k = from.kept[s];
        let carried = k.carried + moved;
        if !at_most(carried, COHERENCE_SLACK_M) {
            return false;
        }
        let (base, len) = (s * KEPT_TRIANGLES, k.len as usize);
        self.kept_tris[base..base + len].copy_from_slice(&from.kept_tris[base..base + len]);
        self.kept_dist[base..base + len].copy_from_slice(&from.kept_dist[base..base + len]);
        self.kept[s] = Kept { carried, q, ..k };
        true
    }

    /// Calls `f` with each node of every triangle a sphere keeps (a node
    /// shared by triangles comes once per triangle): the nodes whose
    /// positions the next evaluation on the kept triangles reads. The loop
    /// reads a new model's offset at these nodes a tick before swapping it
    /// in ([`crate::haptics::servo::Servo::warm`]). Allocates nothing.
    pub fn for_each_kept_node(&self, index: &SurfaceIndex, mut f: impl FnMut(u32)) {
        for (s, k) in self.kept.iter().enumerate() {
            if !k.valid {
                continue;
            }
            let base = s * KEPT_TRIANGLES;
            let Some(kept) = self.kept_tris.get(base..base + k.len as usize) else {
                continue;
            };
            for &t in kept {
                if let Some(tri) = index.tris.get(t as usize) {
                    tri.iter().for_each(|&v| f(v));
                }
            }
        }
    }

    /// Makes sphere `s`'s kept pair blocks those of patch `p`'s nodes in
    /// table `w` (looked up only if the nodes or the table changed).
    /// Returns whether the patch's blocks are kept (false: too many nodes,
    /// or an output without room).
    fn keep_pair_blocks(&mut self, w: &LocalCompliance, p: &Patch) -> bool {
        let (s, len) = (p.sphere as usize, p.len as usize);
        if len > PAIR_CACHE_NODES || s >= self.pair_keys.len() {
            self.pair_lookups += 1;
            return false;
        }
        let nodes = &self.active[p.first as usize..p.first as usize + len];
        let key = &mut self.pair_keys[s];
        if key.table == w.id() && key.len as usize == len && nodes.iter().zip(&key.nodes).all(|(a, &n)| a.node == n) {
            return true;
        }
        self.pair_lookups += 1;
        let key = &mut self.pair_keys[s];
        key.table = w.id();
        key.len = len as u16;
        for (k, a) in key.nodes.iter_mut().zip(nodes) {
            *k = a.node;
        }
        let base = s * PAIR_CACHE_NODES * PAIR_CACHE_NODES;
        for (ai, a) in nodes.iter().enumerate() {
            for (bi, b) in nodes.iter().enumerate() {
                self.pair_blocks[base + ai * len + bi] = w.block(a.node, b.node).copied().unwrap_or_else(Mat3::zeros);
            }
        }
        true
    }

    /// How far sphere `s` at `center` and the surface under it have moved
    /// since its triangles were kept, if it may reuse them.
    fn may_reuse(&self, s: usize, center: &Vec3, motion: &Motion<R>) -> Option<f64> {
        match self.kept.get(s) {
            Some(k) if k.valid => {
                let moved = k.carried + (center - k.center).norm() + motion.row_bound * (motion.q - k.q).norm();
                at_most(moved, COHERENCE_SLACK_M).then_some(moved)
            }
            _ => None,
        }
    }

    /// Sphere `s`'s kept triangles that may still touch a sphere of radius
    /// `rho` after a motion `moved` (m) since they were kept, into `tris`.
    fn take_kept(&mut self, s: usize, rho: f64, moved: f64) {
        let (base, len) = (s * KEPT_TRIANGLES, self.kept[s].len as usize);
        for k in base..base + len {
            // Farther than the radius even after the motion: cannot touch
            // (a NaN distance is not skipped).
            if self.kept_dist[k] - moved > rho {
                continue;
            }
            let _ = self.tris.push(self.kept_tris[k]);
        }
    }

    /// The deformed position of node `i`, evaluated once per evaluation.
    fn position_of(&mut self, i: u32, position: &impl Fn(u32) -> Vec3) -> Vec3 {
        match self.cache.get_mut(i as usize) {
            Some((t, x)) if *t == self.tick => *x,
            Some((t, x)) => {
                *t = self.tick;
                *x = position(i);
                self.positions += 1;
                *x
            }
            None => {
                self.positions += 1;
                position(i)
            }
        }
    }

    /// Marks triangle `t` visited for this sphere; false if it already was.
    fn visit(&mut self, t: u32) -> bool {
        match self.stamps.get_mut(t as usize) {
            Some(s) if *s == self.stamp => false,
            Some(s) => {
                *s = self.stamp;
                if self.tris.push(t).is_err() {
                    self.truncated = true;
                }
                true
            }
            None => {
                if self.tris.contains(&t) {
                    return false;
                }
                if self.tris.push(t).is_err() {
                    self.truncated = true;
                }
                true
            }
        }
    }
}

/// One pressed quadrature point.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Sample {
    /// Depth of the point into the sphere (m).
    depth: f64,
    /// k_p dA (N/m).
    k: f64,
    /// With v the point's offset from the sphere's centre, u how far it
    /// moves per unit of its patch's residual deflection δ (the patch's
    /// own dent there, [`patch_shape`]) and a the patch's force direction:
    /// v·u, u·u, v·a and u·a, so that its distance from the centre at δ is
    /// |v + u δ| and its pressure's share along a follows ([`patch_law`]).
    vu: f64,
    /// See `vu`.
    uu: f64,
    /// See `vu`.
    va: f64,
    /// See `vu`.
    ua: f64,
}

/// Where a pressed sample sits, beside its [`Sample`] (kept apart so that
/// the series solve's passes over the samples read only what they use).
#[derive(Debug, Clone, Copy, PartialEq)]
struct SampleAt {
    /// Direction of its pressure (from the sphere's centre).
    dir: [f32; 3],
    /// Barycentric (b1, b2) in its triangle.
    bary: [f32; 2],
    /// Its triangle's vertices as indices into `ContactOutput::active`
    /// (`NO_SLOT`: not listed).
    slots: [u16; 3],
}

/// A sample's slot that names no active node.
const NO_SLOT: u16 = u16::MAX;
const _: () = assert!(MAX_CONTACT_NODES < NO_SLOT as usize);

/// A node's share of one sphere's pressure, before the series correction.
#[derive(Debug, Clone, Copy, PartialEq)]
struct ActiveNode {
    node: u32,
    /// Penalty force on the node (N).
    f: Vec3,
    /// Its share of the patch stiffness, Σ k_p dA b over the pressed samples (N/m).
    k: f64,
    /// Σ_b ΔW_ab f_b over its patch's nodes b: how the node moves under
    /// its own patch's pressed forces (m), for the deflection shape.
    deflect: Vec3,
}

/// One sphere's contact patch: its nodes are `active[first..first + len]`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Patch {
    sphere: u16,
    first: u16,
    len: u16,
    /// Its pressure samples: `samples[sample_first..sample_first + sample_len]`.
    sample_first: u32,
    sample_len: u32,
    /// Penalty force magnitude |Σ f_a| (N).
    force: f64,
    /// Patch stiffness Σ k_p dA over the pressed samples (N/m).
    k: f64,
    /// Deepest sample (m).
    depth: f64,
    /// The sphere's radius (m).
    rho: f64,
    /// Rest centre of its nodes and their largest rest distance from it
    /// (m): two patches farther apart than the compliance table's reach do
    /// not couple.
    rest_centre: Vec3,
    rest_radius: f64,
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
            triangles: 0,
            samples: 0,
            positions: 0,
            truncated: false,
            uncorrected: 0,
            released: 0,
            corrected: false,
            iterations: 0,
            searches: 0,
            series_ns: 0,
            search_ns: 0,
            pair_lookups: 0,
            sphere_forces: heapless::Vec::new(),
            active: heapless::Vec::new(),
            patches: heapless::Vec::new(),
            tris: heapless::Vec::new(),
            stamps: Vec::new(),
            stamp: 0,
            samples_buf: Vec::with_capacity(MAX_SAMPLES),
            samples_at: Vec::with_capacity(MAX_SAMPLES),
            cache: Vec::new(),
            tick: 0,
            searched: 0,
            kept: Vec::new(),
            kept_tris: Vec::new(),
            kept_dist: Vec::new(),
            pair_keys: Vec::new(),
            pair_blocks: Vec::new(),
            last_force: [0.0; MAX_SPHERES],
            last_table: 0,
        }
    }
}

/// Scratch of the contact query (fixed capacity).
pub type Candidates = heapless::Vec<u32, MAX_CANDIDATES>;

/// Evaluates the penalty contact of the tool at `center` against the surface
/// whose node `i` sits at `position(i)` (deformed) with Φ rows `rows(i)`.
/// Fills `out`; allocates nothing.
pub fn evaluate<'r, const R: usize>(
    index: &SurfaceIndex,
    params: &ContactParams,
    center: &Vec3,
    position: impl Fn(u32) -> Vec3,
    rows: impl Fn(u32) -> Option<&'r SMatrix<f64, 3, R>>,
    scratch: &mut Candidates,
    out: &mut ContactOutput<R>,
) {
    evaluate_with(index, params, center, position, rows, None, scratch, out)
}

/// As [`evaluate`], with the residual `compliance` of the model in series
/// with the penalty (module doc, "Contact anywhere"). Allocates nothing.
#[allow(clippy::too_many_arguments)]
pub fn evaluate_with<'r, const R: usize>(
    index: &SurfaceIndex,
    params: &ContactParams,
    center: &Vec3,
    position: impl Fn(u32) -> Vec3,
    rows: impl Fn(u32) -> Option<&'r SMatrix<f64, 3, R>>,
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
        None,
        scratch,
        out,
    )
}

/// Several tool spheres at once (the points where an instrument touches
/// the wall, up to [`MAX_SPHERES`]; more are ignored and flagged as
/// truncated), all of radius `params.tool_radius_m`: each sphere's pressure
/// on the deformed surface triangles is one patch, and the patches form one
/// coupled problem, so nearby patches load each other through the residual
/// compliance. `out.sphere_forces[s]` is the reaction on sphere s.
/// With `motion` (positions that follow one reduced model), a sphere
/// reuses the triangles it found on an earlier evaluation while it and the
/// surface have moved less than [`COHERENCE_SLACK_M`]: the same result as
/// a search, for less work. Allocates nothing.
#[allow(clippy::too_many_arguments)]
pub fn evaluate_spheres<'r, const R: usize>(
    index: &SurfaceIndex,
    params: &ContactParams,
    centers: &[Vec3],
    position: impl Fn(u32) -> Vec3,
    rows: impl Fn(u32) -> Option<&'r SMatrix<f64, 3, R>>,
    compliance: Option<&LocalCompliance>,
    motion: Option<Motion<R>>,
    scratch: &mut Candidates,
    out: &mut ContactOutput<R>,
) {
    out.tool_force = Vec3::zeros();
    out.reduced_force = SVector::zeros();
    out.reduced_stiffness = SMatrix::zeros();
    out.nodes.clear();
    out.active.clear();
    out.patches.clear();
    out.samples_buf.clear();
    out.samples_at.clear();
    out.tick = out.tick.wrapping_add(1);
    out.searched = 0;
    if out.tick == 0 {
        out.cache.iter_mut().for_each(|c| c.0 = 0);
        out.tick = 1;
    }
    out.sphere_forces.clear();
    out.max_depth = 0.0;
    out.uncorrected = 0;
    out.released = 0;
    out.corrected = false;
    out.iterations = 0;
    out.truncated = centers.len() > MAX_SPHERES;
    out.candidates = 0;
    out.triangles = 0;
    out.samples = 0;
    out.positions = 0;
    out.searches = 0;
    out.series_ns = 0;
    out.search_ns = 0;
    out.pair_lookups = 0;
    for (s, center) in centers.iter().take(MAX_SPHERES).enumerate() {
        let _ = out.sphere_forces.push(Vec3::zeros());
        press_sphere(
            index,
            params,
            s as u16,
            center,
            &position,
            &rows,
            motion.as_ref(),
            scratch,
            out,
        );
    }
    if out.patches.is_empty() {
        return;
    }
    match compliance {
        Some(w) => {
            let t0 = crate::rt::clock::now_ns();
            series_patches(w, &rows, out);
            out.series_ns = crate::rt::clock::now_ns() - t0;
        }
        None => plain_patches(&rows, out),
    }
    let mut fr = SVector::<f64, R>::zeros();
    for c in out.nodes.iter() {
        if let Some(phi) = rows(c.node) {
            fr += phi.tr_mul(&c.force);
        }
    }
    out.reduced_force = fr;
}

/// The pressure k_p (ρ − ‖x − c‖)₊ of sphere `s` at `center` integrated
/// over the deformed surface triangles near it (a fixed sub-triangle
/// quadrature per triangle, so the force is continuous in the tool's
/// position), lumped to the triangles' nodes with the barycentric weights.
/// Appends the patch (if it presses) to `out`.
#[allow(clippy::too_many_arguments)]
fn press_sphere<'r, const R: usize>(
    index: &SurfaceIndex,
    params: &ContactParams,
    s: u16,
    center: &Vec3,
    position: &impl Fn(u32) -> Vec3,
    rows: &impl Fn(u32) -> Option<&'r SMatrix<f64, 3, R>>,
    motion: Option<&Motion<R>>,
    scratch: &mut Candidates,
    out: &mut ContactOutput<R>,
) {
    let rho = params.tool_radius_m;
    let rho2 = rho * rho;
    out.tris.clear();
    match motion.and_then(|m| out.may_reuse(s as usize, center, m)) {
        Some(moved) => out.take_kept(s as usize, rho, moved),
        None => search_triangles(index, rho, s, center, position, rows, motion, scratch, out),
    }
    let first = out.active.len();
    let sample_first = out.samples_buf.len();
    let (mut force, mut k, mut depth_max) = (Vec3::zeros(), 0.0, 0.0f64);
    for ti in 0..out.tris.len() {
        let t = out.tris[ti] as usize;
        let tri = index.tris[t];
        let x = tri.map(|v| out.position_of(v, position));
        if !within_bounding_sphere(&x, center, rho) {
            continue;
        }
        out.triangles += 1;
        let face = (x[1] - x[0]).cross(&(x[2] - x[0]));
        let inward = -face / face.norm().max(f64::MIN_POSITIVE);
        let level = index.tri_level[t] as usize;
        let da = params.pressure_stiffness * index.tri_area[t] / (level * level) as f64;
        let mut fv = [Vec3::zeros(); 3];
        let mut kv = [0.0; 3];
        let tri_samples = out.samples_buf.len();
        let samples_buf = &mut out.samples_buf;
        let samples_at = &mut out.samples_at;
        let mut overflowed = false;
        let overflow = &mut overflowed;
        let mut count = 0usize;
        let (e1, e2) = (x[1] - x[0], x[2] - x[0]);
        let w0 = x[0] - center;
        let mut sample = |b1: f64, b2: f64| {
            count += 1;
            let v = w0 + e1 * b1 + e2 * b2;
            // Most points of the disk's bounding range are outside the
            // sphere: rejected before the square root.
            let d2 = v.norm_squared();
            if !at_most(d2, rho2) || d2 == rho2 {
                return;
            }
            let b = [1.0 - b1 - b2, b1, b2];
            let dist = d2.sqrt();
            let depth = rho - dist;
            if depth.is_nan() || depth <= 0.0 {
                return;
            }
            // The sample's force k_p dA d along its normal (one division).
            let w = da * depth;
            let fw = if dist > 1e-9 * rho { v * (w / dist) } else { inward * w };
            depth_max = depth_max.max(depth);
            for c in 0..3 {
                fv[c] += fw * b[c];
                kv[c] += da * b[c];
            }
            // Both at their fixed capacity: never grown in the tick.
            if samples_buf.len() < samples_buf.capacity() && samples_at.len() < samples_at.capacity() {
                let dir = fw / w.max(f64::MIN_POSITIVE);
                samples_buf.push(Sample {
                    depth,
                    k: da,
                    vu: 0.0,
                    uu: 0.0,
                    va: 0.0,
                    ua: 0.0,
                });
                samples_at.push(SampleAt {
                    dir: [dir.x as f32, dir.y as f32, dir.z as f32],
                    bary: [b1 as f32, b2 as f32],
                    slots: [NO_SLOT; 3],
                });
            } else {
                *overflow = true;
            }
        };
        // Only the sub-triangles under the disk where the sphere cuts the
        // triangle's plane can press: their index ranges from the disk's
        // centre and radius in barycentric coordinates (1/height per metre).
        let twice_area = face.norm();
        let unit = face / twice_area.max(f64::MIN_POSITIVE);
        let off = (center - x[0]).dot(&unit);
        if off.is_nan() || off.abs() >= rho || twice_area.is_nan() || twice_area <= 0.0 {
            continue;
        }
        let disk = (rho * rho - off * off).sqrt();
        let q = center - unit * off - x[0];
        // Barycentric (b1, b2) of the disk centre: q = b1 e1 + b2 e2.
        let b1 = q.cross(&e2).dot(&unit) / twice_area;
        let b2 = e1.cross(&q).dot(&unit) / twice_area;
        let r1 = disk * e2.norm() / twice_area;
        let r2 = disk * e1.norm() / twice_area;
        let lv = level as f64;
        // floor() then clamp() equals clamp() then truncation (NaN: 0).
        let span = |b: f64, r: f64| -> (usize, usize) {
            let lo = ((b - r) * lv).clamp(0.0, lv - 1.0) as usize;
            let hi = ((b + r) * lv).clamp(0.0, lv - 1.0) as usize;
            (lo, hi)
        };
        let (ilo, ihi) = span(b1, r1);
        let (jlo, jhi) = span(b2, r2);
        let h = 1.0 / lv;
        for i in ilo..=ihi {
            for j in jlo..=jhi.min(level - 1 - i.min(level - 1)) {
                if i + j >= level {
                    break;
                }
                sample((i as f64 + 1.0 / 3.0) * h, (j as f64 + 1.0 / 3.0) * h);
                if i + j + 1 < level {
                    sample((i as f64 + 2.0 / 3.0) * h, (j as f64 + 2.0 / 3.0) * h);
                }
            }
        }
        out.samples += count;
        out.truncated |= overflowed;
        let mut slots = [NO_SLOT; 3];
        for c in 0..3 {
            if kv[c] <= 0.0 {
                continue;
            }
            force += fv[c];
            k += kv[c];
            let node = tri[c];
            match out.active[first..].iter().position(|a| a.node == node) {
                Some(at) => {
                    let a = &mut out.active[first + at];
                    a.f += fv[c];
                    a.k += kv[c];
                    slots[c] = (first + at) as u16;
                }
                None => {
                    let at = out.active.len();
                    if out
                        .active
                        .push(ActiveNode {
                            node,
                            f: fv[c],
                            k: kv[c],
                            deflect: Vec3::zeros(),
                        })
                        .is_err()
                    {
                        out.truncated = true;
                    } else {
                        slots[c] = at as u16;
                    }
                }
            }
        }
        for at in &mut out.samples_at[tri_samples..] {
            at.slots = slots;
        }
    }
    let len = out.active.len() - first;
    let magnitude = force.norm();
    if len == 0 || !(magnitude > 0.0 && magnitude.is_finite() && k > 0.0) {
        out.active.truncate(first);
        out.samples_buf.truncate(sample_first);
        out.samples_at.truncate(sample_first);
        return;
    }
    out.max_depth = out.max_depth.max(depth_max);
    let nodes = &out.active[first..];
    let rest_centre = nodes.iter().map(|a| index.rest(a.node)).sum::<Vec3>() / len as f64;
    let rest_radius = nodes
        .iter()
        .map(|a| (index.rest(a.node) - rest_centre).norm())
        .fold(0.0, f64::max);
    let _ = out.patches.push(Patch {
        sphere: s,
        first: first as u16,
        len: len as u16,
        sample_first: sample_first as u32,
        sample_len: (out.samples_buf.len() - sample_first) as u32,
        force: magnitude,
        k,
        depth: depth_max,
        rho,
        rest_centre,
        rest_radius,
    });
}

/// Finds the triangles that can reach sphere `s` at `center` (into
/// `out.tris`) on the grid; with `motion`, also within the slack, and keeps
/// them for the next evaluations.
#[allow(clippy::too_many_arguments)]
fn search_triangles<'r, const R: usize>(
    index: &SurfaceIndex,
    rho: f64,
    s: u16,
    center: &Vec3,
    position: &impl Fn(u32) -> Vec3,
    rows: &impl Fn(u32) -> Option<&'r SMatrix<f64, 3, R>>,
    motion: Option<&Motion<R>>,
    scratch: &mut Candidates,
    out: &mut ContactOutput<R>,
) {
    out.searches += 1;
    let t0 = crate::rt::clock::now_ns();
    search_triangles_timed(index, rho, s, center, position, rows, motion, scratch, out);
    out.search_ns += crate::rt::clock::now_ns() - t0;
}

/// [`search_triangles`]' work (timed there).
#[allow(clippy::too_many_arguments)]
fn search_triangles_timed<'r, const R: usize>(
    index: &SurfaceIndex,
    rho: f64,
    s: u16,
    center: &Vec3,
    position: &impl Fn(u32) -> Vec3,
    rows: &impl Fn(u32) -> Option<&'r SMatrix<f64, 3, R>>,
    motion: Option<&Motion<R>>,
    scratch: &mut Candidates,
    out: &mut ContactOutput<R>,
) {
    // With the triangles kept, every triangle that can come within the
    // tool radius while the motion stays under the slack.
    let slack = if motion.is_some() { COHERENCE_SLACK_M } else { 0.0 };
    let reach = rho + slack;
    // How far Φ q can move a node from rest + ū (NaN: none is skipped by it).
    let base = motion.and_then(|m| m.offset.map(|o| (o, m.row_bound * m.q.norm())));
    // The query's nodes whose rest position is within the search margin
    // of reaching the sphere, as slots of the index's grid-ordered copy
    // (contiguous runs, read in order, rather than a cache line per node).
    let (found, complete) = index.candidates(center, reach + index.margin, base.map(|b| b.0), scratch);
    out.truncated |= !complete;
    out.candidates += found.min(MAX_CANDIDATES);
    // Triangles with a vertex near enough to reach the sphere.
    out.stamp = out.stamp.wrapping_add(1);
    if out.stamp == 0 {
        out.stamps.iter_mut().for_each(|s| *s = 0);
        out.stamp = 1;
    }
    // The mesh-ordered arrays the next passes read are scattered, so the
    // search waits on memory more than it computes: each pass asks for
    // the lines of the nodes it will read while it works on the current
    // one. First the candidates whose deformed position can reach the
    // sphere, compacted in place (the candidates pass asked for their ū).
    let mut kept_n = 0;
    for k in 0..scratch.len() {
        let slot = scratch[k] as usize;
        let (sl, i) = (&index.slots[slot], index.nodes[slot]);
        if let Some((offset, moved)) = base {
            if let Some(u) = offset.get(i as usize) {
                let within = reach + sl.reach + moved;
                if (sl.rest + u - center).norm_squared() > within * within {
                    continue;
                }
            }
        }
        prefetch(index.rest.get(i as usize));
        scratch[kept_n] = slot as u32;
        kept_n += 1;
    }
    scratch.truncate(kept_n);
    // Then their deformed positions and triangles.
    for k in 0..scratch.len() {
        if let Some(&j) = scratch.get(k + PREFETCH_AHEAD) {
            let j = index.nodes[j as usize];
            if let Some(r) = rows(j) {
                prefetch_all(r);
            }
            prefetch(out.cache.get(j as usize));
            prefetch(index.node_tri_start.get(j as usize));
        }
        let slot = scratch[k] as usize;
        let i = index.nodes[slot];
        let x = out.position_of(i, position);
        let near = reach + index.slots[slot].reach;
        if !at_most((x - center).norm_squared(), near * near) {
            continue;
        }
        for &t in index.triangles_of(i) {
            out.visit(t);
        }
    }
    let Some(m) = motion else { return };
    let s = s as usize;
    if s >= out.kept.len() {
        return;
    }
    out.kept[s].valid = false;
    if !complete || out.tris.is_full() {
        return;
    }
    // Keep the triangles that come within the slack, with their distance.
    let base = s * KEPT_TRIANGLES;
    let mut len = 0usize;
    for ti in 0..out.tris.len() {
        // Two stages: a triangle's vertex list, then (when it has come in)
        // its vertices' basis rows and cached positions, since a vertex
        // the candidates' filters passed over is reconstructed here.
        if let Some(&u) = out.tris.get(ti + 2 * PREFETCH_AHEAD) {
            prefetch(index.tris.get(u as usize));
        }
        if let Some(&u) = out.tris.get(ti + PREFETCH_AHEAD) {
            for &v in &index.tris[u as usize] {
                if let Some(r) = rows(v) {
                    prefetch_all(r);
                }
                prefetch(out.cache.get(v as usize));
            }
        }
        let t = out.tris[ti];
        let x = index.tris[t as usize].map(|v| out.position_of(v, position));
        if !within_bounding_sphere(&x, center, reach) {
            continue;
        }
        let dist = (crate::math::closest_on_triangle(*center, x[0], x[1], x[2]) - center).norm();
        if dist > reach {
            continue;
        }
        if len == KEPT_TRIANGLES {
            return;
        }
        out.kept_tris[base + len] = t;
        out.kept_dist[base + len] = dist;
        len += 1;
    }
    out.searched |= 1 << s;
    out.kept[s] = Kept {
        valid: true,
        center: *center,
        q: *m.q,
        len: len as u16,
        carried: 0.0,
    };
    // The tick integrates the kept ones that touch the sphere now (the
    // others cannot press).
    out.tris.clear();
    out.take_kept(s, rho, 0.0);
}

/// How many candidates ahead the search asks for memory ([`prefetch`]).
const PREFETCH_AHEAD: usize = 6;

/// Asks the CPU to bring the cache line holding `*p` in ahead of its use:
/// a hint only, with no effect on any result (and none off x86-64).
#[inline(always)]
fn prefetch<T>(p: Option<&T>) {
    #[cfg(target_arch = "x86_64")]
    if let Some(p) = p {
        // SAFETY: a prefetch never faults nor reads into the program,
        // whatever the address; this one is a live reference anyway.
        unsafe { std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>((p as *const T).cast::<i8>()) }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// [`prefetch`] for every cache line of `*p` (a node's basis rows span
/// several).
#[inline(always)]
fn prefetch_all<T>(p: &T) {
    #[cfg(target_arch = "x86_64")]
    {
        let base = (p as *const T).cast::<i8>();
        for off in (0..std::mem::size_of::<T>()).step_by(64) {
            // SAFETY: as in `prefetch`; the address stays inside `*p`.
            unsafe { std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(base.wrapping_add(off)) }
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// Whether the sphere about the triangle `x`'s centroid through its
/// farthest vertex comes within `r` of `center` (false if NaN): one square
/// root, so it is cheap enough to run on every kept triangle every tick.
fn within_bounding_sphere(x: &[Vec3; 3], center: &Vec3, r: f64) -> bool {
    let centroid = (x[0] + x[1] + x[2]) / 3.0;
    let spread2 = x.iter().map(|v| (v - centroid).norm_squared()).fold(0.0, f64::max);
    let reach = r + spread2.sqrt();
    at_most((centroid - center).norm_squared(), reach * reach)
}

/// a ≤ b, false if either is NaN.
fn at_most(a: f64, b: f64) -> bool {
    a <= b
}

/// Records the force `f` on the tissue at `node`: tool reaction, the
/// touched-node list.
fn push_force<const R: usize>(out: &mut ContactOutput<R>, node: u32, sphere: u16, f: Vec3) {
    out.tool_force -= f;
    if let Some(s) = out.sphere_forces.get_mut(sphere as usize) {
        *s -= f;
    }
    if out.nodes.push(NodeContact { node, force: f, sphere }).is_err() {
        out.truncated = true;
    }
}

/// K += α x yᵀ, column by column (contiguous, so it vectorizes; nalgebra's
/// `ger` calls a non-inlined axpy per column).
pub(crate) fn add_outer<const R: usize>(
    k: &mut SMatrix<f64, R, R>,
    alpha: f64,
    x: &SVector<f64, R>,
    y: &SVector<f64, R>,
) {
    let x = x.as_slice();
    for (col, &yj) in k.as_mut_slice().chunks_exact_mut(R).zip(y.as_slice()) {
        let a = alpha * yj;
        for (kij, &xi) in col.iter_mut().zip(x) {
            *kij += xi * a;
        }
    }
}

/// Patch `p`'s unit-load shape G_p = Σ_a Φ_aᵀ e_a (e_a = f_a / |Σ f|).
fn patch_rows<'r, const R: usize>(
    p: &Patch,
    active: &[ActiveNode],
    rows: &impl Fn(u32) -> Option<&'r SMatrix<f64, 3, R>>,
) -> SVector<f64, R> {
    let mut g = SVector::<f64, R>::zeros();
    for a in &active[p.first as usize..(p.first + p.len) as usize] {
        if let Some(phi) = rows(a.node) {
            g += phi.tr_mul(&(a.f / p.force));
        }
    }
    g
}

/// The penalty alone: node forces as pressed, K_c = Σ_a k_a g_a g_aᵀ
/// (g_a = Φ_aᵀ n_a, n_a the direction of the node's force).
fn plain_patches<'r, const R: usize>(
    rows: &impl Fn(u32) -> Option<&'r SMatrix<f64, 3, R>>,
    out: &mut ContactOutput<R>,
) {
    for pi in 0..out.patches.len() {
        let p = out.patches[pi];
        plain_patch(&p, rows, out);
    }
}

/// One patch with the penalty alone (see [`plain_patches`]).
fn plain_patch<'r, const R: usize>(
    p: &Patch,
    rows: &impl Fn(u32) -> Option<&'r SMatrix<f64, 3, R>>,
    out: &mut ContactOutput<R>,
) {
    for ai in p.first as usize..(p.first + p.len) as usize {
        let a = out.active[ai];
        push_force(out, a.node, p.sphere, a.f);
        let fa = a.f.norm();
        if let (Some(phi), true) = (rows(a.node), fa > 0.0) {
            let g = phi.tr_mul(&(a.f / fa));
            add_outer(&mut out.reduced_stiffness, a.k, &g, &g);
        }
    }
}

#[allow(clippy::needless_range_loop)] // index arithmetic reads as the formula
/// In-place Cholesky of the leading m × m block of `a` (lower triangle);
/// false if not positive definite.
fn cholesky_in_place(a: &mut [[f64; MAX_COMPLIANT_PATCHES]; MAX_COMPLIANT_PATCHES], m: usize) -> bool {
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
fn cholesky_solve(
    l: &[[f64; MAX_COMPLIANT_PATCHES]; MAX_COMPLIANT_PATCHES],
    m: usize,
    b: &mut [f64; MAX_COMPLIANT_PATCHES],
) {
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

/// Newton iterations of the series solve at most (each settles the set of
/// pressed samples; the piecewise-linear law converges in a few).
const SERIES_ITERATIONS: usize = 16;

/// Patch `q`'s pressure law at a deflection `delta` of the tissue under it:
/// (F, −dF/dδ) with F(δ) the patch's pressure summed along its force
/// direction a with every sample moved by its share of the dent,
///
/// ```text
/// F(δ) = Σ_i k_i (ρ − r_i) (w_i · a) / r_i,   w_i = v_i + u_i δ,   r_i = |w_i| < ρ
/// ```
///
/// (v_i the sample's offset from the sphere's centre, u_i its dent per
/// unit δ, [`patch_shape`]), so F(0) is the pressed magnitude and a deep
/// patch's rim, whose pressure is nearly tangent to the wall, leaves the
/// sphere as the wall under it sinks: the distance |v + u δ| is exact for
/// the sample, where its first-order change v̂·u δ kept the rim pressing
/// far past where the full model releases it (docs/RESULTS.md, "At
/// depth"). A sample whose pressure would grow with δ adds nothing to
/// −dF/dδ (the law's slope stays that of a spring; F is exact).
fn patch_law<const R: usize>(q: usize, out: &ContactOutput<R>, delta: f64) -> (f64, f64) {
    let p = &out.patches[q];
    let rho = p.rho;
    let rho2 = rho * rho;
    let (mut f, mut k) = (0.0, 0.0);
    for smp in samples_of(p, &out.samples_buf) {
        let r0 = rho - smp.depth;
        let r2 = r0 * r0 + delta * (2.0 * smp.vu + delta * smp.uu);
        if r2.is_nan() || r2 >= rho2 {
            continue;
        }
        let r = r2.sqrt();
        let g = smp.va + smp.ua * delta;
        if r > 1e-9 * rho {
            let inv = 1.0 / r;
            let grow = rho * inv - 1.0;
            f += smp.k * grow * g;
            // d/dδ [(ρ/r − 1) g] = −ρ (w·u) g / r³ + (ρ/r − 1) (u·a).
            let wu = smp.vu + smp.uu * delta;
            let slope = rho * wu * g * inv * inv * inv - grow * smp.ua;
            if slope > 0.0 {
                k += smp.k * slope;
            }
        } else {
            f += smp.k * (rho - r);
        }
    }
    (f, k)
}

/// Patch `p`'s pressure samples.
fn samples_of<'a>(p: &Patch, buf: &'a [Sample]) -> &'a [Sample] {
    &buf[p.sample_first as usize..(p.sample_first + p.sample_len) as usize]
}

/// The deflection shape of patch `q` under its own load, from its nodes'
/// `deflect` (Σ_b ΔW_ab f_b) and its self-coupling `s_qq`: sample i, at
/// barycentric b_c between the nodes of its triangle, moves by
///
/// ```text
/// u_i δ,   u_i = Σ_c b_c (ΔW e)_c / S_qq,   δ = S_qq P
/// ```
///
/// (its |e|-weighted mean along the pressure is 1). The wall bows most
/// under the patch's centre, so at depth the rim keeps pressing while the
/// centre gives; with one uniform deflection the shallow rim of a deep
/// patch was released as fast as the centre went (measured too soft at
/// 2–3 mm: docs/RESULTS.md). Fills each sample's v·u, u·u, v·a, u·a for
/// [`patch_law`] (v its offset from the centre, a the patch's force
/// direction). A sample whose vertices are not all listed, or a patch
/// without a usable `s_qq`, moves along its own pressure by δ.
fn patch_shape<const R: usize>(q: usize, s_qq: f64, out: &mut ContactOutput<R>) {
    let p = out.patches[q];
    let range = p.sample_first as usize..(p.sample_first + p.sample_len) as usize;
    let nodes = &out.active[p.first as usize..(p.first + p.len) as usize];
    let axis = nodes.iter().map(|a| a.f).sum::<Vec3>() / p.force.max(f64::MIN_POSITIVE);
    let shaped = s_qq > 0.0 && s_qq.is_finite() && p.force > 0.0;
    // (ΔW e)_c = deflect_c / F, divided by S.
    let scale = if shaped { 1.0 / (p.force * s_qq) } else { 0.0 };
    let active = &out.active;
    for (smp, at) in out.samples_buf[range.clone()].iter_mut().zip(&out.samples_at[range]) {
        let n = Vec3::new(at.dir[0] as f64, at.dir[1] as f64, at.dir[2] as f64);
        let u = if shaped && !at.slots.contains(&NO_SLOT) {
            let (b1, b2) = (at.bary[0] as f64, at.bary[1] as f64);
            let b = [1.0 - b1 - b2, b1, b2];
            let mut u = Vec3::zeros();
            for c in 0..3 {
                u += active[at.slots[c] as usize].deflect * b[c];
            }
            u * scale
        } else {
            n
        };
        let r0 = p.rho - smp.depth;
        smp.vu = r0 * n.dot(&u);
        smp.uu = u.norm_squared();
        smp.va = r0 * n.dot(&axis);
        smp.ua = u.dot(&axis);
    }
}

/// S_pq = Σ_ab e_aᵀ ΔW_ab e_b over the nodes of patches `p` and `q`, with
/// e_a = f_a / F the patch's load shape.
fn patch_coupling<const R: usize>(w: &LocalCompliance, p: usize, q: usize, out: &mut ContactOutput<R>) -> f64 {
    // Σ f_aᵀ ΔW_ab f_b over the node forces, scaled once by 1 / (F_p F_q).
    if p == q {
        let pa = out.patches[p];
        if out.keep_pair_blocks(w, &pa) {
            let (len, first) = (pa.len as usize, pa.first as usize);
            let base = pa.sphere as usize * PAIR_CACHE_NODES * PAIR_CACHE_NODES;
            let mut s = 0.0;
            for ai in 0..len {
                let row = &out.pair_blocks[base + ai * len..base + (ai + 1) * len];
                let nodes = &out.active[first..first + len];
                let v: Vec3 = nodes.iter().zip(row).map(|(b, blk)| blk * b.f).sum();
                s += nodes[ai].f.dot(&v);
                out.active[first + ai].deflect = v;
            }
            return s / (pa.force * pa.force);
        }
        // More nodes than are kept: each row from the table.
        let (len, first) = (pa.len as usize, pa.first as usize);
        let mut s = 0.0;
        for ai in first..first + len {
            let a = out.active[ai];
            let v: Vec3 = out.active[first..first + len]
                .iter()
                .filter_map(|b| w.block(a.node, b.node).map(|blk| blk * b.f))
                .sum();
            s += a.f.dot(&v);
            out.active[ai].deflect = v;
        }
        return s / (pa.force * pa.force);
    }
    let (p, q) = (&out.patches[p], &out.patches[q]);
    let apart = (p.rest_centre - q.rest_centre).norm() - p.rest_radius - q.rest_radius;
    if apart > w.reach() {
        return 0.0;
    }
    let mut s = 0.0;
    for a in &out.active[p.first as usize..(p.first + p.len) as usize] {
        for b in &out.active[q.first as usize..(q.first + q.len) as usize] {
            if let Some(blk) = w.block(a.node, b.node) {
                s += a.f.dot(&(blk * b.f));
            }
        }
    }
    s / (p.force * q.force)
}

/// The patches with the residual compliance in series: one unknown per
/// patch, its force magnitude, with the pressed distribution as its load
/// shape e_a = f_a / F. The tissue under patch p deflects by δ = S P
/// (S_pq = Σ e_aᵀ ΔW_ab e_b) and the patch presses with its law
/// P_p = F_p(δ_p); Newton on the piecewise-linear laws solves
/// (K⁻¹ + S) P = F/K + δ with K = dF/dδ, P ≥ 0 (a patch pulled into the
/// tool is released). Node forces P e_a, K_c = G (K⁻¹ + S)⁻¹ Gᵀ.
/// (One unknown per touched node instead, with the nodes' shares of the
/// pressure as separate laws, was measured less accurate: docs/REDUCED.md.)
#[allow(clippy::needless_range_loop)] // index arithmetic reads as the formula
fn series_patches<'r, const R: usize>(
    w: &LocalCompliance,
    rows: &impl Fn(u32) -> Option<&'r SMatrix<f64, 3, R>>,
    out: &mut ContactOutput<R>,
) {
    const C: usize = MAX_COMPLIANT_PATCHES;
    let m = out.patches.len().min(C);
    out.uncorrected = out.patches.len() - m;
    if out.last_table != w.id() {
        out.last_table = w.id();
        out.last_force = [0.0; MAX_SPHERES];
    }
    let mut s = [[0.0f64; C]; C];
    for a in 0..m {
        for b in 0..=a {
            s[a][b] = patch_coupling(w, a, b, out);
            s[b][a] = s[a][b];
        }
        patch_shape(a, s[a][a], out);
    }
    // Patches that do not load each other are separate problems: solve
    // each group of coupled patches on its own (most patches of an
    // instrument are far apart, so this is m scalar problems, not one
    // m × m one).
    let mut group = [0usize; C];
    for a in 0..m {
        group[a] = a;
    }
    for a in 0..m {
        for b in 0..a {
            if s[a][b] != 0.0 {
                let (ga, gb) = (group[a], group[b]);
                if ga != gb {
                    let (keep, gone) = (ga.min(gb), ga.max(gb));
                    group[..m].iter_mut().filter(|g| **g == gone).for_each(|g| *g = keep);
                }
            }
        }
    }
    out.corrected = m == out.patches.len();
    let mut depth = None::<f64>;
    // Scratch of the groups' solves (zeroed once here, not per group).
    let mut l = [[0.0f64; C]; C];
    let mut g_rows = [SVector::<f64, R>::zeros(); C];
    let mut fresh = [Vec3::zeros(); MAX_CONTACT_NODES];
    for g in 0..m {
        let mut idx = [0usize; C];
        let mut k = 0;
        for a in 0..m {
            if group[a] == g {
                idx[k] = a;
                k += 1;
            }
        }
        if k == 0 {
            continue;
        }
        match series_group(&s, &idx[..k], rows, &mut l, &mut g_rows, &mut fresh, out) {
            Some(d) => depth = Some(depth.map_or(d, |x: f64| x.max(d))),
            None => {
                // Not positive definite (a corrupt table): the plain penalty.
                out.corrected = false;
                for &a in &idx[..k] {
                    let pa = out.patches[a];
                    plain_patch(&pa, rows, out);
                }
            }
        }
    }
    if let Some(d) = depth {
        out.max_depth = d;
    }
    // Patches beyond the corrected ones: the plain penalty.
    for pi in m..out.patches.len() {
        let pa = out.patches[pi];
        plain_patch(&pa, rows, out);
    }
}

/// One group of coupled patches `idx` (indices into `out.patches`) of the
/// series solve ([`series_patches`]): Newton on their laws with the
/// couplings `s`, then the patches' node forces taken from their samples
/// at the solution (each sample moved by its share of the dent, so the
/// pressure is the one the deflected surface takes: a deep patch's rim, and
/// a far surface the undeflected probe reached, let go, [`redistribute`]),
/// and their reduced stiffness, into `out`. Returns the deepest
/// penetration into the deflected surface, or None if the system is not
/// positive definite (nothing written). `l`, `g` and `fresh` are scratch
/// (overwritten where used).
#[allow(clippy::needless_range_loop)] // index arithmetic reads as the formula
fn series_group<'r, const R: usize>(
    s_all: &[[f64; MAX_COMPLIANT_PATCHES]; MAX_COMPLIANT_PATCHES],
    idx: &[usize],
    rows: &impl Fn(u32) -> Option<&'r SMatrix<f64, 3, R>>,
    l: &mut [[f64; MAX_COMPLIANT_PATCHES]; MAX_COMPLIANT_PATCHES],
    g: &mut [SVector<f64, R>; MAX_COMPLIANT_PATCHES],
    fresh: &mut [Vec3; MAX_CONTACT_NODES],
    out: &mut ContactOutput<R>,
) -> Option<f64> {
    const C: usize = MAX_COMPLIANT_PATCHES;
    let m = idx.len();
    let mut on = [false; C];
    let mut p = [0.0f64; C];
    let mut delta = [0.0f64; C];
    let mut kk = [0.0f64; C];
    if !solve_group(s_all, idx, l, &mut on, &mut p, &mut delta, &mut kk, out) {
        return None;
    }
    for a in 0..m {
        on[a] = on[a] && p[a] > 0.0;
    }
    let depth = redistribute(s_all, idx, &on, &p, &delta, fresh, out);
    for a in 0..m {
        let pa = out.patches[idx[a]];
        g[a] = patch_rows(&pa, &out.active, rows);
        if on[a] {
            for ai in pa.first as usize..(pa.first + pa.len) as usize {
                let node = out.active[ai];
                push_force(out, node.node, pa.sphere, node.f);
            }
        }
    }
    // K_c = G (K⁻¹ + S)⁻¹ Gᵀ on the live patches.
    for b in 0..m {
        if !on[b] {
            continue;
        }
        let mut col = [0.0f64; C];
        col[b] = 1.0;
        cholesky_solve(l, m, &mut col);
        let mut h = SVector::<f64, R>::zeros();
        for a in 0..m {
            if on[a] {
                h += g[a] * col[a];
            }
        }
        add_outer(&mut out.reduced_stiffness, 1.0, &h, &g[b]);
    }
    Some(depth)
}

/// Newton on the laws of the patches `idx` with the couplings `s_all`:
/// (K⁻¹ + S) P = F/K + δ, K = −dF/dδ at the last δ, a patch pulled into
/// the tool released (`on` false). Leaves the factor of the last system
/// in `l`, and P, δ = S P and K in `p`, `delta`, `kk`; false if the system
/// is not positive definite or the forces are not finite.
#[allow(clippy::needless_range_loop)] // index arithmetic reads as the formula
#[allow(clippy::too_many_arguments)]
fn solve_group<const R: usize>(
    s_all: &[[f64; MAX_COMPLIANT_PATCHES]; MAX_COMPLIANT_PATCHES],
    idx: &[usize],
    l: &mut [[f64; MAX_COMPLIANT_PATCHES]; MAX_COMPLIANT_PATCHES],
    on: &mut [bool; MAX_COMPLIANT_PATCHES],
    p: &mut [f64; MAX_COMPLIANT_PATCHES],
    delta: &mut [f64; MAX_COMPLIANT_PATCHES],
    kk: &mut [f64; MAX_COMPLIANT_PATCHES],
    out: &mut ContactOutput<R>,
) -> bool {
    const C: usize = MAX_COMPLIANT_PATCHES;
    let m = idx.len();
    let s = |a: usize, b: usize| s_all[idx[a]][idx[b]];
    on[..m].iter_mut().for_each(|o| *o = true);
    delta[..m].iter_mut().for_each(|d| *d = 0.0);
    if m == 1 {
        return solve_single(s(0, 0), idx[0], l, on, p, delta, kk, out);
    }
    let mut ok = false;
    let scale = idx.iter().map(|&a| out.patches[a].depth).fold(0.0, f64::max);
    for _ in 0..SERIES_ITERATIONS + m {
        out.iterations += 1;
        let mut rhs = [0.0f64; C];
        for a in 0..m {
            let (f, k) = patch_law(idx[a], out, delta[a]);
            kk[a] = k;
            rhs[a] = if on[a] && k > 0.0 { f / k + delta[a] } else { 0.0 };
        }
        let live = |a: usize| on[a] && kk[a] > 0.0;
        for a in 0..m {
            for b in 0..=a {
                l[a][b] = if !(live(a) && live(b)) {
                    (a == b) as u8 as f64
                } else {
                    s(a, b) + if a == b { 1.0 / kk[a] } else { 0.0 }
                };
            }
        }
        if !cholesky_in_place(l, m) {
            return false;
        }
        *p = rhs;
        cholesky_solve(l, m, p);
        let worst = (0..m)
            .filter(|&a| live(a) && p[a] < 0.0)
            .min_by(|&a, &b| p[a].total_cmp(&p[b]));
        if let Some(a) = worst {
            on[a] = false;
            out.released += 1;
            continue;
        }
        for a in 0..m {
            if !live(a) {
                p[a] = 0.0;
            }
        }
        let mut change = 0.0f64;
        for a in 0..m {
            let d: f64 = (0..m).map(|b| s(a, b) * p[b]).sum();
            change = change.max((d - delta[a]).abs());
            delta[a] = d;
        }
        ok = true;
        if change <= 1e-9 * scale {
            break;
        }
    }
    for a in 0..m {
        on[a] = on[a] && kk[a] > 0.0;
    }
    ok && p[..m].iter().all(|v| v.is_finite())
}

/// [`solve_group`] for a patch alone: P = F(S P) by Newton's method kept
/// inside a bracket (g(P) = P − F(S P) rises from −F(0) at P = 0), so a
/// law whose slope the clamp of [`patch_law`] understates, or that bends
/// as a deep patch's samples leave the sphere, still converges.
#[allow(clippy::too_many_arguments)]
fn solve_single<const R: usize>(
    s: f64,
    q: usize,
    l: &mut [[f64; MAX_COMPLIANT_PATCHES]; MAX_COMPLIANT_PATCHES],
    on: &mut [bool; MAX_COMPLIANT_PATCHES],
    p: &mut [f64; MAX_COMPLIANT_PATCHES],
    delta: &mut [f64; MAX_COMPLIANT_PATCHES],
    kk: &mut [f64; MAX_COMPLIANT_PATCHES],
    out: &mut ContactOutput<R>,
) -> bool {
    if !(s >= 0.0 && s.is_finite()) {
        return false;
    }
    let tol = 1e-9 * out.patches[q].force;
    let (mut lo, mut hi) = (0.0f64, f64::INFINITY);
    // From the last tick's force: a held or slowly moving patch is there
    // within one or two steps.
    let sphere = out.patches[q].sphere as usize;
    let mut pv = match out.last_force.get(sphere) {
        Some(&f) if f > 0.0 && f.is_finite() => f,
        _ => 0.0,
    };
    let (mut f, mut k) = (0.0, 0.0);
    for _ in 0..2 * SERIES_ITERATIONS {
        out.iterations += 1;
        (f, k) = patch_law(q, out, s * pv);
        let g = pv - f;
        if g < 0.0 {
            lo = pv;
        } else {
            hi = pv;
        }
        if g.abs() <= tol {
            break;
        }
        let mut next = pv - g / (1.0 + s * k);
        if !(next > lo && next < hi) {
            next = if hi.is_finite() {
                0.5 * (lo + hi)
            } else {
                lo.max(f) * 2.0
            };
        }
        pv = next;
    }
    if !(pv.is_finite() && f.is_finite()) {
        return false;
    }
    kk[0] = k;
    p[0] = pv;
    delta[0] = s * pv;
    on[0] = pv > 0.0 && k > 0.0;
    if !on[0] {
        p[0] = 0.0;
        delta[0] = 0.0;
        out.released += 1;
    }
    l[0][0] = if on[0] { (s + 1.0 / k).sqrt() } else { 1.0 };
    if let Some(last) = out.last_force.get_mut(sphere) {
        *last = p[0];
    }
    true
}

/// The node forces of the patches `idx` at their solution (`on`, force
/// P, deflection δ): each pressed sample, moved by its share of the dent
/// u δ ([`patch_shape`]), presses with k (ρ − r) along its offset w from
/// the centre (r = |w|), lumped to its triangle's nodes. The forces go
/// into `out.active` and each live patch's `force` becomes |Σ f| (a patch
/// whose samples' pressures cancel keeps P e). Returns the deepest
/// penetration. `fresh` is scratch.
#[allow(clippy::too_many_arguments)]
#[allow(clippy::needless_range_loop)] // index arithmetic reads as the formula
fn redistribute<const R: usize>(
    s_all: &[[f64; MAX_COMPLIANT_PATCHES]; MAX_COMPLIANT_PATCHES],
    idx: &[usize],
    on: &[bool; MAX_COMPLIANT_PATCHES],
    p: &[f64; MAX_COMPLIANT_PATCHES],
    delta: &[f64; MAX_COMPLIANT_PATCHES],
    fresh: &mut [Vec3; MAX_CONTACT_NODES],
    out: &mut ContactOutput<R>,
) -> f64 {
    let mut depth = 0.0f64;
    for (a, &q) in idx.iter().enumerate() {
        if !on[a] {
            continue;
        }
        let pa = out.patches[q];
        let (first, len) = (pa.first as usize, pa.len as usize);
        let s_qq = s_all[q][q];
        let shaped = s_qq > 0.0 && s_qq.is_finite() && pa.force > 0.0;
        // As in `patch_shape`: u = Σ_c b_c deflect_c / (F S_qq).
        let unit = if shaped { 1.0 / (pa.force * s_qq) } else { 0.0 };
        let (d, rho) = (delta[a], pa.rho);
        fresh[..len].iter_mut().for_each(|f| *f = Vec3::zeros());
        let range = pa.sample_first as usize..(pa.sample_first + pa.sample_len) as usize;
        for (smp, at) in out.samples_buf[range.clone()].iter().zip(&out.samples_at[range]) {
            let r0 = rho - smp.depth;
            let r2 = r0 * r0 + d * (2.0 * smp.vu + d * smp.uu);
            if r2.is_nan() || r2 >= rho * rho {
                continue;
            }
            let r = r2.sqrt();
            depth = depth.max(rho - r);
            let n = Vec3::new(at.dir[0] as f64, at.dir[1] as f64, at.dir[2] as f64);
            let (b1, b2) = (at.bary[0] as f64, at.bary[1] as f64);
            let b = [1.0 - b1 - b2, b1, b2];
            let u = if shaped && !at.slots.contains(&NO_SLOT) {
                let mut u = Vec3::zeros();
                for c in 0..3 {
                    u += out.active[at.slots[c] as usize].deflect * b[c];
                }
                u * unit
            } else {
                n
            };
            let w = n * r0 + u * d;
            let f = if r > 1e-9 * rho {
                w * (smp.k * (rho - r) / r)
            } else {
                n * (smp.k * (rho - r))
            };
            for c in 0..3 {
                if let Some(x) = (at.slots[c] as usize).checked_sub(first).and_then(|i| fresh.get_mut(i)) {
                    *x += f * b[c];
                }
            }
        }
        let force = fresh[..len].iter().sum::<Vec3>().norm();
        if !(force > 0.0 && force.is_finite()) {
            // The samples' pressures cancel: the forces P e of the law.
            let scale = p[a] / pa.force;
            out.active[first..first + len].iter_mut().for_each(|n| n.f *= scale);
            out.patches[q].force = p[a];
            continue;
        }
        for (n, f) in out.active[first..first + len].iter_mut().zip(&fresh[..len]) {
            n.f = *f;
        }
        out.patches[q].force = force;
    }
    depth
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
            let reach = p.tool_radius_m + p.search_margin_m + idx.max_edge() + COHERENCE_SLACK_M;
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
    fn a_search_keeps_exactly_the_triangles_within_reach_on_random_spheres() {
        // A deformed plate (ū up to 2 mm, Φ q up to 2 mm per node: under
        // the 8 mm search margin), many spheres about its top face: the
        // triangles a search keeps are exactly those of a brute force over
        // every surface triangle at its deformed position, and the force
        // is the one the search without the motion's filters renders.
        let mesh = plate();
        let p = ContactParams::default();
        let idx = SurfaceIndex::new(&mesh, &p);
        let mut seed = 11u64;
        let mut next = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let n = mesh.num_nodes();
        let offset: Vec<Vec3> = (0..n)
            .map(|_| Vec3::new(next(), next(), next()) * 2e-3 / 3f64.sqrt())
            .collect();
        let rows: Vec<SMatrix<f64, 3, 2>> = (0..n).map(|_| SMatrix::from_fn(|_, _| next())).collect();
        let row_bound = rows.iter().map(|r| r.norm()).fold(0.0, f64::max);
        let q = SVector::<f64, 2>::new(next(), next()).normalize() * (2e-3 / row_bound);
        let rest = mesh.rest();
        let at = |i: u32| rest[i as usize] + offset[i as usize] + rows[i as usize] * q;
        let motion = Motion {
            q: &q,
            row_bound,
            offset: Some(&offset),
        };
        let mut scratch = Candidates::new();
        let (mut out, mut plain) = (ContactOutput::<2>::for_index(&idx), ContactOutput::<2>::for_index(&idx));
        let reach = p.tool_radius_m + COHERENCE_SLACK_M;
        let mut pressed = 0;
        for _ in 0..400 {
            let c = Vec3::new(0.02 + 0.036 * next(), 0.02 + 0.036 * next(), 0.002 + 0.01 * next());
            out.forget();
            evaluate_spheres(
                &idx,
                &p,
                &[c],
                at,
                |i| rows.get(i as usize),
                None,
                Some(motion),
                &mut scratch,
                &mut out,
            );
            assert_eq!(out.searches, 1);
            assert!(!out.truncated);
            let kept = out.kept[0];
            assert!(kept.valid, "{c}: the triangles fit");
            let mut got: Vec<u32> = out.kept_tris[..kept.len as usize].to_vec();
            let mut want: Vec<u32> = (0..idx.tris.len() as u32)
                .filter(|&t| {
                    let x = idx.tris[t as usize].map(at);
                    (crate::math::closest_on_triangle(c, x[0], x[1], x[2]) - c).norm() <= reach
                })
                .collect();
            got.sort_unstable();
            want.sort_unstable();
            assert_eq!(got, want, "sphere at {c}");
            evaluate_spheres(
                &idx,
                &p,
                &[c],
                at,
                |i| rows.get(i as usize),
                None,
                None,
                &mut scratch,
                &mut plain,
            );
            assert!(
                (out.tool_force - plain.tool_force).norm() <= 1e-12 * plain.tool_force.norm(),
                "{c}: {} vs {}",
                out.tool_force,
                plain.tool_force
            );
            pressed += usize::from(plain.tool_force.norm() > 0.0);
        }
        assert!(pressed > 50, "{pressed} of the spheres press");
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
        // The deepest pressure sample lies within a sample spacing of the
        // pole: its depth is h less at most the sphere's sag over it.
        let sag = (p.tool_radius_m / SAMPLES_PER_RADIUS).powi(2) / p.tool_radius_m;
        assert!(
            out.max_depth <= h && out.max_depth >= h - sag,
            "{} vs {h}",
            out.max_depth
        );
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
        let row = SMatrix::<f64, 3, 2>::new(0.0, 1.0, 0.0, 0.0, 1.0, 0.0);
        let rows = |_| Some(&row);
        evaluate(&idx, &p, &c, |i| mesh.rest()[i as usize], rows, &mut scratch, &mut out);
        let fz: f64 = out.nodes.iter().map(|n| n.force.z).sum();
        let fx: f64 = out.nodes.iter().map(|n| n.force.x).sum();
        assert!((out.reduced_force[0] - fz).abs() <= 1e-12 * fz.abs());
        assert!((out.reduced_force[1] - fx).abs() <= 1e-12 * fz.abs());
        assert!(out.reduced_stiffness[(0, 0)] > 0.0);
        let k = out.reduced_stiffness;
        assert!((k - k.transpose()).norm() <= 1e-12 * k.norm());
    }

    #[test]
    fn a_fading_model_takes_over_the_new_models_search_and_renders_the_same() {
        // Two models on the same rows: the old one's positions at q are the
        // new one's at q + shift moved by at most d (ū changed by `off`).
        let mesh = plate();
        let p = ContactParams::default();
        let idx = SurfaceIndex::new(&mesh, &p);
        let row = SMatrix::<f64, 3, 2>::new(0.0, 1.0, 0.0, 0.0, 1.0, 0.0);
        let rows = |_| Some(&row);
        let off = Vec3::new(0.0, 0.0, 1e-4);
        let shift = SVector::<f64, 2>::new(2e-5, 3e-5);
        let d = (off + row * shift).norm();
        let u_new = vec![off; mesh.num_nodes()];
        let u_old = vec![Vec3::zeros(); mesh.num_nodes()];
        let q_old = SVector::<f64, 2>::new(-1e-4, 5e-5);
        let q_new = q_old + shift;
        let rest = mesh.rest();
        let old_at = |q: SVector<f64, 2>| move |i: u32| rest[i as usize] + row * q;
        let new_at = |q: SVector<f64, 2>| {
            let u_new = &u_new;
            move |i: u32| rest[i as usize] + u_new[i as usize] + row * q
        };
        fn motion<'a>(q: &'a SVector<f64, 2>, u: &'a [Vec3]) -> Option<Motion<'a, 2>> {
            Some(Motion {
                q,
                row_bound: 1.0,
                offset: Some(u),
            })
        }
        let mut scratch = Candidates::new();
        let press_new = |c: &[Vec3], scratch: &mut Candidates, out: &mut ContactOutput<2>| {
            evaluate_spheres(
                &idx,
                &p,
                c,
                new_at(q_new),
                rows,
                None,
                motion(&q_new, &u_new),
                scratch,
                out,
            )
        };
        let (mut new, mut old, mut fresh) = (
            ContactOutput::<2>::for_index(&idx),
            ContactOutput::<2>::for_index(&idx),
            ContactOutput::<2>::for_index(&idx),
        );
        for (k, dx) in [0.0, 2e-4, 1.5e-3].into_iter().enumerate() {
            let c = [Vec3::new(0.02 + dx, 0.02, 0.002 + p.tool_radius_m - 5e-4)];
            press_new(&c, &mut scratch, &mut new);
            let om = motion(&q_old, &u_old).unwrap();
            let adopted = old.adopt_searches(&new, d, &shift, &c, &om);
            // The new model searched on the first tick and after 1.5 mm;
            // the old one takes those searches over, and reuses its kept
            // triangles in between.
            assert_eq!(new.searches, usize::from(k != 1), "tick {k}");
            assert_eq!(adopted, new.searches, "tick {k}");
            evaluate_spheres(
                &idx,
                &p,
                &c,
                old_at(q_old),
                rows,
                None,
                Some(om),
                &mut scratch,
                &mut old,
            );
            assert_eq!(old.searches, 0, "tick {k}: the old model searched nothing");
            fresh.forget();
            evaluate_spheres(
                &idx,
                &p,
                &c,
                old_at(q_old),
                rows,
                None,
                motion(&q_old, &u_old),
                &mut scratch,
                &mut fresh,
            );
            assert_eq!(fresh.searches, 1);
            assert!(fresh.tool_force.norm() > 0.0, "tick {k}: the sphere presses");
            assert!(
                (old.tool_force - fresh.tool_force).norm() <= 1e-12 * fresh.tool_force.norm(),
                "tick {k}: {:?} vs a fresh search {:?}",
                old.tool_force,
                fresh.tool_force
            );
        }
        // A bound beyond the slack takes nothing over.
        let c = [Vec3::new(0.03, 0.02, 0.002 + p.tool_radius_m - 5e-4)];
        press_new(&c, &mut scratch, &mut new);
        let om = motion(&q_old, &u_old).unwrap();
        assert_eq!(old.adopt_searches(&new, 2.0 * COHERENCE_SLACK_M, &shift, &c, &om), 0);
    }
}
