//! Isotropic surface remeshing after Botsch & Kobbelt, "A remeshing approach
//! to multiresolution modeling" (Symposium on Geometry Processing 2004).
//!
//! Each iteration
//! 1. splits every edge longer than 4/3 of the target size (at its midpoint),
//! 2. collapses every edge shorter than 4/5 of it, unless the collapse would
//!    create an edge longer than 4/3, turn a triangle over (its normal turns
//!    by more than 90°), or break the link condition (the two ends share a
//!    neighbour other than the edge's opposite vertices: a non-manifold
//!    result),
//! 3. flips edges that bring the valences closer to 6 (4 on a boundary),
//!    unless the flip folds the surface or halves the smallest angle,
//! 4. moves every vertex toward the centroid of its neighbours in the tangent
//!    plane (tangential relaxation), and
//! 5. projects every vertex back onto the **input** surface: the closest point
//!    on the input triangles (a BVH of the input, `parry3d-f64`), and for a
//!    boundary vertex the closest point on the input boundary loop it belongs
//!    to.
//!
//! The target size may vary over the surface (a closure of the position), so
//! thin branches can be meshed finer than the trunk ([`graded_size`]).
//! Boundary loops (the openings of a vessel) are kept: their vertices stay on
//! the input loop, are resampled along it to the target size (split and
//! collapse along the loop, relaxation along the loop) and no loop falls
//! below three edges. No feature lines or corners are kept (a lumen has none).
//! The output keeps the input's orientation.
//!
//! [`remesh_to_vertex_count`] chooses the uniform size that gives a vertex
//! count (a secant iteration on log size against log count, since the count
//! goes as the area over the triangle area, about `A / (s² √3/4) / 2`).

use crate::math::Vec3;
use crate::mesh::surface::SurfaceMesh;
use parry3d_f64::math::Vector as PVec;
use parry3d_f64::shape::{CompositeShapeRef, TriMesh};

const NONE: u32 = u32::MAX;

/// Settings of [`remesh`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RemeshOptions {
    /// Split / collapse / flip / relax / project iterations (Botsch & Kobbelt
    /// use 5–10).
    pub iterations: usize,
    /// Fraction of the way each relaxation step moves a vertex toward the
    /// centroid of its neighbours (in the tangent plane), in (0, 1].
    pub relaxation: f64,
    /// Relaxation and projection steps at the end, after the last iteration,
    /// with no change of connectivity (smooths the vertex distribution).
    pub final_relaxation: usize,
}

impl Default for RemeshOptions {
    fn default() -> Self {
        RemeshOptions {
            iterations: 10,
            relaxation: 0.8,
            final_relaxation: 3,
        }
    }
}

/// Why a surface could not be remeshed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RemeshError {
    /// No triangles.
    #[error("the surface has no triangles")]
    Empty,
    /// A coordinate is NaN or infinite.
    #[error("vertex {vertex}: a coordinate is not finite")]
    NonFiniteVertex {
        /// The vertex.
        vertex: usize,
    },
    /// A triangle refers to a vertex that does not exist.
    #[error("triangle {triangle}: vertex index {index} is out of range (the surface has {vertices} vertices)")]
    IndexOutOfRange {
        /// The triangle.
        triangle: usize,
        /// The bad index.
        index: u32,
        /// Number of vertices.
        vertices: usize,
    },
    /// A triangle uses one vertex twice.
    #[error("triangle {triangle} uses vertex {vertex} twice")]
    DegenerateTriangle {
        /// The triangle.
        triangle: usize,
        /// The repeated vertex.
        vertex: u32,
    },
    /// An edge is shared by more than two triangles, or two triangles run
    /// along it in the same direction (inconsistent orientation).
    #[error(
        "edge {a}-{b}: non-manifold or inconsistently oriented (triangles {first} and {second} both run from {a} to {b}); \
         clean the surface first (mesh::surface::check_surface)"
    )]
    NonManifoldEdge {
        /// Start vertex.
        a: u32,
        /// End vertex.
        b: u32,
        /// A triangle with the directed edge a→b.
        first: usize,
        /// Another one.
        second: usize,
    },
    /// Two boundary loops touch at a vertex.
    #[error("vertex {vertex}: two boundary loops touch here (a non-manifold vertex); clean the surface first")]
    NonManifoldBoundary {
        /// The vertex.
        vertex: u32,
    },
    /// The size field gave a size that is not a positive finite number.
    #[error("the size field is {size} at ({:.6e}, {:.6e}, {:.6e}); it must be positive and finite", at.x, at.y, at.z)]
    BadSize {
        /// Where.
        at: Vec3,
        /// The size returned.
        size: f64,
    },
    /// An option is out of range.
    #[error("invalid remesh option: {0}")]
    BadOption(String),
    /// [`remesh_to_vertex_count`] (or [`remesh_to_vertex_count_scaled`])
    /// did not reach the count.
    #[error("no size within the tolerance of {target} vertices: the closest was {best} vertices (size parameter {size:.6e})")]
    CountNotReached {
        /// The vertex count asked for.
        target: usize,
        /// The closest count found.
        best: usize,
        /// What gave it: the size (m), or the factor of
        /// [`remesh_to_vertex_count_scaled`].
        size: f64,
    },
}

