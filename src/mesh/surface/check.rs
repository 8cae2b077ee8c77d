//! Checks of a user's lumen surface before it is meshed: what can be fixed
//! is fixed and reported ([`SurfaceReport`]), what cannot is refused with a
//! [`SurfaceDefect`] naming the triangles, vertices and coordinates.
//!
//! In order:
//! 1. non-finite coordinates and indices out of range are refused;
//! 2. triangles with a repeated vertex (an STL facet whose corners welded)
//!    and duplicate triangles (the same three vertices) are removed and
//!    listed; a triangle with three distinct but collinear vertices is
//!    refused (removing it would leave a crack);
//! 3. unused vertices are dropped;
//! 4. an edge shared by more than two triangles, or a vertex whose triangles
//!    form two or more separate fans (two sheets touching at a point), is
//!    refused;
//! 5. orientation is made consistent across every edge (triangles flipped,
//!    counted), unless the surface is non-orientable;
//! 6. several disconnected bodies are refused (with their sizes), or all but
//!    the largest dropped with [`CheckOptions::keep_largest_body`];
//! 7. a bounding-box diagonal outside 5 mm – 2 m is refused as a wrong unit,
//!    naming the scale that would fix it;
//! 8. boundary loops (the openings of an open tube) are traced, and the
//!    surface turned so its normals point out of the volume it encloses once
//!    each opening is closed by a flat fan;
//! 9. self-intersections (two triangles that cross or touch, other than along
//!    the edge or at the vertex they share) are refused, naming the first
//!    pair; exact orientation predicates (Shewchuk's, the `robust` crate)
//!    with a uniform-grid broad phase.
//!
//! Vertex and triangle indices in reports and errors are those of the mesh
//! given to [`check_surface`] (0-based).

use super::intersect::first_intersection;
use super::{bbox_diagonal, SurfaceMesh};
use crate::math::Vec3;
use std::collections::HashMap;

/// Smallest and largest plausible bounding-box diagonal of a vessel lumen (m).
pub const PLAUSIBLE_DIAGONAL: (f64, f64) = (5e-3, 2.0);

/// What [`check_surface`] does beyond its fixed checks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CheckOptions {
    /// Keep the largest body (most triangles) and drop the others (listed in
    /// [`SurfaceReport::dropped_bodies`]) instead of refusing several bodies.
    pub keep_largest_body: bool,
    /// Refuse a bounding-box diagonal outside [`PLAUSIBLE_DIAGONAL`].
    pub check_unit: bool,
    /// Look for self-intersections (the costliest check, about linear in the
    /// number of triangles).
    pub self_intersections: bool,
    /// The scale the surface was read with, only to name the right one in a
    /// wrong-unit error.
    pub scale: f64,
}

impl Default for CheckOptions {
    fn default() -> Self {
        CheckOptions {
            keep_largest_body: false,
            check_unit: true,
            self_intersections: true,
            scale: 1.0,
        }
    }
}

/// An opening of the surface: a closed loop of boundary edges.
#[derive(Debug, Clone, PartialEq)]
pub struct BoundaryLoop {
    /// The loop's vertices in order (indices into [`CheckedSurface::mesh`]),
    /// counter-clockwise seen from outside, around [`BoundaryLoop::normal`].
    pub vertices: Vec<u32>,
    /// The centre: the loop's edge midpoints weighted by edge length (m).
    pub centre: Vec3,
    /// Unit normal of the loop's vector area, pointing out of the enclosed
    /// volume through the opening (for a vessel: out of the lumen, along the
    /// flow at an outlet, against it at an inlet).
    pub normal: Vec3,
    /// Area of the opening: the norm of the vector area ½ Σ pᵢ × pᵢ₊₁ (m²);
    /// exact for a planar loop, the largest projected area otherwise.
    pub area: f64,
    /// Length of the loop (m).
    pub perimeter: f64,
}