/// Quality figures of a remeshed surface. Edge lengths are relative to the
/// target size at the edge's midpoint.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct RemeshStats {
    /// Vertices of the output.
    pub vertices: usize,
    /// Triangles of the output.
    pub triangles: usize,
    /// Mean of edge length / target size.
    pub edge_mean: f64,
    /// Smallest edge length / target size.
    pub edge_min: f64,
    /// Largest edge length / target size.
    pub edge_max: f64,
    /// Smallest triangle angle (degrees).
    pub min_angle_deg: f64,
    /// Fraction of triangles with an angle below 20°.
    pub below_20_deg: f64,
    /// Largest distance from an output vertex to the input surface (m).
    pub max_vertex_distance: f64,
    /// Largest distance from an output triangle's centroid to the input
    /// surface (m): how far the flat triangles stray from the input.
    pub max_centroid_distance: f64,
    /// Iterations run.
    pub iterations: usize,
}

/// A remeshed surface with its quality figures.
#[derive(Debug, Clone)]
pub struct Remeshed {
    /// The new surface (oriented as the input).
    pub mesh: SurfaceMesh,
    /// For each vertex of [`Remeshed::mesh`], the index of the input boundary
    /// loop it lies on (`None` inside). Loops are numbered in the order
    /// [`input_boundary_loops`] returns them.
    pub boundary_loop: Vec<Option<u32>>,
    /// Quality figures.
    pub stats: RemeshStats,
}

/// The boundary loops of a consistently oriented manifold surface, each as
/// vertex indices in the order of its boundary edges (as the triangles run
/// along them), longest first.
pub fn input_boundary_loops(mesh: &SurfaceMesh) -> Result<Vec<Vec<u32>>, RemeshError> {
    validate(mesh)?;
    boundary_loops_of(&mesh.triangles, mesh.vertices.len())
}

fn boundary_loops_of(tris: &[[u32; 3]], nv: usize) -> Result<Vec<Vec<u32>>, RemeshError> {
    let mut directed: Vec<(u32, u32)> = Vec::with_capacity(tris.len() * 3);
    for t in tris {
        for k in 0..3 {
            directed.push((t[k], t[(k + 1) % 3]));
        }
    }
    directed.sort_unstable();
    let mut next = vec![NONE; nv];
    for &(a, b) in &directed {
        if directed.binary_search(&(b, a)).is_err() {
            if next[a as usize] != NONE {
                return Err(RemeshError::NonManifoldBoundary { vertex: a });
            }
            next[a as usize] = b;
        }
    }
    let mut seen = vec![false; nv];
    let mut loops = Vec::new();
    for start in 0..nv {
        if next[start] == NONE || seen[start] {
            continue;
        }
        let mut l = Vec::new();
        let mut v = start as u32;
        while !seen[v as usize] {
            seen[v as usize] = true;
            l.push(v);
            v = next[v as usize];
            if v == NONE {
                break;
            }
        }
        loops.push(l);
    }
    loops.sort_by_key(|l| std::cmp::Reverse(l.len()));
    Ok(loops)
}

fn validate(mesh: &SurfaceMesh) -> Result<(), RemeshError> {
    if mesh.triangles.is_empty() {
        return Err(RemeshError::Empty);
    }
    let nv = mesh.vertices.len();
    for (i, p) in mesh.vertices.iter().enumerate() {
        if !p.iter().all(|c| c.is_finite()) {
            return Err(RemeshError::NonFiniteVertex { vertex: i });
        }
    }
    let mut directed: Vec<(u32, u32, usize)> = Vec::with_capacity(mesh.triangles.len() * 3);
    for (t, tri) in mesh.triangles.iter().enumerate() {
        for &v in tri {
            if v as usize >= nv {
                return Err(RemeshError::IndexOutOfRange {
                    triangle: t,
                    index: v,
                    vertices: nv,
                });
            }
        }
        for k in 0..3 {
            if tri[k] == tri[(k + 1) % 3] {
                return Err(RemeshError::DegenerateTriangle {
                    triangle: t,
                    vertex: tri[k],
                });
            }
            directed.push((tri[k], tri[(k + 1) % 3], t));
        }
    }
    directed.sort_unstable();
    for w in directed.windows(2) {
        if w[0].0 == w[1].0 && w[0].1 == w[1].1 {
            return Err(RemeshError::NonManifoldEdge {
                a: w[0].0,
                b: w[0].1,
                first: w[0].2,
                second: w[1].2,
            });
        }
    }
    Ok(())
}

/// The input surface the vertices are projected onto.
struct Reference {
    bvh: TriMesh,
    /// Boundary loops as closed polylines (positions).
    loops: Vec<Vec<Vec3>>,
}

fn pv(p: &Vec3) -> PVec {
    PVec::new(p.x, p.y, p.z)
}

impl Reference {
    fn new(mesh: &SurfaceMesh, loops: &[Vec<u32>]) -> Reference {
        let verts = mesh.vertices.iter().map(pv).collect();
        // validate() has ruled out an empty index buffer, the only error.
        let bvh = TriMesh::new(verts, mesh.triangles.clone()).expect("non-empty triangle list");
        Reference {
            bvh,
            loops: loops
                .iter()
                .map(|l| l.iter().map(|&v| mesh.vertices[v as usize]).collect())
                .collect(),
        }
    }
    fn closest(&self, p: &Vec3) -> Vec3 {
        match CompositeShapeRef(&self.bvh).project_local_point_and_get_location(pv(p), f64::MAX, false) {
            Some((_, proj, _)) => Vec3::new(proj.point.x, proj.point.y, proj.point.z),
            None => *p,
        }
    }
    fn closest_on_loop(&self, l: usize, p: &Vec3) -> Vec3 {
        let pts = &self.loops[l];
        let mut best = (f64::INFINITY, *p);
        for i in 0..pts.len() {
            let (a, b) = (pts[i], pts[(i + 1) % pts.len()]);
            let q = closest_on_segment(p, &a, &b);
            let d = (q - p).norm_squared();
            if d < best.0 {
                best = (d, q);
            }
        }
        best.1
    }
}

/// The closest point to `p` on the segment a–b.
pub fn closest_on_segment(p: &Vec3, a: &Vec3, b: &Vec3) -> Vec3 {
    a + (b - a) * crate::math::segment_parameter(*p, *a, *b)
}

fn tri_normal(a: &Vec3, b: &Vec3, c: &Vec3) -> Vec3 {
    (b - a).cross(&(c - a))
}

/// Smallest angle of a triangle (radians); 0 for a degenerate one.
fn min_angle(a: &Vec3, b: &Vec3, c: &Vec3) -> f64 {
    let ang = |p: &Vec3, q: &Vec3, r: &Vec3| {
        let (u, v) = (q - p, r - p);
        let d = u.norm() * v.norm();
        if d <= 0.0 {
            0.0
        } else {
            (u.dot(&v) / d).clamp(-1.0, 1.0).acos()
        }
    };
    ang(a, b, c).min(ang(b, c, a)).min(ang(c, a, b))
}

/// The surface being remeshed: triangles with vertex→triangle adjacency.
struct Work<'a> {
    p: Vec<Vec3>,
    alive_v: Vec<bool>,
    size: Vec<f64>,
    /// Boundary loop of each vertex (index into Reference::loops) or NONE.
    bloop: Vec<u32>,
    /// Vertices on each loop.
    loop_len: Vec<usize>,
    tris: Vec<[u32; 3]>,
    alive_t: Vec<bool>,
    vt: Vec<Vec<u32>>,
    size_fn: &'a dyn Fn(&Vec3) -> f64,
}

impl<'a> Work<'a> {
    fn size_at(&self, p: &Vec3) -> Result<f64, RemeshError> {
        let s = (self.size_fn)(p);
        if s.is_finite() && s > 0.0 {
            Ok(s)
        } else {
            Err(RemeshError::BadSize { at: *p, size: s })
        }
    }

    fn add_vertex(&mut self, p: Vec3, bloop: u32) -> Result<u32, RemeshError> {
        let s = self.size_at(&p)?;
        self.p.push(p);
        self.alive_v.push(true);
        self.size.push(s);
        self.bloop.push(bloop);
        self.vt.push(Vec::new());
        if bloop != NONE {
            self.loop_len[bloop as usize] += 1;
        }
        Ok((self.p.len() - 1) as u32)
    }

    fn add_tri(&mut self, t: [u32; 3]) -> u32 {
        let id = self.tris.len() as u32;
        self.tris.push(t);
        self.alive_t.push(true);
        for &v in &t {
            self.vt[v as usize].push(id);
        }
        id
    }

    fn detach(&mut self, v: u32, t: u32) {
        let l = &mut self.vt[v as usize];
        if let Some(i) = l.iter().position(|&x| x == t) {
            l.swap_remove(i);
        }
    }

    /// Triangles containing both a and b.
    fn edge_tris(&self, a: u32, b: u32) -> ([u32; 2], usize) {
        let mut out = [NONE; 2];
        let mut n = 0;
        for &t in &self.vt[a as usize] {
            if self.tris[t as usize].contains(&b) {
                if n < 2 {
                    out[n] = t;
                }
                n += 1;
            }
        }
        (out, n)
    }

    fn neighbours(&self, v: u32, out: &mut Vec<u32>) {
        out.clear();
        for &t in &self.vt[v as usize] {
            for &w in &self.tris[t as usize] {
                if w != v && !out.contains(&w) {
                    out.push(w);
                }
            }
        }
    }

    fn is_b(&self, v: u32) -> bool {
        self.bloop[v as usize] != NONE
    }

    fn valence(&self, v: u32) -> i64 {
        self.vt[v as usize].len() as i64 + self.is_b(v) as i64
    }

    fn target_valence(&self, v: u32) -> i64 {
        if self.is_b(v) {
            4
        } else {
            6
        }
    }