/// What [`check_surface`] found and fixed (nothing here is an error).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SurfaceReport {
    /// Triangles removed because a vertex repeats in them (input indices).
    pub degenerate: Vec<usize>,
    /// Triangles removed because an earlier one has the same three vertices
    /// (input indices).
    pub duplicates: Vec<usize>,
    /// Vertices no kept triangle uses, dropped.
    pub unused_vertices: usize,
    /// Kept triangles whose vertex order was reversed (for a consistent
    /// orientation with normals pointing out).
    pub flipped: usize,
    /// Sizes (triangles) of the bodies dropped by
    /// [`CheckOptions::keep_largest_body`], largest first.
    pub dropped_bodies: Vec<usize>,
    /// The openings, largest area first (empty for a closed surface).
    pub boundary_loops: Vec<BoundaryLoop>,
    /// Diagonal of the bounding box (m).
    pub bbox_diagonal: f64,
    /// Total triangle area (m²).
    pub area: f64,
    /// Volume enclosed by the surface with each opening closed by a flat fan
    /// around its centre (m³, positive: normals point out).
    pub volume: f64,
    /// For each vertex of the checked mesh, its index in the input.
    pub input_vertex: Vec<u32>,
    /// For each triangle of the checked mesh, its index in the input.
    pub input_triangle: Vec<u32>,
}

/// A surface that passed [`check_surface`]: cleaned, consistently oriented
/// with outward normals, one body, with what was done and found.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckedSurface {
    /// The cleaned surface.
    pub mesh: SurfaceMesh,
    /// What was fixed and found.
    pub report: SurfaceReport,
}

/// Formats a point for messages.
fn pt(p: &Vec3) -> String {
    format!("({:.6e}, {:.6e}, {:.6e})", p.x, p.y, p.z)
}

fn list(v: &[usize]) -> String {
    v.iter().map(|x| x.to_string()).collect::<Vec<_>>().join(", ")
}

/// Why a surface cannot be meshed. Indices are those of the mesh given to
/// [`check_surface`]; coordinates are in metres.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SurfaceDefect {
    /// No triangles.
    #[error("the surface has no triangles")]
    Empty,
    /// A coordinate is NaN or infinite.
    #[error("vertex {vertex}: coordinate {axis} is not finite ({value})")]
    NonFiniteVertex {
        /// The vertex.
        vertex: usize,
        /// x, y or z.
        axis: char,
        /// The value.
        value: f64,
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
    /// Three distinct but collinear vertices.
    #[error(
        "triangle {triangle} (vertices {}, {}, {} at {}, {}, {}) has zero area with three distinct vertices: \
         removing it would leave a crack; repair the surface (e.g. collapse its shortest edge)",
        vertices[0], vertices[1], vertices[2], pt(&corners[0]), pt(&corners[1]), pt(&corners[2])
    )]
    ZeroArea {
        /// The triangle.
        triangle: usize,
        /// Its vertices.
        vertices: [u32; 3],
        /// Their positions.
        corners: [Vec3; 3],
    },
    /// An edge shared by more than two triangles.
    #[error(
        "non-manifold edge {a}-{b} ({} to {}): shared by {} triangles ({}); at most 2 allowed",
        pt(pa), pt(pb), triangles.len(), list(triangles)
    )]
    NonManifoldEdge {
        /// First vertex.
        a: u32,
        /// Second vertex.
        b: u32,
        /// Position of `a`.
        pa: Vec3,
        /// Position of `b`.
        pb: Vec3,
        /// The triangles sharing the edge.
        triangles: Vec<usize>,
    },
    /// A vertex where separate sheets touch.
    #[error(
        "non-manifold vertex {vertex} at {}: its triangles form {fans} separate fans (sheets touching at a point)",
        pt(position)
    )]
    NonManifoldVertex {
        /// The vertex.
        vertex: u32,
        /// Its position.
        position: Vec3,
        /// Number of separate fans around it.
        fans: usize,
    },
    /// The triangles cannot be oriented consistently (a Möbius-like surface).
    #[error(
        "the surface is not orientable: no consistent orientation exists across edge {a}-{b} ({} to {})",
        pt(pa),
        pt(pb)
    )]
    NonOrientable {
        /// First vertex.
        a: u32,
        /// Second vertex.
        b: u32,
        /// Position of `a`.
        pa: Vec3,
        /// Position of `b`.
        pb: Vec3,
    },
    /// More than one connected body.
    #[error(
        "the surface has {} disconnected bodies (triangles in each: {}); one lumen is expected: \
         remove the others, or keep the largest (keep_largest_body)",
        sizes.len(), list(sizes)
    )]
    SeveralBodies {
        /// Triangles per body, largest first.
        sizes: Vec<usize>,
    },
    /// A size no vessel lumen has: probably the wrong unit.
    #[error(
        "the bounding-box diagonal is {diagonal:.6e} m after scale {scale}, but a vessel lumen's is between 5 mm and 2 m: \
         wrong unit?{}",
        match suggested {
            Some(s) => format!(" read it with scale {s} (diagonal {:.3e} m)", diagonal / scale * s),
            None => String::new(),
        }
    )]
    WrongUnit {
        /// The diagonal found (m).
        diagonal: f64,
        /// The scale the surface was read with.
        scale: f64,
        /// A scale that gives a plausible size, if a power of ten does.
        suggested: Option<f64>,
    },
    /// Two triangles intersect.
    #[error(
        "self-intersection: triangles {first} and {second} intersect (near {}); {pairs} intersecting pair(s) in all",
        pt(near)
    )]
    SelfIntersection {
        /// One triangle.
        first: usize,
        /// The other.
        second: usize,
        /// The centroid of the two triangles' centroids.
        near: Vec3,
        /// Number of intersecting pairs found.
        pairs: usize,
    },
}