    /// Unique edges (low, high) of the alive triangles.
    fn edges(&self) -> Vec<(u32, u32)> {
        let mut e = Vec::with_capacity(self.tris.len() * 3 / 2);
        for (t, tri) in self.tris.iter().enumerate() {
            if !self.alive_t[t] {
                continue;
            }
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                e.push((a.min(b), a.max(b)));
            }
        }
        e.sort_unstable();
        e.dedup();
        e
    }

    fn edge_target(&self, a: u32, b: u32) -> f64 {
        0.5 * (self.size[a as usize] + self.size[b as usize])
    }

    fn split_long(&mut self) -> Result<usize, RemeshError> {
        let mut total = 0;
        for _ in 0..64 {
            let mut n = 0;
            for (a, b) in self.edges() {
                let l = (self.p[a as usize] - self.p[b as usize]).norm();
                if l <= 4.0 / 3.0 * self.edge_target(a, b) {
                    continue;
                }
                self.split(a, b)?;
                n += 1;
            }
            total += n;
            if n == 0 {
                break;
            }
        }
        Ok(total)
    }

    fn split(&mut self, a: u32, b: u32) -> Result<(), RemeshError> {
        let (ts, n) = self.edge_tris(a, b);
        let boundary_edge = n == 1;
        let bl = if boundary_edge { self.bloop[a as usize] } else { NONE };
        let mid = 0.5 * (self.p[a as usize] + self.p[b as usize]);
        let m = self.add_vertex(mid, bl)?;
        for &t in ts.iter().take(n.min(2)) {
            let tri = self.tris[t as usize];
            let k = (0..3)
                .find(|&k| {
                    let (x, y) = (tri[k], tri[(k + 1) % 3]);
                    (x == a && y == b) || (x == b && y == a)
                })
                .expect("edge in its triangle");
            let (x, y, z) = (tri[k], tri[(k + 1) % 3], tri[(k + 2) % 3]);
            self.tris[t as usize] = [x, m, z];
            self.detach(y, t);
            self.vt[m as usize].push(t);
            self.add_tri([m, y, z]);
        }
        Ok(())
    }

    fn collapse_short(&mut self) -> usize {
        let mut total = 0;
        let mut na = Vec::new();
        let mut nb = Vec::new();
        for _ in 0..64 {
            let mut n = 0;
            for (a, b) in self.edges() {
                if !self.alive_v[a as usize] || !self.alive_v[b as usize] {
                    continue;
                }
                let l = (self.p[a as usize] - self.p[b as usize]).norm();
                if l >= 4.0 / 5.0 * self.edge_target(a, b) {
                    continue;
                }
                if self.try_collapse(a, b, &mut na, &mut nb) {
                    n += 1;
                }
            }
            total += n;
            if n == 0 {
                break;
            }
        }
        total
    }

    fn try_collapse(&mut self, a: u32, b: u32, na: &mut Vec<u32>, nb: &mut Vec<u32>) -> bool {
        let (ts, n) = self.edge_tris(a, b);
        if n == 0 || n > 2 {
            return false;
        }
        let (ba, bb) = (self.is_b(a), self.is_b(b));
        let boundary_edge = n == 1;
        let (keep, gone, q) = match (ba, bb) {
            (true, true) => {
                if !boundary_edge || self.loop_len[self.bloop[a as usize] as usize] <= 3 {
                    return false;
                }
                (b, a, 0.5 * (self.p[a as usize] + self.p[b as usize]))
            }
            (true, false) => (a, b, self.p[a as usize]),
            (false, true) => (b, a, self.p[b as usize]),
            (false, false) => {
                if boundary_edge {
                    return false;
                }
                (b, a, 0.5 * (self.p[a as usize] + self.p[b as usize]))
            }
        };
        // Link condition: the common neighbours are exactly the opposite
        // vertices of the edge's triangles.
        self.neighbours(a, na);
        self.neighbours(b, nb);
        let common = na.iter().filter(|w| nb.contains(w)).count();
        if common != n {
            return false;
        }
        // A closed surface needs more than 4 vertices (a tetrahedron).
        if !ba && !bb && na.len() <= 3 && nb.len() <= 3 {
            return false;
        }
        let q_size = match self.size_at(&q) {
            Ok(s) => s,
            Err(_) => return false,
        };
        // No long edges.
        for &w in na.iter().chain(nb.iter()) {
            if w == a || w == b {
                continue;
            }
            let high = 4.0 / 3.0 * 0.5 * (q_size + self.size[w as usize]);
            if (q - self.p[w as usize]).norm() > high {
                return false;
            }
        }
        // No triangle turned over or made degenerate.
        for &v in &[a, b] {
            for &t in &self.vt[v as usize] {
                let tri = self.tris[t as usize];
                if tri.contains(&a) && tri.contains(&b) {
                    continue;
                }
                let before = tri.map(|i| self.p[i as usize]);
                let after = tri.map(|i| if i == a || i == b { q } else { self.p[i as usize] });
                let n0 = tri_normal(&before[0], &before[1], &before[2]);
                let n1 = tri_normal(&after[0], &after[1], &after[2]);
                if n0.dot(&n1) <= 0.0 || min_angle(&after[0], &after[1], &after[2]) < 1e-3 {
                    return false;
                }
            }
        }
        // Collapse `gone` into `keep` at q.
        for &t in ts.iter().take(n) {
            self.alive_t[t as usize] = false;
            for &v in &self.tris[t as usize].clone() {
                self.detach(v, t);
            }
        }
        let moved = std::mem::take(&mut self.vt[gone as usize]);
        for t in moved {
            for v in self.tris[t as usize].iter_mut() {
                if *v == gone {
                    *v = keep;
                }
            }
            self.vt[keep as usize].push(t);
        }
        self.alive_v[gone as usize] = false;
        if self.bloop[gone as usize] != NONE {
            self.loop_len[self.bloop[gone as usize] as usize] -= 1;
        }
        self.p[keep as usize] = q;
        self.size[keep as usize] = q_size;
        true
    }

    /// The interior edge a–b as a flip candidate: its triangles t1 (running
    /// a→b) and t2 (b→a) and their opposite vertices c and d, or None where
    /// a flip is impossible (a boundary or non-manifold edge, c–d already an
    /// edge, or an end vertex of valence 3 or less).
    fn flip_candidate(&self, a: u32, b: u32) -> Option<(u32, u32, u32, u32)> {
        let (ts, cnt) = self.edge_tris(a, b);
        if cnt != 2 {
            return None;
        }
        let runs = |t: u32| {
            let tri = self.tris[t as usize];
            (0..3).any(|k| tri[k] == a && tri[(k + 1) % 3] == b)
        };
        let (t1, t2) = if runs(ts[0]) { (ts[0], ts[1]) } else { (ts[1], ts[0]) };
        let opp = |t: u32| {
            let tri = self.tris[t as usize];
            tri.iter().copied().find(|&v| v != a && v != b)
        };
        let (c, d) = (opp(t1)?, opp(t2)?);
        if c == d || self.vt[c as usize].iter().any(|&t| self.tris[t as usize].contains(&d)) {
            return None;
        }
        if self.valence(a) <= 3 || self.valence(b) <= 3 {
            return None;
        }
        Some((t1, t2, c, d))
    }

    fn flip_valence(&mut self) -> usize {
        let mut n = 0;
        for (a, b) in self.edges() {
            let Some((t1, t2, c, d)) = self.flip_candidate(a, b) else {
                continue;
            };
            let dev = |v: u32, delta: i64| (self.valence(v) + delta - self.target_valence(v)).abs();
            let before = dev(a, 0) + dev(b, 0) + dev(c, 0) + dev(d, 0);
            let after = dev(a, -1) + dev(b, -1) + dev(c, 1) + dev(d, 1);
            if after >= before {
                continue;
            }
            let [pa, pb, pc, pd] = [a, b, c, d].map(|v| self.p[v as usize]);
            let (o1, o2) = (tri_normal(&pa, &pb, &pc), tri_normal(&pb, &pa, &pd));
            let (m1, m2) = (tri_normal(&pa, &pd, &pc), tri_normal(&pd, &pb, &pc));
            let old = o1 + o2;
            if m1.dot(&old) <= 0.0 || m2.dot(&old) <= 0.0 || m1.dot(&m2) <= 0.0 {
                continue;
            }
            let q_old = min_angle(&pa, &pb, &pc).min(min_angle(&pb, &pa, &pd));
            let q_new = min_angle(&pa, &pd, &pc).min(min_angle(&pd, &pb, &pc));
            if q_new < 0.5 * q_old {
                continue;
            }
            self.do_flip(t1, t2, a, b, c, d);
            n += 1;
        }
        n
    }

    fn do_flip(&mut self, t1: u32, t2: u32, a: u32, b: u32, c: u32, d: u32) {
        self.tris[t1 as usize] = [a, d, c];
        self.tris[t2 as usize] = [d, b, c];
        self.detach(b, t1);
        self.detach(a, t2);
        self.vt[d as usize].push(t1);
        self.vt[c as usize].push(t2);
    }

    /// Delaunay-style flips: an interior edge whose two opposite angles sum
    /// to more than π is flipped when that raises the smallest angle and does
    /// not fold the surface (valence is not considered).
    fn flip_angles(&mut self) -> usize {
        let mut n = 0;
        for (a, b) in self.edges() {
            let Some((t1, t2, c, d)) = self.flip_candidate(a, b) else {
                continue;
            };
            let [pa, pb, pc, pd] = [a, b, c, d].map(|v| self.p[v as usize]);
            let angle = |p: &Vec3, q: &Vec3, r: &Vec3| {
                let (u, v) = (q - p, r - p);
                (u.dot(&v) / (u.norm() * v.norm()).max(f64::MIN_POSITIVE))
                    .clamp(-1.0, 1.0)
                    .acos()
            };
            if angle(&pc, &pa, &pb) + angle(&pd, &pa, &pb) <= std::f64::consts::PI + 1e-9 {
                continue;
            }
            let (o1, o2) = (tri_normal(&pa, &pb, &pc), tri_normal(&pb, &pa, &pd));
            let (m1, m2) = (tri_normal(&pa, &pd, &pc), tri_normal(&pd, &pb, &pc));
            let old = o1 + o2;
            if m1.dot(&old) <= 0.0 || m2.dot(&old) <= 0.0 || m1.dot(&m2) <= 0.5 * m1.norm() * m2.norm() {
                continue;
            }
            let q_old = min_angle(&pa, &pb, &pc).min(min_angle(&pb, &pa, &pd));
            let q_new = min_angle(&pa, &pd, &pc).min(min_angle(&pd, &pb, &pc));
            if q_new <= q_old {
                continue;
            }
            self.do_flip(t1, t2, a, b, c, d);
            n += 1;
        }
        n
    }

    /// Tangential relaxation then projection onto the reference.
    fn relax_and_project(&mut self, reference: &Reference, lambda: f64) -> Result<(), RemeshError> {
        let nv = self.p.len();
        let mut normal = vec![Vec3::zeros(); nv];
        for (t, tri) in self.tris.iter().enumerate() {
            if !self.alive_t[t] {
                continue;
            }
            let nrm = tri_normal(
                &self.p[tri[0] as usize],
                &self.p[tri[1] as usize],
                &self.p[tri[2] as usize],
            );
            for &v in tri {
                normal[v as usize] += nrm;
            }
        }
        let mut new_p = self.p.clone();
        let mut nbr = Vec::new();
        for v in 0..nv as u32 {
            if !self.alive_v[v as usize] || self.vt[v as usize].is_empty() {
                continue;
            }
            let p = self.p[v as usize];
            if self.is_b(v) {
                // Along the loop: the midpoint of the two boundary neighbours.
                self.neighbours(v, &mut nbr);
                let mut acc = Vec3::zeros();
                let mut k = 0;
                for &w in &nbr {
                    if self.edge_tris(v, w).1 == 1 {
                        acc += self.p[w as usize];
                        k += 1;
                    }
                }
                if k == 2 {
                    new_p[v as usize] = p + lambda * (acc / 2.0 - p);
                }
            } else {
                self.neighbours(v, &mut nbr);
                if nbr.is_empty() {
                    continue;
                }
                // Neighbours weighted by the area they stand for (∝ size²),
                // so a graded size field keeps its gradation.
                let mut acc = Vec3::zeros();
                let mut wsum = 0.0;
                for &w in &nbr {
                    let s = self.size[w as usize];
                    acc += self.p[w as usize] * s * s;
                    wsum += s * s;
                }
                let u = acc / wsum - p;
                let nl = normal[v as usize].norm();
                let u = if nl > 0.0 {
                    let n = normal[v as usize] / nl;
                    u - n * n.dot(&u)
                } else {
                    u
                };
                new_p[v as usize] = p + lambda * u;
            }
        }
        for (v, q) in new_p.into_iter().enumerate() {
            if !self.alive_v[v] || self.vt[v].is_empty() {
                continue;
            }
            let proj = if self.bloop[v] != NONE {
                reference.closest_on_loop(self.bloop[v] as usize, &q)
            } else {
                reference.closest(&q)
            };
            self.p[v] = proj;
            self.size[v] = self.size_at(&proj)?;
        }
        Ok(())
    }
}