/// The surface being cleaned, with the input index of each vertex and triangle.
struct Work {
    verts: Vec<Vec3>,
    tris: Vec<[u32; 3]>,
    vin: Vec<u32>,
    tin: Vec<u32>,
}

impl Work {
    /// Drops the vertices no triangle uses (the others keep their order);
    /// returns how many.
    fn compact(&mut self) -> usize {
        let mut map = vec![u32::MAX; self.verts.len()];
        for t in &self.tris {
            for &v in t {
                map[v as usize] = 0;
            }
        }
        let mut verts = Vec::with_capacity(self.verts.len());
        let mut vin = Vec::with_capacity(self.verts.len());
        for (v, m) in map.iter_mut().enumerate() {
            if *m == 0 {
                *m = verts.len() as u32;
                verts.push(self.verts[v]);
                vin.push(self.vin[v]);
            }
        }
        for t in &mut self.tris {
            for v in t.iter_mut() {
                *v = map[*v as usize];
            }
        }
        let dropped = self.verts.len() - verts.len();
        self.verts = verts;
        self.vin = vin;
        dropped
    }

    fn edge_defect(&self, a: u32, b: u32) -> (u32, u32, Vec3, Vec3) {
        (
            self.vin[a as usize],
            self.vin[b as usize],
            self.verts[a as usize],
            self.verts[b as usize],
        )
    }
}

/// Topology of a clean triangle list: interior edges (two triangles each,
/// with whether they run the edge the same way) and boundary edges.
struct Topo {
    /// (t1, t2, a, b, same direction)
    interior: Vec<(u32, u32, u32, u32, bool)>,
    /// (t, a, b) boundary edges, a < b.
    boundary: Vec<(u32, u32, u32)>,
}

fn topology(w: &Work) -> Result<Topo, SurfaceDefect> {
    // Every half-edge as (low, high, triangle, forward = runs low -> high).
    let mut he: Vec<(u32, u32, u32, bool)> = Vec::with_capacity(3 * w.tris.len());
    for (t, tri) in w.tris.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            he.push((a.min(b), a.max(b), t as u32, a < b));
        }
    }
    he.sort_unstable();
    let mut topo = Topo {
        interior: Vec::new(),
        boundary: Vec::new(),
    };
    let mut i = 0;
    while i < he.len() {
        let mut j = i + 1;
        while j < he.len() && he[j].0 == he[i].0 && he[j].1 == he[i].1 {
            j += 1;
        }
        let (a, b) = (he[i].0, he[i].1);
        match j - i {
            1 => topo.boundary.push((he[i].2, a, b)),
            2 => topo.interior.push((he[i].2, he[i + 1].2, a, b, he[i].3 == he[i + 1].3)),
            _ => {
                let (a, b, pa, pb) = w.edge_defect(a, b);
                let mut triangles: Vec<usize> = he[i..j].iter().map(|h| w.tin[h.2 as usize] as usize).collect();
                triangles.sort_unstable();
                return Err(SurfaceDefect::NonManifoldEdge {
                    a,
                    b,
                    pa,
                    pb,
                    triangles,
                });
            }
        }
        i = j;
    }
    Ok(topo)
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let p = parent[parent[x as usize] as usize];
        parent[x as usize] = p;
        x = p;
    }
    x
}

fn union(parent: &mut [u32], a: u32, b: u32) {
    let (ra, rb) = (find(parent, a), find(parent, b));
    if ra != rb {
        parent[ra.max(rb) as usize] = ra.min(rb);
    }
}