/// Remeshes `input` to edges of length about `size(x)` at x (m), projecting
/// every vertex onto the input surface. The input must be a consistently
/// oriented manifold surface (as [`crate::mesh::surface::check_surface`]
/// leaves it); its boundary loops are kept.
pub fn remesh(input: &SurfaceMesh, size: &dyn Fn(&Vec3) -> f64, opts: &RemeshOptions) -> Result<Remeshed, RemeshError> {
    if opts.iterations == 0 {
        return Err(RemeshError::BadOption("iterations must be at least 1".into()));
    }
    if !(opts.relaxation > 0.0 && opts.relaxation <= 1.0) {
        return Err(RemeshError::BadOption(format!(
            "relaxation must be in (0, 1], got {}",
            opts.relaxation
        )));
    }
    validate(input)?;
    let loops = boundary_loops_of(&input.triangles, input.vertices.len())?;
    let reference = Reference::new(input, &loops);

    let nv = input.vertices.len();
    let mut used = vec![false; nv];
    for t in &input.triangles {
        for &v in t {
            used[v as usize] = true;
        }
    }
    let mut w = Work {
        p: input.vertices.clone(),
        alive_v: used,
        size: Vec::with_capacity(nv),
        bloop: vec![NONE; nv],
        loop_len: loops.iter().map(Vec::len).collect(),
        tris: Vec::with_capacity(input.triangles.len()),
        alive_t: Vec::with_capacity(input.triangles.len()),
        vt: vec![Vec::new(); nv],
        size_fn: size,
    };
    for (i, l) in loops.iter().enumerate() {
        for &v in l {
            w.bloop[v as usize] = i as u32;
        }
    }
    for (i, p) in input.vertices.iter().enumerate() {
        let s = if w.alive_v[i] { w.size_at(p)? } else { 1.0 };
        w.size.push(s);
    }
    for t in &input.triangles {
        w.add_tri(*t);
    }

    for _ in 0..opts.iterations {
        w.split_long()?;
        w.collapse_short();
        w.flip_valence();
        w.relax_and_project(&reference, opts.relaxation)?;
    }
    for _ in 0..opts.final_relaxation {
        w.flip_angles();
        w.relax_and_project(&reference, opts.relaxation)?;
    }
    w.flip_angles();

    // Compact.
    let mut map = vec![NONE; w.p.len()];
    let mut vertices = Vec::new();
    let mut boundary_loop = Vec::new();
    for (v, m) in map.iter_mut().enumerate() {
        if w.alive_v[v] && !w.vt[v].is_empty() {
            *m = vertices.len() as u32;
            vertices.push(w.p[v]);
            boundary_loop.push((w.bloop[v] != NONE).then_some(w.bloop[v]));
        }
    }
    let triangles: Vec<[u32; 3]> = w
        .tris
        .iter()
        .zip(&w.alive_t)
        .filter(|(_, &a)| a)
        .map(|(t, _)| t.map(|v| map[v as usize]))
        .collect();
    let mesh = SurfaceMesh { vertices, triangles };
    let stats = measure(&mesh, size, &reference, opts.iterations);
    Ok(Remeshed {
        mesh,
        boundary_loop,
        stats,
    })
}