/// Refuses a vertex whose triangles form several fans: the corners of a
/// vertex are joined across every interior edge; one fan = one class.
fn manifold_vertices(w: &Work, topo: &Topo) -> Result<(), SurfaceDefect> {
    let corner = |t: u32, v: u32| 3 * t + w.tris[t as usize].iter().position(|&x| x == v).unwrap_or(0) as u32;
    let mut parent: Vec<u32> = (0..3 * w.tris.len() as u32).collect();
    for &(t1, t2, a, b, _) in &topo.interior {
        union(&mut parent, corner(t1, a), corner(t2, a));
        union(&mut parent, corner(t1, b), corner(t2, b));
    }
    let mut first = vec![u32::MAX; w.verts.len()];
    let mut bad: Option<u32> = None;
    for c in 0..3 * w.tris.len() as u32 {
        let v = w.tris[(c / 3) as usize][(c % 3) as usize];
        let r = find(&mut parent, c);
        let f = &mut first[v as usize];
        if *f == u32::MAX {
            *f = r;
        } else if *f != r && bad.is_none_or(|b| w.vin[v as usize] < w.vin[b as usize]) {
            bad = Some(v);
        }
    }
    if let Some(v) = bad {
        let mut roots: Vec<u32> = (0..3 * w.tris.len() as u32)
            .filter(|&c| w.tris[(c / 3) as usize][(c % 3) as usize] == v)
            .map(|c| find(&mut parent, c))
            .collect();
        roots.sort_unstable();
        roots.dedup();
        return Err(SurfaceDefect::NonManifoldVertex {
            vertex: w.vin[v as usize],
            position: w.verts[v as usize],
            fans: roots.len(),
        });
    }
    Ok(())
}

/// A consistent orientation: per triangle whether to flip it and its body,
/// and the size of each body.
struct Orientation {
    flip: Vec<bool>,
    body: Vec<u32>,
    sizes: Vec<usize>,
}

fn orient(w: &Work, topo: &Topo) -> Result<Orientation, SurfaceDefect> {
    let n = w.tris.len();
    let mut deg = vec![0u32; n + 1];
    for &(t1, t2, ..) in &topo.interior {
        deg[t1 as usize + 1] += 1;
        deg[t2 as usize + 1] += 1;
    }
    for i in 0..n {
        deg[i + 1] += deg[i];
    }
    let mut fill = deg.clone();
    let mut adj = vec![(0u32, 0u32); deg[n] as usize]; // (neighbour, interior edge id)
    for (e, &(t1, t2, ..)) in topo.interior.iter().enumerate() {
        adj[fill[t1 as usize] as usize] = (t2, e as u32);
        fill[t1 as usize] += 1;
        adj[fill[t2 as usize] as usize] = (t1, e as u32);
        fill[t2 as usize] += 1;
    }
    let mut flip = vec![false; n];
    let mut body = vec![u32::MAX; n];
    let mut sizes = Vec::new();
    let mut stack = Vec::new();
    for seed in 0..n {
        if body[seed] != u32::MAX {
            continue;
        }
        let id = sizes.len() as u32;
        body[seed] = id;
        stack.push(seed as u32);
        let mut members = vec![seed as u32];
        while let Some(t) = stack.pop() {
            for &(u, e) in &adj[deg[t as usize] as usize..deg[t as usize + 1] as usize] {
                let (.., a, b, same) = topo.interior[e as usize];
                // Two triangles running an edge the same way disagree.
                let want = flip[t as usize] ^ same;
                if body[u as usize] == u32::MAX {
                    body[u as usize] = id;
                    flip[u as usize] = want;
                    stack.push(u);
                    members.push(u);
                } else if flip[u as usize] != want {
                    let (a, b, pa, pb) = w.edge_defect(a, b);
                    return Err(SurfaceDefect::NonOrientable { a, b, pa, pb });
                }
            }
        }
        // Flip the fewer triangles.
        if 2 * members.iter().filter(|&&t| flip[t as usize]).count() > members.len() {
            for &t in &members {
                flip[t as usize] = !flip[t as usize];
            }
        }
        sizes.push(members.len());
    }
    Ok(Orientation { flip, body, sizes })
}