fn measure(mesh: &SurfaceMesh, size: &dyn Fn(&Vec3) -> f64, reference: &Reference, iterations: usize) -> RemeshStats {
    let mut edges: Vec<(u32, u32)> = mesh
        .triangles
        .iter()
        .flat_map(|t| (0..3).map(move |k| (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]))))
        .collect();
    edges.sort_unstable();
    edges.dedup();
    let (mut sum, mut lo, mut hi) = (0.0, f64::INFINITY, 0.0f64);
    for &(a, b) in &edges {
        let (pa, pb) = (mesh.vertices[a as usize], mesh.vertices[b as usize]);
        let r = (pa - pb).norm() / size(&(0.5 * (pa + pb)));
        sum += r;
        lo = lo.min(r);
        hi = hi.max(r);
    }
    let mut amin = f64::INFINITY;
    let mut below = 0usize;
    let mut cdist = 0.0f64;
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|v| mesh.vertices[v as usize]);
        let m = min_angle(&a, &b, &c).to_degrees();
        amin = amin.min(m);
        if m < 20.0 {
            below += 1;
        }
        let g = (a + b + c) / 3.0;
        cdist = cdist.max((reference.closest(&g) - g).norm());
    }
    let vdist = mesh
        .vertices
        .iter()
        .map(|p| (reference.closest(p) - p).norm())
        .fold(0.0, f64::max);
    RemeshStats {
        vertices: mesh.vertices.len(),
        triangles: mesh.triangles.len(),
        edge_mean: sum / edges.len().max(1) as f64,
        edge_min: lo,
        edge_max: hi,
        min_angle_deg: amin,
        below_20_deg: below as f64 / mesh.triangles.len().max(1) as f64,
        max_vertex_distance: vdist,
        max_centroid_distance: cdist,
        iterations,
    }
}