/// The first scale (the current one times a power of ten) that brings the
/// diagonal into the plausible range, millimetres first.
fn suggest_scale(diagonal: f64, scale: f64) -> Option<f64> {
    [1e-3, 1e3, 1e-2, 1e2, 1e-1, 1e1, 1e-6, 1e6]
        .into_iter()
        .find(|f| (PLAUSIBLE_DIAGONAL.0..=PLAUSIBLE_DIAGONAL.1).contains(&(diagonal * f)))
        .map(|f| {
            let s = scale * f;
            // Print 0.001, not 0.0010000000000000002.
            format!("{s:.12e}").parse().unwrap_or(s)
        })
}

/// Traces the boundary loops; each stored against the boundary half-edges'
/// direction so its vector area points out of the enclosed volume.
fn boundary_loops(w: &Work, topo: &Topo) -> Vec<BoundaryLoop> {
    let mut next: HashMap<u32, u32> = HashMap::with_capacity(topo.boundary.len());
    for &(t, a, b) in &topo.boundary {
        let tri = w.tris[t as usize];
        let ia = tri.iter().position(|&x| x == a).unwrap_or(0);
        // The triangle runs a -> b when b follows a.
        let (from, to) = if tri[(ia + 1) % 3] == b { (a, b) } else { (b, a) };
        next.insert(from, to);
    }
    let mut starts: Vec<u32> = next.keys().copied().collect();
    starts.sort_unstable();
    let mut seen = std::collections::HashSet::with_capacity(next.len());
    let mut loops = Vec::new();
    for s in starts {
        if seen.contains(&s) {
            continue;
        }
        let mut lp = vec![s];
        seen.insert(s);
        let mut v = s;
        while let Some(&u) = next.get(&v) {
            if u == s || !seen.insert(u) {
                break;
            }
            lp.push(u);
            v = u;
        }
        lp.reverse();
        loops.push(loop_geometry(&w.verts, lp));
    }
    loops
}

fn loop_geometry(verts: &[Vec3], vertices: Vec<u32>) -> BoundaryLoop {
    let n = vertices.len();
    let p = |k: usize| verts[vertices[k % n] as usize];
    let mut vec_area = Vec3::zeros();
    let mut centre = Vec3::zeros();
    let mut perimeter = 0.0;
    for k in 0..n {
        let (a, b) = (p(k), p(k + 1));
        vec_area += 0.5 * a.cross(&b);
        let l = (b - a).norm();
        centre += 0.5 * (a + b) * l;
        perimeter += l;
    }
    let centre = if perimeter > 0.0 { centre / perimeter } else { p(0) };
    let area = vec_area.norm();
    let normal = if area > 0.0 { vec_area / area } else { Vec3::zeros() };
    BoundaryLoop {
        vertices,
        centre,
        normal,
        area,
        perimeter,
    }
}

/// Enclosed volume of the triangles plus a fan cap over each loop.
fn capped_volume(w: &Work, loops: &[BoundaryLoop]) -> f64 {
    let mut v = 0.0;
    for t in &w.tris {
        let [a, b, c] = t.map(|i| w.verts[i as usize]);
        v += a.dot(&b.cross(&c));
    }
    for lp in loops {
        let n = lp.vertices.len();
        for k in 0..n {
            let a = w.verts[lp.vertices[k] as usize];
            let b = w.verts[lp.vertices[(k + 1) % n] as usize];
            v += lp.centre.dot(&a.cross(&b));
        }
    }
    v / 6.0
}