/// Total area of a surface (m²).
pub fn surface_area(mesh: &SurfaceMesh) -> f64 {
    mesh.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|v| mesh.vertices[v as usize]);
            0.5 * tri_normal(&a, &b, &c).norm()
        })
        .sum()
}

/// A size field that is `base` everywhere except where the lumen is thin,
/// so a vessel of radius r keeps at least `nodes_around` vertices around:
/// edges are left alone up to 4/3 of the size, so the size is capped at
/// `(3/4) 2π r / nodes_around` (`radius(x)` is the local lumen radius).
pub fn graded_size<'a>(base: f64, nodes_around: usize, radius: &'a dyn Fn(&Vec3) -> f64) -> impl Fn(&Vec3) -> f64 + 'a {
    let cap = around_cap(nodes_around);
    move |p: &Vec3| base.min(cap * radius(p))
}

/// The factor c such that the size c·r keeps `nodes_around` vertices around
/// a vessel of radius r: (3/4) 2π / `nodes_around` (edges up to 4/3 of the
/// size are not split).
pub fn around_cap(nodes_around: usize) -> f64 {
    0.75 * 2.0 * std::f64::consts::PI / nodes_around.max(3) as f64
}

/// Remeshes with the uniform size `s` capped by `cap(x)` (use
/// `|_| f64::INFINITY` for no cap, or `around_cap(8) r(x)` for branches), choosing `s`
/// so the output has `target` vertices within the relative `tolerance`
/// (e.g. 0.01). Starts from the area estimate `s² = 2A / (√3 V)` and refines
/// by a secant step on (ln s, ln V); each trial remeshes the input afresh.
/// Once `s` exceeds the cap everywhere on the input, a larger `s` changes
/// nothing: the search stops there and reports the count it gives (the
/// fewest vertices the cap allows). Returns the size found and the
/// remeshed surface.
pub fn remesh_to_vertex_count(
    input: &SurfaceMesh,
    target: usize,
    cap: &dyn Fn(&Vec3) -> f64,
    opts: &RemeshOptions,
    tolerance: f64,
) -> Result<(f64, Remeshed), RemeshError> {
    check_count_options(input, target, tolerance)?;
    let area = surface_area(input);
    let s0 = (2.0 * area / (3f64.sqrt() * target as f64)).sqrt();
    let cap_max = input.vertices.iter().map(cap).fold(0.0f64, |a, b| a.max(b));
    let field = |s: f64, p: &Vec3| s.min(cap(p));
    secant_count(input, target, s0, cap_max, &field, opts, tolerance)
}

/// Remeshes with the size `c · base(x)`, choosing the factor `c` so the
/// output has `target` vertices within the relative `tolerance`, with `c`
/// at most `c_max`. The size keeps the shape of `base` (e.g. a fraction of
/// the local lumen radius, so every vessel keeps the same number of
/// vertices around); see [`remesh_to_vertex_count`] for the search.
/// Returns the factor found and the remeshed surface.
pub fn remesh_to_vertex_count_scaled(
    input: &SurfaceMesh,
    target: usize,
    base: &dyn Fn(&Vec3) -> f64,
    c0: f64,
    c_max: f64,
    opts: &RemeshOptions,
    tolerance: f64,
) -> Result<(f64, Remeshed), RemeshError> {
    check_count_options(input, target, tolerance)?;
    if !(c0.is_finite() && c0 > 0.0 && c_max >= c0) {
        return Err(RemeshError::BadOption(format!(
            "size factors must be positive with c0 <= c_max, got {c0} and {c_max}"
        )));
    }
    let field = |c: f64, p: &Vec3| c.min(c_max) * base(p);
    secant_count(input, target, c0, c_max, &field, opts, tolerance)
}