/// Checks and cleans a surface; see the module documentation for what is
/// checked in which order.
pub fn check_surface(mesh: &SurfaceMesh, options: &CheckOptions) -> Result<CheckedSurface, SurfaceDefect> {
    if mesh.triangles.is_empty() {
        return Err(SurfaceDefect::Empty);
    }
    let nv = mesh.vertices.len();
    for (i, p) in mesh.vertices.iter().enumerate() {
        if let Some(k) = (0..3).find(|&k| !p[k].is_finite()) {
            return Err(SurfaceDefect::NonFiniteVertex {
                vertex: i,
                axis: ['x', 'y', 'z'][k],
                value: p[k],
            });
        }
    }
    let mut report = SurfaceReport::default();
    let mut seen: HashMap<[u32; 3], usize> = HashMap::with_capacity(mesh.triangles.len());
    let mut w = Work {
        verts: mesh.vertices.clone(),
        tris: Vec::with_capacity(mesh.triangles.len()),
        vin: (0..nv as u32).collect(),
        tin: Vec::with_capacity(mesh.triangles.len()),
    };
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if let Some(&index) = tri.iter().find(|&&v| v as usize >= nv) {
            return Err(SurfaceDefect::IndexOutOfRange {
                triangle: t,
                index,
                vertices: nv,
            });
        }
        let mut key = *tri;
        key.sort_unstable();
        if key[0] == key[1] || key[1] == key[2] {
            report.degenerate.push(t);
            continue;
        }
        let corners = tri.map(|i| mesh.vertices[i as usize]);
        let [a, b, c] = corners;
        let longest = (b - a)
            .norm_squared()
            .max((c - b).norm_squared())
            .max((a - c).norm_squared());
        if (b - a).cross(&(c - a)).norm() <= 1e-12 * longest {
            return Err(SurfaceDefect::ZeroArea {
                triangle: t,
                vertices: *tri,
                corners,
            });
        }
        if seen.insert(key, t).is_some() {
            report.duplicates.push(t);
            continue;
        }
        w.tris.push(*tri);
        w.tin.push(t as u32);
    }
    if w.tris.is_empty() {
        return Err(SurfaceDefect::Empty);
    }
    report.unused_vertices = w.compact();
    let mut topo = topology(&w)?;
    manifold_vertices(&w, &topo)?;
    let Orientation { mut flip, body, sizes } = orient(&w, &topo)?;
    if sizes.len() > 1 {
        let mut sorted = sizes.clone();
        sorted.sort_unstable_by(|a, b| b.cmp(a));
        if !options.keep_largest_body {
            return Err(SurfaceDefect::SeveralBodies { sizes: sorted });
        }
        let largest = (0..sizes.len())
            .max_by_key(|&b| (sizes[b], std::cmp::Reverse(b)))
            .unwrap_or(0) as u32;
        report.dropped_bodies = sorted[1..].to_vec();
        let keep: Vec<usize> = (0..w.tris.len()).filter(|&t| body[t] == largest).collect();
        w.tris = keep.iter().map(|&t| w.tris[t]).collect();
        w.tin = keep.iter().map(|&t| w.tin[t]).collect();
        flip = keep.iter().map(|&t| flip[t]).collect();
        report.unused_vertices += w.compact();
        topo = topology(&w)?;
    }
    for (t, f) in w.tris.iter_mut().zip(&flip) {
        if *f {
            t.swap(1, 2);
        }
    }
    report.bbox_diagonal = bbox_diagonal(&w.verts);
    if options.check_unit && !(PLAUSIBLE_DIAGONAL.0..=PLAUSIBLE_DIAGONAL.1).contains(&report.bbox_diagonal) {
        return Err(SurfaceDefect::WrongUnit {
            diagonal: report.bbox_diagonal,
            scale: options.scale,
            suggested: suggest_scale(report.bbox_diagonal, options.scale),
        });
    }
    let mut loops = boundary_loops(&w, &topo);
    let mut volume = capped_volume(&w, &loops);
    if volume < 0.0 {
        volume = -volume;
        for t in &mut w.tris {
            t.swap(1, 2);
        }
        for f in &mut flip {
            *f = !*f;
        }
        for lp in &mut loops {
            lp.vertices.reverse();
            lp.normal = -lp.normal;
        }
    }
    loops.sort_by(|a, b| b.area.total_cmp(&a.area));
    if options.self_intersections {
        if let Some((first, second, pairs)) = first_intersection(&w.verts, &w.tris) {
            let c = |t: usize| w.tris[t].iter().map(|&i| w.verts[i as usize]).sum::<Vec3>() / 3.0;
            let (a, b) = (w.tin[first] as usize, w.tin[second] as usize);
            return Err(SurfaceDefect::SelfIntersection {
                first: a.min(b),
                second: a.max(b),
                near: 0.5 * (c(first) + c(second)),
                pairs,
            });
        }
    }
    report.flipped = flip.iter().filter(|&&f| f).count();
    report.boundary_loops = loops;
    report.volume = volume;
    report.area = w
        .tris
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| w.verts[i as usize]);
            0.5 * (b - a).cross(&(c - a)).norm()
        })
        .sum();
    report.input_vertex = w.vin;
    report.input_triangle = w.tin;
    Ok(CheckedSurface {
        mesh: SurfaceMesh {
            vertices: w.verts,
            triangles: w.tris,
        },
        report,
    })
}