fn check_count_options(input: &SurfaceMesh, target: usize, tolerance: f64) -> Result<(), RemeshError> {
    if target < 4 {
        return Err(RemeshError::BadOption(format!(
            "a target of {target} vertices is too small (at least 4)"
        )));
    }
    if !(tolerance > 0.0 && tolerance.is_finite()) {
        return Err(RemeshError::BadOption(format!(
            "tolerance must be positive, got {tolerance}"
        )));
    }
    validate(input)
}

/// Secant search on (ln x, ln V) for the parameter `x` of the size field
/// `field(x, p)` (a size that grows with x, about in proportion) giving
/// `target` vertices; `x` beyond `x_sat` changes nothing, so the search
/// stops once it is there with too many vertices.
fn secant_count(
    input: &SurfaceMesh,
    target: usize,
    x0: f64,
    x_sat: f64,
    field: &dyn Fn(f64, &Vec3) -> f64,
    opts: &RemeshOptions,
    tolerance: f64,
) -> Result<(f64, Remeshed), RemeshError> {
    let mut x = x0;
    let (mut lo, mut hi) = (0.0f64, f64::INFINITY);
    let mut hist: Vec<(f64, usize)> = Vec::new();
    let mut best: Option<(f64, f64, Remeshed)> = None;
    for _ in 0..12 {
        let f = |p: &Vec3| field(x, p);
        let r = remesh(input, &f, opts)?;
        let n = r.stats.vertices;
        let err = (n as f64 / target as f64 - 1.0).abs();
        hist.push((x, n));
        if best.as_ref().is_none_or(|b| err < b.0) {
            best = Some((err, x, r));
        }
        if err <= tolerance || (x >= x_sat && n > target) {
            break;
        }
        // Secant on ln V = c + m ln x (m ≈ −2 for a size proportional to x).
        let mut slope = -2.0;
        if hist.len() >= 2 {
            let (x0, n0) = hist[hist.len() - 2];
            let (x1, n1) = hist[hist.len() - 1];
            let m = ((n1 as f64).ln() - (n0 as f64).ln()) / (x1.ln() - x0.ln());
            if m.is_finite() && (-4.0..=-0.5).contains(&m) {
                slope = m;
            }
        }
        // Bracket: the largest x with too many vertices, the smallest with
        // too few; a step outside it is replaced by bisection (in ln x).
        if n > target {
            lo = lo.max(x);
        } else {
            hi = hi.min(x);
        }
        let step = ((target as f64).ln() - (n as f64).ln()) / slope;
        let mut next = x * step.clamp(-0.5, 0.5).exp();
        if hi.is_finite() && lo > 0.0 && !(next > lo && next < hi) {
            next = (lo * hi).sqrt();
        }
        // Past saturation only once: the count there is the floor.
        x = if next > x_sat && x < x_sat { x_sat } else { next };
    }
    let (err, x, r) = best.expect("at least one trial");
    if err <= tolerance {
        Ok((x, r))
    } else {
        Err(RemeshError::CountNotReached {
            target,
            best: r.stats.vertices,
            size: x,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat square grid of n×n cells on [0, 1]², triangulated.
    fn square(n: usize) -> SurfaceMesh {
        let mut vertices = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                vertices.push(Vec3::new(i as f64 / n as f64, j as f64 / n as f64, 0.0));
            }
        }
        let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        let mut triangles = Vec::new();
        for j in 0..n {
            for i in 0..n {
                triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
        SurfaceMesh { vertices, triangles }
    }

    #[test]
    fn flat_square_keeps_its_outline_and_orientation() {
        let input = square(40);
        let r = remesh(&input, &|_| 0.1, &RemeshOptions::default()).unwrap();
        let s = r.stats;
        assert!((s.edge_mean - 1.0).abs() < 0.15, "{s:?}");
        assert!(s.max_vertex_distance < 1e-12, "{s:?}");
        // Still one loop, oriented as the input (normals +z).
        assert_eq!(input_boundary_loops(&r.mesh).unwrap().len(), 1);
        for t in &r.mesh.triangles {
            let [a, b, c] = t.map(|v| r.mesh.vertices[v as usize]);
            assert!(tri_normal(&a, &b, &c).z > 0.0);
        }
        // Corners are not kept: each of the four may be cut by a triangle
        // with legs up to 4/3 of the size, nothing else is lost.
        let a = surface_area(&r.mesh);
        let cut = 4.0 * 0.5 * (4.0 / 3.0 * 0.1f64).powi(2);
        assert!(a <= 1.0 + 1e-12 && a >= 1.0 - cut, "{a}");
    }

    #[test]
    fn bad_input_is_named() {
        let mut m = square(2);
        m.triangles.push([0, 1, 99]);
        assert!(matches!(
            remesh(&m, &|_| 0.1, &RemeshOptions::default()),
            Err(RemeshError::IndexOutOfRange { index: 99, .. })
        ));
        let mut m = square(2);
        let t = m.triangles[0];
        m.triangles.push(t);
        assert!(matches!(
            remesh(&m, &|_| 0.1, &RemeshOptions::default()),
            Err(RemeshError::NonManifoldEdge { .. })
        ));
        let m = square(2);
        assert!(matches!(
            remesh(&m, &|_| -1.0, &RemeshOptions::default()),
            Err(RemeshError::BadSize { .. })
        ));
        assert_eq!(
            remesh(&SurfaceMesh::default(), &|_| 1.0, &RemeshOptions::default()).unwrap_err(),
            RemeshError::Empty
        );
    }
}
