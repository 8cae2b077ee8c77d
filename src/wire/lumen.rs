//! What the wire touches: the [`Lumen`] trait (the nearest point of the
//! vessel's inner wall, the signed distance to it and the wall's normal;
//! the pieces of wall a contact sphere overlaps, [`Lumen::overlaps_cached`]) and
//! three walls: a rigid straight tube ([`StraightTube`], optionally closed at
//! its far end), a rigid curved tube ([`CurvedTube`]: a torus section between
//! two straight pieces) and a triangle surface whose vertices may move every
//! tick ([`TriangleLumen`], the inner wall of the vessel mesh, searched
//! through a uniform grid rebuilt in O(triangles) without allocating).

pub use crate::math::closest_on_triangle;
use crate::math::Vec3;

/// The nearest wall point seen from a query point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallHit {
    /// Signed distance from the query point to the wall (m): positive inside
    /// the lumen, negative beyond the wall.
    pub distance: f64,
    /// Unit normal of the wall at `point`, pointing into the lumen.
    pub normal: Vec3,
    /// The nearest wall point.
    pub point: Vec3,
    /// The wall's normal compliance at `point` (m/N): how far the wall
    /// gives per newton pressed on it along `normal`; 0 for a rigid wall.
    /// The wire's contact puts it in series with its penalty.
    pub compliance: f64,
    /// The triangle `point` lies on, for a [`TriangleLumen`] (an index into
    /// its triangles); [`NO_TRIANGLE`] for the analytic walls.
    pub triangle: u32,
}

/// [`WallHit::triangle`] of a wall that is not made of triangles.
pub const NO_TRIANGLE: u32 = u32::MAX;

/// [`WallHit::triangle`] of the continuation of a [`TriangleLumen`]'s
/// opening k is `OPENING_TAG − k` (no triangle of the surface).
pub const OPENING_TAG: u32 = u32::MAX - 1;

/// A vessel lumen as seen by the wire's contact.
pub trait Lumen {
    /// The nearest wall point to `p` if it is closer than `range` (m) — or
    /// beyond the wall at any depth a wall of this kind can tell; `None` when
    /// no wall is within `range`. Must not allocate (it runs in the 1 kHz
    /// step).
    fn probe(&self, p: Vec3, range: f64) -> Option<WallHit>;

    /// [`Lumen::probe`] for a query point that moves a little between calls
    /// (a wire node across Newton iterates and steps): `cache` is the
    /// caller's, one per query point, and lets a lumen keep what it found
    /// near the point. The result is that of [`Lumen::probe`]. The default
    /// keeps nothing. Must not allocate.
    fn probe_cached(&self, p: Vec3, range: f64, cache: &mut ProbeCache) -> Option<WallHit> {
        let _ = cache;
        self.probe(p, range)
    }

    /// Every piece of the wall that the sphere of `radius` about `p`
    /// overlaps, into `out`, for a point on the lumen's side whose nearest
    /// wall `nearest` (from [`Lumen::probe_cached`] with the same `cache`)
    /// is nearer than `radius`.
    ///
    /// Why: against a wall made of flat pieces, the distance to the
    /// nearest piece has a kink where two pieces meeting in a valley are
    /// equally near, and a sphere pressed into the valley has no
    /// equilibrium: its force turns from one piece's normal to the other's
    /// as it crosses the kink. A penalty summed over the pieces overlapped
    /// is smooth, and counts each once where pieces meet flat: the
    /// triangles' terms, less those of the edges two of them share, plus
    /// those of their vertices (weights in [`WallOverlap::weight`]): where
    /// the nearest point of several triangles is one edge or vertex, their
    /// terms cancel to one. The default (an analytic, smooth wall) is the
    /// nearest wall alone. Must not allocate.
    fn overlaps_cached(&self, p: Vec3, radius: f64, nearest: &WallHit, cache: &mut ProbeCache, out: &mut WallOverlaps) {
        let _ = (p, radius, cache);
        out.clear();
        let _ = out.push(WallOverlap::from_hit(nearest));
    }
}

/// One piece of the wall (a triangle, an edge or a vertex of a triangle
/// wall; the whole wall of an analytic one) that a contact sphere
/// overlaps: the sphere's penalty is the sum over its overlaps of
/// `weight` · ½ k (radius − `distance`)² (see [`Lumen::overlaps_cached`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallOverlap {
    /// +1 for a triangle, −1 for an edge two overlapped triangles share,
    /// 1 − (triangles) + (edges) about a vertex (1 inside the wall, 0 on
    /// its border).
    pub weight: f64,
    /// Distance from the sphere's centre to the piece (m, ≥ 0).
    pub distance: f64,
    /// Unit direction from the piece's nearest point to the centre.
    pub normal: Vec3,
    /// The wall's normal compliance there (m/N), as [`WallHit::compliance`].
    pub compliance: f64,
}

/// Overlaps one contact sphere holds at most (a vertex of the wall with
/// its fan of triangles and edges: six of each and the vertex fill 13).
pub const MAX_OVERLAPS: usize = 16;

/// A contact sphere's overlaps, fixed size.
pub type WallOverlaps = heapless::Vec<WallOverlap, MAX_OVERLAPS>;

impl WallOverlap {
    /// The nearest wall seen from a point on the lumen's side as the one
    /// piece overlapped.
    pub fn from_hit(hit: &WallHit) -> WallOverlap {
        WallOverlap {
            weight: 1.0,
            distance: hit.distance,
            normal: hit.normal,
            compliance: hit.compliance,
        }
    }
}

/// Candidate triangles a [`ProbeCache`] holds at most.
pub const PROBE_CACHE_CAP: usize = 48;

/// What [`TriangleLumen`] keeps for one query point between
/// [`Lumen::probe_cached`] calls: every triangle that came within a
/// distance `reach` of a centre point when it was built. A later query at
/// p with range r uses them alone if |p − centre| + r + (how far the wall
/// has moved since) ≤ `reach` and |p − centre| ≤ r / 2: every triangle
/// within r of p is among them then (triangle inequality), and a point
/// with none of them within r is on the centre's side of the wall, which
/// was the lumen's side (the centre's nearest wall was farther than the
/// distance moved). A centre beyond the wall by at most r / 2 (a wire
/// pressed into a compliant wall, which gives: its nodes sit beyond the
/// undented wall) serves too: the nearest wall of a query it covers is
/// then within r / 2 + r / 2 = r, so that wall is among the candidates and
/// the None case cannot arise. Deeper centres are left to the grid.
/// Otherwise the cache is rebuilt around p. Either way the result is the
/// grid probe's, bit for bit (`cached_probe_matches_the_grid_probe`).
/// Fixed size: nothing allocates.
#[derive(Debug, Clone, Copy)]
pub struct ProbeCache {
    /// Which lumen instance built it (0: empty).
    stamp: u64,
    centre: Vec3,
    reach: f64,
    /// The lumen's accumulated wall motion when it was built.
    moved: f64,
    /// False when the centre lay more than half the range beyond the wall
    /// or the candidates did not fit: queries then search the grid.
    usable: bool,
    /// How far the centre lay beyond the wall (m; 0 on the lumen's side):
    /// a query is served only if its nearest wall is sure to lie within
    /// its range (`depth` + its offset ≤ range, whatever the range).
    depth: f64,
    /// A lower bound on the centre's distance to every candidate when it
    /// was built (its nearest wall's distance, or `reach` if none was
    /// within it): a query farther than its range from all of them needs
    /// no candidate evaluated.
    clear: f64,
    len: u16,
    tris: [u32; PROBE_CACHE_CAP],
    /// The nearest candidate of the last full search ([`NO_NEAR`]: none
    /// since the cache was built), the point searched from, the lumen's
    /// `moved` then, and a lower bound on how much farther every other
    /// candidate was: a later query within `near_gap` / 2 of that point,
    /// wall motion included, has the same nearest candidate
    /// (`TriangleLumen::nearest_cached`).
    near: u32,
    near_at: Vec3,
    near_moved: f64,
    near_gap: f64,
}

/// [`ProbeCache`]'s `near` when no full search has run since it was built.
const NO_NEAR: u32 = u32::MAX;

impl Default for ProbeCache {
    fn default() -> Self {
        ProbeCache {
            stamp: 0,
            centre: Vec3::zeros(),
            reach: 0.0,
            moved: 0.0,
            usable: false,
            depth: 0.0,
            clear: 0.0,
            len: 0,
            tris: [0; PROBE_CACHE_CAP],
            near: NO_NEAR,
            near_at: Vec3::zeros(),
            near_moved: 0.0,
            near_gap: 0.0,
        }
    }
}

impl ProbeCache {
    /// Forgets what it holds (the next query rebuilds it).
    pub fn clear(&mut self) {
        self.stamp = 0;
    }

    /// Candidate triangles held (0 when empty or unusable).
    pub fn len(&self) -> usize {
        if self.stamp != 0 && self.usable {
            self.len as usize
        } else {
            0
        }
    }

    /// Whether it holds no candidate.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Gives every [`TriangleLumen`] instance (clones included) its own stamp,
/// so a [`ProbeCache`] is only used with the lumen that built it.
static NEXT_STAMP: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

fn new_stamp() -> u64 {
    NEXT_STAMP.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

/// No wall at all (a wire in free space, for tests and benchmarks).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct NoWall;

impl Lumen for NoWall {
    fn probe(&self, _p: Vec3, _range: f64) -> Option<WallHit> {
        None
    }
}

/// Errors building a lumen.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LumenError {
    /// A geometric parameter is out of range.
    #[error("{key}: {value}: {allowed}")]
    Param {
        /// Which parameter.
        key: &'static str,
        /// Its value.
        value: f64,
        /// What is allowed.
        allowed: &'static str,
    },
    /// A triangle refers to a vertex that does not exist.
    #[error("triangle {triangle} refers to vertex {vertex}, but there are {vertices} vertices")]
    BadIndex {
        /// The triangle.
        triangle: usize,
        /// The vertex index it holds.
        vertex: u32,
        /// How many vertices there are.
        vertices: usize,
    },
    /// No triangles.
    #[error("the surface has no triangles")]
    Empty,
    /// A vertex update has the wrong length or a non-finite position.
    #[error("vertex update: {0}")]
    Update(String),
}

fn positive(key: &'static str, value: f64) -> Result<(), LumenError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(LumenError::Param {
            key,
            value,
            allowed: "must be finite and > 0",
        })
    }
}

fn unit(key: &'static str, v: Vec3) -> Result<Vec3, LumenError> {
    let n = v.norm();
    if n.is_finite() && n > 1e-12 {
        Ok(v / n)
    } else {
        Err(LumenError::Param {
            key,
            value: n,
            allowed: "must be a finite non-zero vector",
        })
    }
}

/// A unit vector perpendicular to `a` (a unit vector).
pub(crate) fn perpendicular(a: Vec3) -> Vec3 {
    let t = if a.x.abs() < 0.9 { Vec3::x() } else { Vec3::y() };
    let p = t - a * a.dot(&t);
    p / p.norm()
}

/// The wall hit of a tube of radius `a` around the centreline point `c`.
fn tube_hit(p: Vec3, c: Vec3, a: f64, fallback: Vec3) -> WallHit {
    let r = p - c;
    let rho = r.norm();
    let out = if rho > 1e-15 { r / rho } else { -fallback };
    WallHit {
        distance: a - rho,
        normal: -out,
        point: c + out * a,
        compliance: 0.0,
        triangle: NO_TRIANGLE,
    }
}

/// A rigid straight tube: centreline from `start` along `axis`, open at the
/// start (it continues behind it), closed by a flat cap at `length` if
/// `closed_end`, otherwise open there too.
#[derive(Debug, Clone, PartialEq)]
pub struct StraightTube {
    start: Vec3,
    axis: Vec3,
    length: f64,
    radius: f64,
    closed_end: bool,
}

impl StraightTube {
    /// A tube of inner `radius` (m) from `start` along `axis` (normalised
    /// here) for `length` (m).
    pub fn new(start: Vec3, axis: Vec3, length: f64, radius: f64, closed_end: bool) -> Result<Self, LumenError> {
        positive("length", length)?;
        positive("radius", radius)?;
        Ok(StraightTube {
            start,
            axis: unit("axis", axis)?,
            length,
            radius,
            closed_end,
        })
    }
}

impl Lumen for StraightTube {
    fn probe(&self, p: Vec3, _range: f64) -> Option<WallHit> {
        let s = (p - self.start).dot(&self.axis);
        let c = self.start + self.axis * s;
        let side = tube_hit(p, c, self.radius, perpendicular(self.axis));
        if self.closed_end {
            let d = self.length - s;
            if d < side.distance {
                return Some(WallHit {
                    distance: d,
                    normal: -self.axis,
                    point: p + self.axis * d,
                    compliance: 0.0,
                    triangle: NO_TRIANGLE,
                });
            }
        }
        Some(side)
    }
}

/// A rigid curved tube: a straight inlet of length `inlet` from `start` along
/// `tangent`, then an arc of centreline radius `bend_radius` turning by
/// `angle` toward `toward` (a direction perpendicular to the tangent), then a
/// straight outlet of length `outlet`; inner radius `radius` everywhere.
#[derive(Debug, Clone, PartialEq)]
pub struct CurvedTube {
    start: Vec3,
    tangent: Vec3,
    arc_start: Vec3,
    center: Vec3,
    x: Vec3,
    y: Vec3,
    bend_radius: f64,
    angle: f64,
    arc_end: Vec3,
    out_tangent: Vec3,
    inlet: f64,
    outlet: f64,
    radius: f64,
}

/// The shape of a [`CurvedTube`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CurvedTubeShape {
    /// Start of the straight inlet (m).
    pub start: Vec3,
    /// Direction of the inlet.
    pub tangent: Vec3,
    /// The side the arc turns toward (its component along `tangent` is
    /// ignored).
    pub toward: Vec3,
    /// Inlet length (m).
    pub inlet: f64,
    /// Centreline radius of the arc (m).
    pub bend_radius: f64,
    /// Angle the arc turns by (rad), in (0, 2π).
    pub angle: f64,
    /// Outlet length (m).
    pub outlet: f64,
    /// Inner radius of the tube (m), below `bend_radius`.
    pub radius: f64,
}

impl CurvedTube {
    /// Builds the tube; errors name the bad parameter.
    pub fn new(s: &CurvedTubeShape) -> Result<Self, LumenError> {
        positive("bend_radius", s.bend_radius)?;
        positive("radius", s.radius)?;
        if !(s.inlet.is_finite() && s.inlet >= 0.0) {
            return Err(LumenError::Param {
                key: "inlet",
                value: s.inlet,
                allowed: "must be finite and ≥ 0",
            });
        }
        if !(s.outlet.is_finite() && s.outlet >= 0.0) {
            return Err(LumenError::Param {
                key: "outlet",
                value: s.outlet,
                allowed: "must be finite and ≥ 0",
            });
        }
        if !(s.angle > 0.0 && s.angle < 2.0 * std::f64::consts::PI) {
            return Err(LumenError::Param {
                key: "angle",
                value: s.angle,
                allowed: "must be in (0, 2π) rad",
            });
        }
        if s.radius >= s.bend_radius {
            return Err(LumenError::Param {
                key: "radius",
                value: s.radius,
                allowed: "must be below bend_radius",
            });
        }
        let t = unit("tangent", s.tangent)?;
        let toward = unit("toward", s.toward - t * s.toward.dot(&t))?;
        let arc_start = s.start + t * s.inlet;
        let center = arc_start + toward * s.bend_radius;
        let x = -toward;
        let y = t;
        let (sn, cs) = s.angle.sin_cos();
        let arc_end = center + (x * cs + y * sn) * s.bend_radius;
        let out_tangent = -x * sn + y * cs;
        Ok(CurvedTube {
            start: s.start,
            tangent: t,
            arc_start,
            center,
            x,
            y,
            bend_radius: s.bend_radius,
            angle: s.angle,
            arc_end,
            out_tangent,
            inlet: s.inlet,
            outlet: s.outlet,
            radius: s.radius,
        })
    }

    /// The point of the centreline at arc length `s` from the start (m),
    /// clamped to the tube, and its tangent.
    pub fn centreline(&self, s: f64) -> (Vec3, Vec3) {
        let arc = self.bend_radius * self.angle;
        if s <= self.inlet {
            (self.start + self.tangent * s.max(0.0), self.tangent)
        } else if s <= self.inlet + arc {
            let phi = (s - self.inlet) / self.bend_radius;
            let (sn, cs) = phi.sin_cos();
            (
                self.center + (self.x * cs + self.y * sn) * self.bend_radius,
                -self.x * sn + self.y * cs,
            )
        } else {
            let d = (s - self.inlet - arc).min(self.outlet);
            (self.arc_end + self.out_tangent * d, self.out_tangent)
        }
    }

    /// The centreline's total length (m).
    pub fn centreline_length(&self) -> f64 {
        self.inlet + self.bend_radius * self.angle + self.outlet
    }
}

impl Lumen for CurvedTube {
    fn probe(&self, p: Vec3, _range: f64) -> Option<WallHit> {
        // The nearest centreline point among the three pieces; the straight
        // pieces extend beyond the tube's ends, so the far ends stay open.
        let s_in = (p - self.start).dot(&self.tangent).min(self.inlet);
        let c_in = self.start + self.tangent * s_in;
        let s_out = (p - self.arc_end).dot(&self.out_tangent).max(0.0);
        let c_out = self.arc_end + self.out_tangent * s_out;
        let q = p - self.center;
        // The angle about the bend's centre in [0, 2π), then the nearer
        // end of the arc if it lies beyond it (an arc of more than π
        // reaches angles atan2 gives as negative).
        let mut phi = q.dot(&self.y).atan2(q.dot(&self.x));
        if phi < 0.0 {
            phi += std::f64::consts::TAU;
        }
        if phi > self.angle {
            phi = if phi - self.angle < std::f64::consts::TAU - phi {
                self.angle
            } else {
                0.0
            };
        }
        let (sn, cs) = phi.sin_cos();
        let c_arc = self.center + (self.x * cs + self.y * sn) * self.bend_radius;
        let mut best = (c_in, self.tangent);
        for c in [(c_arc, -self.x * sn + self.y * cs), (c_out, self.out_tangent)] {
            if (p - c.0).norm_squared() < (p - best.0).norm_squared() {
                best = c;
            }
        }
        Some(tube_hit(p, best.0, self.radius, perpendicular(best.1)))
    }
}

/// A triangle surface as the lumen's wall: triangles wound so that their
/// normals ((b − a) × (c − a)) point into the lumen. Vertices may move every
/// tick ([`TriangleLumen::update_vertices`]); the search grid is rebuilt then
/// in O(triangles) into buffers sized at construction.
///
/// Each triangle is filed in the grid cell of its centroid; a query searches
/// the cells within the query range plus the largest centroid-to-vertex
/// distance, so it is exact for any range. [`Lumen::probe_cached`] keeps,
/// per query point, the triangles near it ([`ProbeCache`]): a wire node
/// then tests a few triangles instead of walking the grid.
#[derive(Debug)]
pub struct TriangleLumen {
    verts: Vec<Vec3>,
    tris: Vec<[u32; 3]>,
    dims: [usize; 3],
    lo: Vec3,
    inv_cell: Vec3,
    cell: Vec3,
    reach: f64,
    cell_start: Vec<u32>,
    items: Vec<u32>,
    tri_cell: Vec<u32>,
    /// Per slot of `items`: the triangle's centroid and the distance to its
    /// farthest vertex, in the order a query walks them (a cheap lower
    /// bound on the distance that skips most triangles).
    spheres: Vec<[f64; 4]>,
    /// The same bounding spheres indexed by triangle (for cached queries).
    tri_spheres: Vec<[f64; 4]>,
    /// The wall's normal compliance per vertex (m/N; empty: rigid).
    compliance: Vec<f64>,
    /// This instance's stamp (see [`ProbeCache`]).
    stamp: u64,
    /// Sum over vertex updates of the largest vertex displacement (m): a
    /// bound on how far any wall point moved between two of its values.
    moved: f64,
    /// The surface's openings (boundary loops that end a tube), each
    /// continued beyond its plane by a straight rigid tube.
    openings: Vec<Opening>,
}

/// An opening of a [`TriangleLumen`]: a boundary loop of its surface that
/// ends a tube (a vessel's inlet or outlet, a branch stub's end). Beyond
/// its plane a surface with a hole has no inside: the lumen continues the
/// vessel there by a straight rigid tube along the opening's axis whose
/// cross-section is the loop itself (the loop's polygon in the plane,
/// extruded), so a wire may leave the mesh through it, or enter through
/// it, and is held as the continuing vessel would hold it; at the plane
/// the continuation's wall is the rim's, with no ledge (docs/WIRE.md "Open
/// ends").
#[derive(Debug, Clone, PartialEq)]
pub struct Opening {
    /// The loop's vertices, in order.
    ring: Vec<u32>,
    /// Centre of the loop (mean of its vertices, m).
    pub centre: Vec3,
    /// Unit normal of the loop's plane pointing out of the mesh.
    pub axis: Vec3,
    /// Largest distance of a loop vertex from the axis (m): the
    /// continuation applies within twice it of the axis.
    pub radius: f64,
    /// A basis of the plane (u, v, axis right-handed).
    u: Vec3,
    v: Vec3,
    /// The loop's vertices in the plane's basis, about the centre (m).
    flat: Vec<[f64; 2]>,
    /// The radius of a disk about the centre that lies inside the loop's
    /// polygon (m; 0 when the centre is outside it): a point whose
    /// projection is nearer the axis than `inner` less the range has no
    /// edge within the range (`Opening::probe`'s quick answer).
    inner: f64,
}

impl Opening {
    /// The loop's vertices (indices into the lumen's vertices), in order.
    pub fn ring(&self) -> &[u32] {
        &self.ring
    }

    /// Centre, outward axis and radius from the ring's current vertices
    /// (Newell's normal, signed by `outward`); false if degenerate.
    fn measure(&mut self, verts: &[Vec3], outward: Vec3) -> bool {
        let k = self.ring.len() as f64;
        let c = self.ring.iter().map(|&i| verts[i as usize]).sum::<Vec3>() / k;
        let mut n = Vec3::zeros();
        for (a, &i) in self.ring.iter().enumerate() {
            let j = self.ring[(a + 1) % self.ring.len()];
            n += (verts[i as usize] - c).cross(&(verts[j as usize] - c));
        }
        let nn = n.norm();
        if !(nn > 0.0 && nn.is_finite()) {
            return false;
        }
        let mut axis = n / nn;
        if axis.dot(&outward) < 0.0 {
            axis = -axis;
        }
        let radius = self
            .ring
            .iter()
            .map(|&i| {
                let r = verts[i as usize] - c;
                (r - axis * r.dot(&axis)).norm()
            })
            .fold(0.0, f64::max);
        self.centre = c;
        self.axis = axis;
        self.radius = radius;
        self.u = perpendicular(axis);
        self.v = axis.cross(&self.u);
        for (f, &i) in self.flat.iter_mut().zip(&self.ring) {
            let r = verts[i as usize] - c;
            *f = [r.dot(&self.u), r.dot(&self.v)];
        }
        // The nearest edge to the centre, and whether the centre is inside
        // (crossings of a ray, as `probe` counts them).
        let n = self.flat.len();
        let (mut near, mut inside) = (f64::INFINITY, false);
        for k in 0..n {
            let (px, py) = self.nearest_on_edge(k, 0.0, 0.0);
            near = near.min((px * px + py * py).sqrt());
            inside ^= self.crosses(k, 0.0, 0.0);
        }
        self.inner = if inside && near.is_finite() { near } else { 0.0 };
        radius > 0.0
    }

    /// The pieces of the continuation's wall that the sphere of `radius`
    /// about `p` overlaps (the faces of the extruded polygon, less the
    /// corners two of them share: smooth in the polygon's valleys, as
    /// [`TriangleLumen::overlaps`] for the surface), for a point inside
    /// it; else the nearest alone. Allocates nothing.
    #[allow(clippy::needless_range_loop)] // faces and corners by index, cyclically
    fn overlaps(&self, p: Vec3, radius: f64, nearest: &WallHit, out: &mut WallOverlaps) {
        out.clear();
        let alone = |out: &mut WallOverlaps| {
            out.clear();
            let _ = out.push(WallOverlap::from_hit(nearest));
        };
        let q = p - self.centre;
        let r = q - self.axis * q.dot(&self.axis);
        let (x, y) = (r.dot(&self.u), r.dot(&self.v));
        if nearest.distance <= 0.0 {
            return alone(out);
        }
        let n = self.flat.len();
        let piece = |px: f64, py: f64, weight: f64| {
            let (dx, dy) = (x - px, y - py);
            let d = (dx * dx + dy * dy).sqrt();
            (d < radius && d > 1e-12).then(|| WallOverlap {
                weight,
                distance: d,
                normal: (self.u * dx + self.v * dy) / d,
                compliance: 0.0,
            })
        };
        // Which faces overlap: bit k for face k (from vertex k to k + 1);
        // rings longer than 128 fall back to the nearest alone.
        if n > 128 {
            return alone(out);
        }
        let mut hit = [false; 128];
        for k in 0..n {
            let (px, py) = self.nearest_on_edge(k, x, y);
            if let Some(o) = piece(px, py, 1.0) {
                hit[k] = true;
                if out.push(o).is_err() {
                    return alone(out);
                }
            }
        }
        for k in 0..n {
            if hit[k] && hit[(k + n - 1) % n] {
                let [vx, vy] = self.flat[k];
                if let Some(o) = piece(vx, vy, -1.0) {
                    if out.push(o).is_err() {
                        return alone(out);
                    }
                }
            }
        }
        if out.is_empty() {
            alone(out);
        }
    }

    /// The point of the loop's flattened edge k (vertex k to k + 1) nearest
    /// to (x, y), in the opening's plane.
    /// Whether edge k of the loop's polygon crosses the ray from (x, y)
    /// along +x in the plane (a point is inside if an odd number do).
    fn crosses(&self, k: usize, x: f64, y: f64) -> bool {
        let n = self.flat.len();
        let ([ax, ay], [cx, cy]) = (self.flat[k], self.flat[(k + 1) % n]);
        (ay > y) != (cy > y) && x < ax + (y - ay) / (cy - ay) * (cx - ax)
    }

    fn nearest_on_edge(&self, k: usize, x: f64, y: f64) -> (f64, f64) {
        let n = self.flat.len();
        let [ax, ay] = self.flat[k];
        let [cx, cy] = self.flat[(k + 1) % n];
        let (ex, ey) = (cx - ax, cy - ay);
        let l2 = ex * ex + ey * ey;
        let t = if l2 > 0.0 {
            (((x - ax) * ex + (y - ay) * ey) / l2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (ax + t * ex, ay + t * ey)
    }

    /// The continuation's wall seen from `p` if `p` lies beyond the
    /// opening's plane and within twice its radius of the axis (its
    /// distance may then be beyond `range`): `Some(None)` when the wall is
    /// farther than `range`; `None` when the opening does not apply.
    fn probe(&self, p: Vec3, range: f64) -> Option<Option<WallHit>> {
        let q = p - self.centre;
        let h = q.dot(&self.axis);
        if h <= 0.0 {
            return None;
        }
        let r = q - self.axis * h;
        let r2 = r.norm_squared();
        if r2 >= 4.0 * self.radius * self.radius {
            return None;
        }
        // Deep inside the loop: every edge is at least `inner` − |r| away
        // (the disk of radius `inner` lies inside the polygon), beyond the
        // range with a margin far above the distances' rounding, so the
        // edge loop below would find the same: no wall within range (a
        // rod's nodes on the axis of the opening it enters through).
        if self.inner - r2.sqrt() > range + 1e-9 * self.radius {
            return Some(None);
        }
        // The nearest point of the loop's polygon to p's projection, and
        // whether the projection lies inside it (crossings of a ray).
        let (x, y) = (r.dot(&self.u), r.dot(&self.v));
        let n = self.flat.len();
        let (mut best, mut bx, mut by, mut inside) = (f64::INFINITY, 0.0, 0.0, false);
        for k in 0..n {
            let (px, py) = self.nearest_on_edge(k, x, y);
            let d2 = (x - px) * (x - px) + (y - py) * (y - py);
            if d2 < best {
                (best, bx, by) = (d2, px, py);
            }
            inside ^= self.crosses(k, x, y);
        }
        let d = best.sqrt();
        let (nx, ny) = if d > 1e-15 {
            let s = if inside { 1.0 } else { -1.0 };
            (s * (x - bx) / d, s * (y - by) / d)
        } else {
            let l = (bx * bx + by * by).sqrt().max(1e-300);
            (-bx / l, -by / l)
        };
        let hit = WallHit {
            distance: if inside { d } else { -d },
            normal: self.u * nx + self.v * ny,
            point: self.centre + self.axis * h + self.u * bx + self.v * by,
            compliance: 0.0,
            triangle: NO_TRIANGLE,
        };
        Some((hit.distance <= range).then_some(hit))
    }
}

/// The boundary loops of a triangle surface that end a tube, with the
/// direction out of the surface at each. A loop counts when it is nearly
/// planar (its vertices within a quarter of its radius of its plane) and
/// the triangles along it lie on one side of that plane (their third
/// vertices, on average, at least 30 % of the loop's mean edge from it):
/// a flat sheet's border is not an opening.
fn find_openings(verts: &[Vec3], tris: &[[u32; 3]]) -> Vec<Opening> {
    use std::collections::HashMap;
    let mut uses: HashMap<(u32, u32), u32> = HashMap::new();
    for t in tris {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *uses.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    // Boundary edges as the triangles wind them, and each one's third vertex.
    let mut next: HashMap<u32, (u32, u32)> = HashMap::new();
    for t in tris {
        for k in 0..3 {
            let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            if uses[&(a.min(b), a.max(b))] == 1 {
                next.insert(a, (b, c));
            }
        }
    }
    let mut starts: Vec<u32> = next.keys().copied().collect();
    starts.sort_unstable();
    let mut seen = std::collections::HashSet::new();
    let mut out = Vec::new();
    for s in starts {
        if seen.contains(&s) {
            continue;
        }
        let (mut ring, mut third) = (Vec::new(), Vec::new());
        let mut v = s;
        let closed = loop {
            if !seen.insert(v) {
                break v == s;
            }
            let Some(&(b, c)) = next.get(&v) else { break false };
            ring.push(v);
            third.push(c);
            v = b;
        };
        if !closed || ring.len() < 3 {
            continue;
        }
        let flat = vec![[0.0; 2]; ring.len()];
        let mut o = Opening {
            ring,
            centre: Vec3::zeros(),
            axis: Vec3::z(),
            radius: 0.0,
            u: Vec3::x(),
            v: Vec3::y(),
            flat,
            inner: 0.0,
        };
        if !o.measure(verts, Vec3::zeros()) {
            continue;
        }
        let side = third
            .iter()
            .map(|&c| (verts[c as usize] - o.centre).dot(&o.axis))
            .sum::<f64>()
            / third.len() as f64;
        let n = o.ring.len();
        let edge = (0..n)
            .map(|a| (verts[o.ring[(a + 1) % n] as usize] - verts[o.ring[a] as usize]).norm())
            .sum::<f64>()
            / n as f64;
        let flat = o
            .ring
            .iter()
            .all(|&i| (verts[i as usize] - o.centre).dot(&o.axis).abs() <= 0.25 * o.radius);
        if !flat || side.abs() < 0.3 * edge {
            continue;
        }
        if side > 0.0 {
            let out = -o.axis;
            o.measure(verts, out);
        }
        out.push(o);
    }
    out
}

impl Clone for TriangleLumen {
    /// A copy with its own stamp: caches built with one are not used with
    /// the other (the two may move differently).
    fn clone(&self) -> Self {
        TriangleLumen {
            verts: self.verts.clone(),
            tris: self.tris.clone(),
            dims: self.dims,
            lo: self.lo,
            inv_cell: self.inv_cell,
            cell: self.cell,
            reach: self.reach,
            cell_start: self.cell_start.clone(),
            items: self.items.clone(),
            tri_cell: self.tri_cell.clone(),
            spheres: self.spheres.clone(),
            tri_spheres: self.tri_spheres.clone(),
            compliance: self.compliance.clone(),
            stamp: new_stamp(),
            moved: self.moved,
            openings: self.openings.clone(),
        }
    }
}

impl TriangleLumen {
    /// A lumen from vertex positions and triangles (indices into them).
    pub fn new(vertices: &[Vec3], triangles: &[[u32; 3]]) -> Result<Self, LumenError> {
        if triangles.is_empty() {
            return Err(LumenError::Empty);
        }
        for (t, tri) in triangles.iter().enumerate() {
            for &v in tri {
                if v as usize >= vertices.len() {
                    return Err(LumenError::BadIndex {
                        triangle: t,
                        vertex: v,
                        vertices: vertices.len(),
                    });
                }
            }
        }
        check_finite(vertices)?;
        // Cells about twice the mean triangle size, at most 64 a side.
        let (lo, hi) = bounds(vertices);
        let ext = (hi - lo).map(|e| e.max(1e-9));
        let mean_edge: f64 = triangles
            .iter()
            .map(|t| (vertices[t[1] as usize] - vertices[t[0] as usize]).norm())
            .sum::<f64>()
            / triangles.len() as f64;
        let target = (2.0 * mean_edge).max(1e-9);
        let dims = [0, 1, 2].map(|k| ((ext[k] / target).ceil() as usize).clamp(1, 64));
        let cells = dims[0] * dims[1] * dims[2];
        let mut l = TriangleLumen {
            verts: vertices.to_vec(),
            tris: triangles.to_vec(),
            dims,
            lo,
            inv_cell: Vec3::zeros(),
            cell: Vec3::zeros(),
            reach: 0.0,
            cell_start: vec![0; cells + 1],
            items: vec![0; triangles.len()],
            tri_cell: vec![0; triangles.len()],
            spheres: vec![[0.0; 4]; triangles.len()],
            tri_spheres: vec![[0.0; 4]; triangles.len()],
            compliance: Vec::new(),
            stamp: new_stamp(),
            moved: 0.0,
            openings: find_openings(vertices, triangles),
        };
        l.rebuild();
        Ok(l)
    }

    /// The current vertex positions.
    pub fn vertices(&self) -> &[Vec3] {
        &self.verts
    }

    /// The triangles.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.tris
    }

    /// Sets the wall's normal compliance at each vertex (m/N, ≥ 0, finite;
    /// one per vertex), interpolated over the triangles into
    /// [`WallHit::compliance`]; an empty slice makes the wall rigid again.
    pub fn set_compliance(&mut self, per_vertex: &[f64]) -> Result<(), LumenError> {
        if !per_vertex.is_empty() && per_vertex.len() != self.verts.len() {
            return Err(LumenError::Update(format!(
                "{} compliances given, the surface has {} vertices",
                per_vertex.len(),
                self.verts.len()
            )));
        }
        if let Some(i) = per_vertex.iter().position(|c| !(c.is_finite() && *c >= 0.0)) {
            return Err(LumenError::Update(format!(
                "the compliance of vertex {i} is {} (must be finite and >= 0 m/N)",
                per_vertex[i]
            )));
        }
        self.compliance = per_vertex.to_vec();
        Ok(())
    }

    /// The wall's normal compliance per vertex (m/N; empty: rigid).
    pub fn compliance(&self) -> &[f64] {
        &self.compliance
    }

    /// A copy that shares this lumen's identity, so the wire's probe caches
    /// stay valid across twins: one producer updates a pool of twins with
    /// [`TriangleLumen::update_twin`] off the wire's thread and the wire
    /// swaps in the newest, instead of rebuilding the grid itself.
    /// Allocates (once, at setup).
    pub fn twin(&self) -> TriangleLumen {
        let mut t = self.clone();
        t.stamp = self.stamp;
        t
    }

    /// The bound on how far the wall has moved, summed over the updates
    /// (m): what [`TriangleLumen::update_twin`]'s `moved` continues.
    pub fn moved(&self) -> f64 {
        self.moved
    }

    /// Moves the vertices of a twin ([`TriangleLumen::twin`]) and rebuilds
    /// its grid. `moved` continues the twins' common bound on the wall's
    /// motion: the `moved` of the twins' last update plus the largest
    /// vertex displacement since it (the producer keeps both), and never
    /// less than this twin's own. Allocates nothing.
    pub fn update_twin(&mut self, vertices: &[Vec3], moved: f64) -> Result<(), LumenError> {
        if vertices.len() != self.verts.len() {
            return Err(LumenError::Update(format!(
                "{} vertices given, the surface has {}",
                vertices.len(),
                self.verts.len()
            )));
        }
        check_finite(vertices)?;
        if !(moved.is_finite() && moved >= self.moved) {
            return Err(LumenError::Update(format!(
                "motion bound {moved} m below this twin's {} m",
                self.moved
            )));
        }
        self.moved = moved;
        self.verts.copy_from_slice(vertices);
        self.rebuild();
        Ok(())
    }

    /// Moves the vertices (same count as at construction) and rebuilds the
    /// grid. Allocates nothing.
    pub fn update_vertices(&mut self, vertices: &[Vec3]) -> Result<(), LumenError> {
        if vertices.len() != self.verts.len() {
            return Err(LumenError::Update(format!(
                "{} vertices given, the surface has {}",
                vertices.len(),
                self.verts.len()
            )));
        }
        check_finite(vertices)?;
        let step = self
            .verts
            .iter()
            .zip(vertices)
            .map(|(a, b)| (a - b).norm_squared())
            .fold(0.0, f64::max)
            .sqrt();
        self.moved += step;
        self.verts.copy_from_slice(vertices);
        self.rebuild();
        Ok(())
    }

    fn cell_of(&self, p: Vec3) -> [usize; 3] {
        // Truncating a non-negative value is its floor (no libm call).
        [0, 1, 2].map(|k| (((p[k] - self.lo[k]) * self.inv_cell[k]).max(0.0) as usize).min(self.dims[k] - 1))
    }

    /// The surface's openings, each continued beyond its plane by a
    /// straight rigid tube (see [`Opening`]).
    pub fn openings(&self) -> &[Opening] {
        &self.openings
    }

    /// The wall seen from `p` with the openings continued: beyond an
    /// opening's plane (within twice its radius of its axis) the
    /// continuation's wall, or a piece of the surface on `p`'s side nearer
    /// than it (the surface's "beyond the wall" means nothing there: it
    /// has a hole); elsewhere the surface's `mesh` hit.
    fn continued(&self, p: Vec3, range: f64, mesh: Option<WallHit>) -> Option<WallHit> {
        for (k, o) in self.openings.iter().enumerate() {
            if let Some(cont) = o.probe(p, range) {
                let cont = cont.map(|h| WallHit {
                    triangle: OPENING_TAG - k as u32,
                    ..h
                });
                return match (mesh, cont) {
                    (Some(m), Some(c)) if m.distance > 0.0 && m.distance < c.distance => Some(m),
                    (Some(m), None) if m.distance > 0.0 => Some(m),
                    (_, c) => c,
                };
            }
        }
        mesh
    }

    fn rebuild(&mut self) {
        // The openings follow the wall (the loops' vertices move with it).
        for o in &mut self.openings {
            let out = o.axis;
            o.measure(&self.verts, out);
        }
        let (lo, hi) = bounds(&self.verts);
        self.lo = lo;
        for k in 0..3 {
            let ext = (hi[k] - lo[k]).max(1e-9);
            self.cell[k] = ext / self.dims[k] as f64;
            self.inv_cell[k] = 1.0 / self.cell[k];
        }
        let [nx, ny, _] = self.dims;
        self.cell_start.fill(0);
        let mut reach: f64 = 0.0;
        for t in 0..self.tris.len() {
            let [a, b, c] = self.tris[t].map(|i| self.verts[i as usize]);
            let g = (a + b + c) / 3.0;
            // One square root: sqrt is monotonic, so this is the largest
            // of the three distances exactly.
            let r = (a - g)
                .norm_squared()
                .max((b - g).norm_squared())
                .max((c - g).norm_squared())
                .sqrt();
            reach = reach.max(r);
            self.tri_spheres[t] = [g.x, g.y, g.z, r];
            let [i, j, k] = self.cell_of(g);
            let id = i + nx * (j + ny * k);
            self.tri_cell[t] = id as u32;
            self.cell_start[id + 1] += 1;
        }
        self.reach = reach;
        // Counting sort: prefix sums give each cell's start; filling moves
        // each start to its end, which a shift turns back into starts.
        for i in 0..self.cell_start.len() - 1 {
            self.cell_start[i + 1] += self.cell_start[i];
        }
        for t in 0..self.tris.len() {
            let id = self.tri_cell[t] as usize;
            let slot = self.cell_start[id] as usize;
            self.items[slot] = t as u32;
            self.spheres[slot] = self.tri_spheres[t];
            self.cell_start[id] += 1;
        }
        for i in (1..self.cell_start.len()).rev() {
            self.cell_start[i] = self.cell_start[i - 1];
        }
        self.cell_start[0] = 0;
    }
}

fn bounds(v: &[Vec3]) -> (Vec3, Vec3) {
    let mut lo = Vec3::repeat(f64::INFINITY);
    let mut hi = Vec3::repeat(f64::NEG_INFINITY);
    for p in v {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    (lo, hi)
}

fn check_finite(v: &[Vec3]) -> Result<(), LumenError> {
    match v.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        Some(i) => Err(LumenError::Update(format!("vertex {i} is not finite"))),
        None => Ok(()),
    }
}

impl TriangleLumen {
    /// [`Lumen::probe`] with the index of the nearest triangle (into
    /// [`TriangleLumen::triangles`]): where a contact's force goes on the
    /// wall. Allocates nothing.
    pub fn probe_triangle(&self, p: Vec3, range: f64) -> Option<(WallHit, usize)> {
        let best = self.nearest_in_grid(p, range.max(0.0));
        self.finish(p, range, best)
    }

    /// The nearest triangle to `p` among those filed in the cells within
    /// `range` plus the largest centroid-to-vertex distance (every triangle
    /// within `range` of `p` is among them): squared distance, nearest
    /// point, triangle. Walks the cells, and the triangles within them, in
    /// increasing slot order.
    fn nearest_in_grid(&self, p: Vec3, range: f64) -> Option<(f64, Vec3, usize)> {
        let r = range + self.reach;
        // Entirely outside the grid's box on some axis: nothing in range.
        for k in 0..3 {
            let lo = self.lo[k] - r;
            let hi = self.lo[k] + self.cell[k] * self.dims[k] as f64 + r;
            if p[k] < lo || p[k] > hi {
                return None;
            }
        }
        let a = self.cell_of(p - Vec3::repeat(r));
        let b = self.cell_of(p + Vec3::repeat(r));
        let [nx, ny, _] = self.dims;
        let mut best: Option<(f64, Vec3, usize)> = None;
        for k in a[2]..=b[2] {
            for j in a[1]..=b[1] {
                for i in a[0]..=b[0] {
                    let id = i + nx * (j + ny * k);
                    let (s, e) = (self.cell_start[id] as usize, self.cell_start[id + 1] as usize);
                    for slot in s..e {
                        self.consider(p, self.items[slot] as usize, &self.spheres[slot], &mut best);
                    }
                }
            }
        }
        best
    }

    /// Updates `best` with triangle `t` (bounding sphere `sphere`) unless
    /// its sphere is already farther than `best` (exact: only farther
    /// triangles are skipped). Ties keep the earlier triangle.
    #[inline]
    fn consider(&self, p: Vec3, t: usize, sphere: &[f64; 4], best: &mut Option<(f64, Vec3, usize)>) {
        let [gx, gy, gz, gr] = *sphere;
        if let Some((bd, _, _)) = *best {
            let dc = ((p.x - gx).powi(2) + (p.y - gy).powi(2) + (p.z - gz).powi(2)).sqrt();
            let lb = dc - gr;
            if lb > 0.0 && lb * lb >= bd {
                return;
            }
        }
        let [va, vb, vc] = self.tris[t].map(|i| self.verts[i as usize]);
        let q = closest_on_triangle(p, va, vb, vc);
        let d2 = (p - q).norm_squared();
        if best.is_none_or(|(bd, _, _)| d2 < bd) {
            *best = Some((d2, q, t));
        }
    }

    /// The hit for `p` from its nearest triangle: beyond `range` on the
    /// lumen's side is no wall; beyond the wall is always reported.
    fn finish(&self, p: Vec3, range: f64, best: Option<(f64, Vec3, usize)>) -> Option<(WallHit, usize)> {
        let (d2, q, t) = best?;
        let d = d2.sqrt();
        let [va, vb, vc] = self.tris[t].map(|i| self.verts[i as usize]);
        let nf = (vb - va).cross(&(vc - va));
        if d > range.max(0.0) && (p - q).dot(&nf) >= 0.0 {
            return None;
        }
        let nfn = nf.norm();
        let face = if nfn > 0.0 { nf / nfn } else { Vec3::z() };
        let side = (p - q).dot(&face);
        let (distance, normal) = if d > 1e-12 {
            let s = if side >= 0.0 { 1.0 } else { -1.0 };
            (s * d, (p - q) / d * s)
        } else {
            (0.0, face)
        };
        let compliance = self.compliance_at(t, q);
        Some((
            WallHit {
                distance,
                normal,
                point: q,
                compliance,
                triangle: t as u32,
            },
            t,
        ))
    }

    /// [`TriangleLumen::probe_triangle`] through `cache` (see
    /// [`ProbeCache`]): the same result, from the few triangles kept near
    /// `p` when the cache covers it, rebuilding it around `p` otherwise.
    /// Allocates nothing.
    pub fn probe_triangle_cached(&self, p: Vec3, range: f64, cache: &mut ProbeCache) -> Option<(WallHit, usize)> {
        let range = range.max(0.0);
        if !self.covers(cache, p, range) {
            self.build_cache(cache, p, range);
        }
        if !cache.usable {
            return self.probe_triangle(p, range);
        }
        // Every candidate is at least `clear` from the centre, less how far
        // the wall moved since: when that is beyond `range` from p (with a
        // margin far above the distances' rounding), none is within range,
        // which the loop below would find too. Most of a wire's nodes are
        // far from the wall.
        let off = (p - cache.centre).norm() + (self.moved - cache.moved);
        if cache.clear - off > range + 1e-9 * range.max(cache.clear) {
            return None;
        }
        let best = self.nearest_cached(p, cache);
        match best {
            // Every triangle within `range` of p is a candidate: none is
            // within range, and p is on the lumen's side (see ProbeCache).
            Some((d2, _, _)) if d2 > range * range => None,
            _ => self.finish(p, range, best),
        }
    }

    /// The nearest of `cache`'s candidates to `p` (squared distance,
    /// nearest point, triangle), as [`TriangleLumen::consider`] over them
    /// all in order finds it. When `p` is within half the last full
    /// search's gap of the point it searched from (the wall's motion since
    /// counted in), that search's nearest triangle is still strictly the
    /// nearest (triangle inequality: it came nearer by at most the drift,
    /// every other candidate by at most the drift too), and only its
    /// distance is computed: the same result, bit for bit, as the full
    /// search (`cached_probe_matches_the_grid_probe`).
    ///
    /// Why: a wire's node moves micrometres between the evaluations of a
    /// step and between steps, while its cache holds a dozen candidates;
    /// the full search over them was the largest part of a wall-loaded
    /// step (the tick bench's 33 contacts: ~60 probes an evaluation).
    fn nearest_cached(&self, p: Vec3, cache: &mut ProbeCache) -> Option<(f64, Vec3, usize)> {
        if cache.near != NO_NEAR {
            let drift = (p - cache.near_at).norm() + (self.moved - cache.near_moved);
            // The margin covers the distances' rounding, far below it.
            if cache.near_gap > 2.0 * drift + 1e-9 * cache.reach {
                let t = cache.near as usize;
                let [va, vb, vc] = self.tris[t].map(|i| self.verts[i as usize]);
                let q = closest_on_triangle(p, va, vb, vc);
                return Some(((p - q).norm_squared(), q, t));
            }
        }
        // The full search, as `consider` does it, noting a lower bound on
        // every other candidate's distance: its own where computed, its
        // sphere's where skipped (at least the best's distance).
        let mut best: Option<(f64, Vec3, usize)> = None;
        let mut other = f64::INFINITY;
        for &t in &cache.tris[..cache.len as usize] {
            let t = t as usize;
            let [gx, gy, gz, gr] = self.tri_spheres[t];
            if let Some((bd, _, _)) = best {
                let dc = ((p.x - gx).powi(2) + (p.y - gy).powi(2) + (p.z - gz).powi(2)).sqrt();
                let lb = dc - gr;
                if lb > 0.0 && lb * lb >= bd {
                    other = other.min(lb);
                    continue;
                }
            }
            let [va, vb, vc] = self.tris[t].map(|i| self.verts[i as usize]);
            let q = closest_on_triangle(p, va, vb, vc);
            let d2 = (p - q).norm_squared();
            match best {
                Some((bd, _, _)) if d2 >= bd => other = other.min(d2.sqrt()),
                _ => {
                    if let Some((bd, _, _)) = best {
                        other = other.min(bd.sqrt());
                    }
                    best = Some((d2, q, t));
                }
            }
        }
        match best {
            Some((d2, _, t)) => {
                cache.near = t as u32;
                cache.near_at = p;
                cache.near_moved = self.moved;
                cache.near_gap = other - d2.sqrt();
            }
            None => cache.near = NO_NEAR,
        }
        best
    }

    /// Whether `cache` was built by this lumen and holds every triangle
    /// within `range` of `p`, with `p` close enough to its centre that the
    /// side of the wall is known.
    fn covers(&self, cache: &ProbeCache, p: Vec3, range: f64) -> bool {
        if cache.stamp != self.stamp {
            return false;
        }
        let off = (p - cache.centre).norm() + (self.moved - cache.moved);
        off <= 0.5 * range && off + range <= cache.reach && cache.depth + off <= range
    }

    /// Rebuilds `cache` around `c` for queries of `range`: every triangle
    /// whose bounding sphere comes within 1.5 `range` of `c`, in slot
    /// order (that of a grid query, so ties resolve alike).
    fn build_cache(&self, cache: &mut ProbeCache, c: Vec3, range: f64) {
        let reach = 1.5 * range;
        cache.stamp = self.stamp;
        cache.centre = c;
        cache.reach = reach;
        cache.moved = self.moved;
        cache.len = 0;
        cache.near = NO_NEAR;
        // A centre on the lumen's side, or beyond the wall by at most half
        // the range (a wire pressed into a compliant wall, which gives: the
        // nearest wall of every query it serves then lies within the
        // range; see ProbeCache). Deeper centres are left to the grid.
        (cache.usable, cache.clear) = match self.probe_triangle(c, reach) {
            None => (true, reach),
            Some((h, _)) => (h.distance >= -0.5 * range, h.distance),
        };
        cache.depth = (-cache.clear).max(0.0);
        if !cache.usable {
            return;
        }
        let r = reach + self.reach;
        for k in 0..3 {
            let lo = self.lo[k] - r;
            let hi = self.lo[k] + self.cell[k] * self.dims[k] as f64 + r;
            if c[k] < lo || c[k] > hi {
                return;
            }
        }
        let a = self.cell_of(c - Vec3::repeat(r));
        let b = self.cell_of(c + Vec3::repeat(r));
        let [nx, ny, _] = self.dims;
        for k in a[2]..=b[2] {
            for j in a[1]..=b[1] {
                for i in a[0]..=b[0] {
                    let id = i + nx * (j + ny * k);
                    let (s, e) = (self.cell_start[id] as usize, self.cell_start[id + 1] as usize);
                    for slot in s..e {
                        let [gx, gy, gz, gr] = self.spheres[slot];
                        let dc = ((c.x - gx).powi(2) + (c.y - gy).powi(2) + (c.z - gz).powi(2)).sqrt();
                        if dc - gr > reach {
                            continue;
                        }
                        if cache.len as usize == PROBE_CACHE_CAP {
                            cache.usable = false;
                            return;
                        }
                        cache.tris[cache.len as usize] = self.items[slot];
                        cache.len += 1;
                    }
                }
            }
        }
    }

    /// [`Lumen::overlaps_cached`] for the triangle wall: the triangles
    /// nearer than `radius` among the cache's candidates, the edges two of
    /// them share and their vertices, each nearer than `radius`. Falls
    /// back to the nearest wall alone when the cache does not cover `p`,
    /// when `p` is not on the lumen's side, or when the overlaps do not
    /// fit in [`MAX_OVERLAPS`]. Allocates nothing.
    pub fn overlaps(&self, p: Vec3, radius: f64, nearest: &WallHit, cache: &ProbeCache, out: &mut WallOverlaps) {
        out.clear();
        let alone = |out: &mut WallOverlaps| {
            out.clear();
            let _ = out.push(WallOverlap::from_hit(nearest));
        };
        // Every triangle within `radius` of p must be a candidate; an
        // opening's continuation (no triangle) is one smooth wall.
        let off = (p - cache.centre).norm() + (self.moved - cache.moved);
        if nearest.distance <= 0.0
            || nearest.triangle as usize >= self.tris.len()
            || !cache.usable
            || cache.stamp != self.stamp
            || off + radius > cache.reach
        {
            return alone(out);
        }
        let comp = |v: u32| {
            if self.compliance.is_empty() {
                0.0
            } else {
                self.compliance[v as usize].max(0.0)
            }
        };
        // The triangles overlapped (indices kept for the edges and vertices).
        let mut faces: heapless::Vec<u32, MAX_OVERLAPS> = heapless::Vec::new();
        for &t in &cache.tris[..cache.len as usize] {
            let [gx, gy, gz, gr] = self.tri_spheres[t as usize];
            let dc = ((p.x - gx).powi(2) + (p.y - gy).powi(2) + (p.z - gz).powi(2)).sqrt();
            if dc - gr >= radius {
                continue;
            }
            let [va, vb, vc] = self.tris[t as usize].map(|i| self.verts[i as usize]);
            let q = closest_on_triangle(p, va, vb, vc);
            let d = (p - q).norm();
            if d >= radius || d <= 1e-12 {
                continue;
            }
            let face = WallOverlap {
                weight: 1.0,
                distance: d,
                normal: (p - q) / d,
                compliance: self.compliance_at(t as usize, q),
            };
            if faces.push(t).is_err() || out.push(face).is_err() {
                return alone(out);
            }
        }
        if faces.len() < 2 {
            return alone(out);
        }
        // Edges shared by two overlapped triangles, then the vertices.
        let mut edges: heapless::Vec<[u32; 2], MAX_OVERLAPS> = heapless::Vec::new();
        for (a, &ta) in faces.iter().enumerate() {
            let ia = self.tris[ta as usize];
            for &tb in &faces[a + 1..] {
                let ib = self.tris[tb as usize];
                let mut shared = [0u32; 2];
                let mut k = 0;
                for v in ia {
                    if ib.contains(&v) && k < 2 {
                        shared[k] = v;
                        k += 1;
                    }
                }
                if k < 2 {
                    continue;
                }
                let (a0, b0) = (self.verts[shared[0] as usize], self.verts[shared[1] as usize]);
                let s = crate::math::segment_parameter(p, a0, b0);
                let q = a0 + (b0 - a0) * s;
                let d = (p - q).norm();
                if d >= radius || d <= 1e-12 {
                    continue;
                }
                let edge = WallOverlap {
                    weight: -1.0,
                    distance: d,
                    normal: (p - q) / d,
                    compliance: (1.0 - s) * comp(shared[0]) + s * comp(shared[1]),
                };
                if edges.push(shared).is_err() || out.push(edge).is_err() {
                    return alone(out);
                }
            }
        }
        let mut seen: heapless::Vec<u32, { 3 * MAX_OVERLAPS }> = heapless::Vec::new();
        for &t in &faces {
            for v in self.tris[t as usize] {
                if seen.contains(&v) {
                    continue;
                }
                let _ = seen.push(v);
                let q = self.verts[v as usize];
                let d = (p - q).norm();
                if d >= radius || d <= 1e-12 {
                    continue;
                }
                let nf = faces.iter().filter(|&&t| self.tris[t as usize].contains(&v)).count() as f64;
                let ne = edges.iter().filter(|e| e.contains(&v)).count() as f64;
                let weight = 1.0 - nf + ne;
                if weight == 0.0 {
                    continue;
                }
                let vertex = WallOverlap {
                    weight,
                    distance: d,
                    normal: (p - q) / d,
                    compliance: comp(v),
                };
                if out.push(vertex).is_err() {
                    return alone(out);
                }
            }
        }
    }

    /// The wall's normal compliance at `q`, a point of triangle `t`: its
    /// vertices' compliances interpolated (0 for a rigid wall).
    fn compliance_at(&self, t: usize, q: Vec3) -> f64 {
        if self.compliance.is_empty() {
            return 0.0;
        }
        let w = self.barycentric(t, q);
        let c = self.tris[t].map(|i| self.compliance[i as usize]);
        (w[0] * c[0] + w[1] * c[1] + w[2] * c[2]).max(0.0)
    }

    /// Barycentric weights of `q` (a point on or near triangle `t`) on the
    /// triangle's three vertices: non-negative, summing to 1 (clamped to
    /// the triangle).
    pub fn barycentric(&self, t: usize, q: Vec3) -> [f64; 3] {
        let [a, b, c] = self.tris[t].map(|i| self.verts[i as usize]);
        let (v0, v1, v2) = (b - a, c - a, q - a);
        let (d00, d01, d11) = (v0.dot(&v0), v0.dot(&v1), v1.dot(&v1));
        let (d20, d21) = (v2.dot(&v0), v2.dot(&v1));
        let den = d00 * d11 - d01 * d01;
        if den.is_nan() || den.abs() <= 1e-300 {
            return [1.0 / 3.0; 3];
        }
        let v = ((d11 * d20 - d01 * d21) / den).max(0.0);
        let w = ((d00 * d21 - d01 * d20) / den).max(0.0);
        let u = (1.0 - v - w).max(0.0);
        let s = u + v + w;
        if s > 0.0 {
            [u / s, v / s, w / s]
        } else {
            [1.0 / 3.0; 3]
        }
    }
}

impl Lumen for TriangleLumen {
    fn probe(&self, p: Vec3, range: f64) -> Option<WallHit> {
        self.continued(p, range, self.probe_triangle(p, range).map(|(h, _)| h))
    }

    fn probe_cached(&self, p: Vec3, range: f64, cache: &mut ProbeCache) -> Option<WallHit> {
        self.continued(p, range, self.probe_triangle_cached(p, range, cache).map(|(h, _)| h))
    }

    fn overlaps_cached(&self, p: Vec3, radius: f64, nearest: &WallHit, cache: &mut ProbeCache, out: &mut WallOverlaps) {
        let k = OPENING_TAG.wrapping_sub(nearest.triangle) as usize;
        match self.openings.get(k).filter(|_| nearest.triangle != NO_TRIANGLE) {
            Some(o) => o.overlaps(p, radius, nearest, out),
            None => self.overlaps(p, radius, nearest, cache, out),
        }
    }
}

/// The inner wall of a straight tube along x as triangles wound inward
/// (normals into the lumen, as [`TriangleLumen::new`] takes them): a
/// regular polygon of `sides` vertices at `radius` from the axis, the first
/// at the angle `phase` (radians, from +y toward +z), on `rings` + 1 rings
/// from x = `x0` to `x0 + length`. With many sides it is a faceted circular
/// tube; with few, a duct whose corners are ridges of the wall's distance.
pub fn tube_wall(
    x0: f64,
    length: f64,
    radius: f64,
    sides: usize,
    rings: usize,
    phase: f64,
) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut v = Vec::with_capacity((rings + 1) * sides);
    for l in 0..=rings {
        for r in 0..sides {
            let phi = phase + r as f64 / sides as f64 * std::f64::consts::TAU;
            v.push(Vec3::new(
                x0 + length * l as f64 / rings as f64,
                radius * phi.cos(),
                radius * phi.sin(),
            ));
        }
    }
    let mut t = Vec::with_capacity(2 * rings * sides);
    for l in 0..rings {
        for r in 0..sides {
            let i = |l: usize, r: usize| (l * sides + r % sides) as u32;
            // Inward normals: (b − a) × (c − a) toward the axis.
            t.push([i(l, r), i(l + 1, r), i(l, r + 1)]);
            t.push([i(l, r + 1), i(l + 1, r), i(l + 1, r + 1)]);
        }
    }
    (v, t)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed-ring tube surface (radius a around the x axis from 0 to len),
    /// wound inward.
    fn tube_mesh(a: f64, len: f64, nr: usize, nl: usize) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        tube_wall(0.0, len, a, nr, nl, 0.0)
    }

    /// Uniform numbers in [−0.5, 0.5) from a fixed seed (a 64-bit LCG).
    fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut s = seed;
        move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        }
    }

    /// Moves `p` by `d`, keeps it inside the test tube (x in 2–48 mm, within
    /// 6 mm of the axis), probes it through `cache` and through the grid and
    /// asserts they agree (`at`: iteration and point, for the message).
    /// Returns whether a wall was hit and whether the cache's kept
    /// candidates answered (no rebuild).
    fn wander_and_probe(
        lum: &TriangleLumen,
        p: &mut Vec3,
        d: Vec3,
        range: f64,
        cache: &mut ProbeCache,
        at: (usize, usize),
    ) -> (bool, bool) {
        *p += d;
        p.x = p.x.clamp(0.002, 0.048);
        let rho = (p.y * p.y + p.z * p.z).sqrt();
        if rho > 6e-3 {
            *p *= 6e-3 / rho;
        }
        let before = (cache.stamp, cache.centre);
        let a = lum.probe_triangle(*p, range);
        let b = lum.probe_triangle_cached(*p, range, cache);
        assert_eq!(a, b, "iteration {}, point {} at {p:?}", at.0, at.1);
        let kept = before == (cache.stamp, cache.centre) && !cache.is_empty();
        (a.is_some(), kept)
    }

    #[test]
    fn triangle_lumen_matches_brute_force_and_the_tube() {
        let (v, t) = tube_mesh(5e-3, 0.05, 32, 20);
        let mut lum = TriangleLumen::new(&v, &t).unwrap();
        let mut rnd = uniform(7);
        for pass in 0..2 {
            let a = if pass == 0 { 5e-3 } else { 4e-3 };
            for _ in 0..300 {
                let p = Vec3::new(0.01 + 0.03 * (rnd() + 0.5), 0.012 * rnd(), 0.012 * rnd());
                let brute = lum
                    .triangles()
                    .iter()
                    .map(|tr| {
                        let [a, b, c] = tr.map(|i| lum.vertices()[i as usize]);
                        (p - closest_on_triangle(p, a, b, c)).norm()
                    })
                    .fold(f64::INFINITY, f64::min);
                let h = lum.probe(p, 1.0).unwrap();
                assert!((h.distance.abs() - brute).abs() < 1e-12, "{} vs {brute}", h.distance);
                // Inside the (faceted) tube: positive; well outside: negative.
                let rho = (p.y * p.y + p.z * p.z).sqrt();
                if rho < 0.9 * a {
                    assert!(h.distance > 0.0);
                    assert!(h.normal.dot(&Vec3::new(0.0, -p.y, -p.z)) > 0.0);
                }
                if rho > 1.1 * a {
                    assert!(h.distance < 0.0, "pass {pass} p {p:?} rho {rho} h {h:?}");
                }
                // A small range: inside points far from the wall see nothing.
                if h.distance > 1e-3 {
                    assert!(lum.probe(p, 0.5e-3).is_none());
                }
            }
            if pass == 0 {
                // Move the wall: shrink the radius to 4 mm.
                let moved: Vec<Vec3> = v.iter().map(|p| Vec3::new(p.x, p.y * 0.8, p.z * 0.8)).collect();
                lum.update_vertices(&moved).unwrap();
            }
        }
        assert!(lum.update_vertices(&v[..3]).is_err());
    }

    /// A cached probe gives the grid probe's result, bit for bit, for
    /// points wandering in small and large steps near and far from the
    /// wall, across wall updates (small moves keep the caches, a large one
    /// and a clone drop them).
    #[test]
    fn cached_probe_matches_the_grid_probe() {
        let (v, t) = tube_mesh(5e-3, 0.05, 32, 20);
        let mut lum = TriangleLumen::new(&v, &t).unwrap();
        let mut rnd = uniform(11);
        let range = 1.335e-3;
        let mut caches = [ProbeCache::default(); 8];
        let mut pts: Vec<Vec3> = (0..8)
            .map(|k| Vec3::new(0.005 + 0.005 * k as f64, 4.0e-3 - 0.6e-3 * k as f64, 0.0))
            .collect();
        let (mut hits, mut kept) = (0, 0);
        for it in 0..4000 {
            if it % 500 == 499 {
                // Breathe the wall by up to 20 µm; every 1500 iterations 1 mm.
                let f = if it % 1500 == 1499 { 0.8 } else { 1.0 + 0.004 * rnd() };
                let moved: Vec<Vec3> = lum
                    .vertices()
                    .iter()
                    .map(|p| Vec3::new(p.x, p.y * f, p.z * f))
                    .collect();
                lum.update_vertices(&moved).unwrap();
            }
            if it == 2200 {
                lum = lum.clone();
            }
            for (k, p) in pts.iter_mut().enumerate() {
                let step = if it % 97 == k { 4e-3 } else { 0.1e-3 };
                let d = Vec3::new(rnd(), rnd(), rnd()) * step;
                let (hit, from_cache) = wander_and_probe(&lum, p, d, range, &mut caches[k], (it, k));
                hits += hit as usize;
                kept += from_cache as usize;
                assert!(caches[k].len() <= PROBE_CACHE_CAP);
            }
        }
        assert!(hits > 2000, "{hits} hits");
        assert!(kept > 10000, "{kept} cached queries");
    }

    /// Points drifting by micrometres, as a wire's nodes do between the
    /// evaluations of a step, while the wall breathes by less and twins
    /// are swapped in: every query is the grid probe's, bit for bit, and
    /// most take the last full search's nearest triangle.
    #[test]
    fn a_probe_that_drifts_micrometres_keeps_its_nearest_triangle_exactly() {
        let (v, t) = tube_mesh(5e-3, 0.05, 32, 20);
        let first = TriangleLumen::new(&v, &t).unwrap();
        let mut spare = first.twin();
        let mut current = first;
        let mut moved = 0.0;
        let mut last = v.clone();
        let mut rnd = uniform(17);
        let range = 1.335e-3;
        let mut caches = [ProbeCache::default(); 8];
        // Near the wall (0.1–1 mm inside it), where a wire's nodes probe.
        let mut pts: Vec<Vec3> = (0..8)
            .map(|k| {
                let phi = 0.8 * k as f64;
                let rho = 4.0e-3 + 0.12e-3 * k as f64;
                Vec3::new(0.006 + 0.005 * k as f64, rho * phi.cos(), rho * phi.sin())
            })
            .collect();
        let (mut quick, mut queries) = (0, 0);
        for it in 0..6000 {
            if it % 17 == 16 {
                let f = 1.0 + 0.0004 * rnd();
                let new: Vec<Vec3> = v.iter().map(|p| Vec3::new(p.x, p.y * f, p.z * f)).collect();
                moved += new.iter().zip(&last).map(|(a, b)| (a - b).norm()).fold(0.0, f64::max);
                last.copy_from_slice(&new);
                spare.update_twin(&new, moved).unwrap();
                std::mem::swap(&mut current, &mut spare);
            }
            for (k, p) in pts.iter_mut().enumerate() {
                let d = Vec3::new(rnd(), rnd(), rnd()) * 4e-6;
                let at = caches[k].near_at;
                wander_and_probe(&current, p, d, range, &mut caches[k], (it, k));
                quick += (caches[k].near != NO_NEAR && caches[k].near_at == at) as usize;
                queries += 1;
            }
        }
        assert!(
            quick > queries / 2,
            "{quick} of {queries} queries took the kept nearest triangle"
        );
    }

    /// Nodes of a wire pressed into a compliant wall sit beyond the
    /// undented wall by a fraction of a millimetre: their caches serve them
    /// (the nearest wall is within range), and the result is the grid's.
    #[test]
    fn a_cache_beyond_the_wall_serves_and_matches_the_grid_probe() {
        let (v, t) = tube_mesh(5e-3, 0.05, 32, 20);
        let lum = TriangleLumen::new(&v, &t).unwrap();
        let mut rnd = uniform(3);
        let range = 1.335e-3;
        let mut caches = [ProbeCache::default(); 6];
        let mut kept = 0;
        for it in 0..2000 {
            for (k, cache) in caches.iter_mut().enumerate() {
                // 0.05–0.6 mm beyond the 5 mm wall, wandering along it.
                let phi = 0.3 * k as f64 + 1e-3 * it as f64 + 0.02 * rnd();
                let rho = 5.05e-3 + 0.55e-3 * (rnd() + 0.5);
                let mut p = Vec3::new(
                    0.01 + 0.004 * k as f64 + 1e-5 * it as f64,
                    rho * phi.cos(),
                    rho * phi.sin(),
                );
                let hit = wander_and_probe(&lum, &mut p, Vec3::zeros(), range, cache, (it, k));
                assert!(hit.0, "beyond the wall is always a hit");
                kept += hit.1 as usize;
            }
        }
        assert!(kept > 10000, "{kept} of 12000 queries from kept candidates");
    }

    #[test]
    fn a_pool_of_twins_updated_in_turn_keeps_the_caches_exact_and_in_use() {
        // The service's pattern: a producer updates three twins in turn with
        // the wall's running motion bound; the consumer swaps in the newest.
        // Cached probes on whichever twin is current equal the grid probe,
        // and most still come from the kept candidates.
        let (v, t) = tube_mesh(5e-3, 0.05, 32, 20);
        let first = TriangleLumen::new(&v, &t).unwrap();
        let mut pool: Vec<TriangleLumen> = (0..3).map(|_| first.twin()).collect();
        let mut current = first;
        let mut last = v.clone();
        let mut moved = 0.0;
        let mut rnd = uniform(5);
        let range = 1.335e-3;
        let mut caches = [ProbeCache::default(); 6];
        let mut pts: Vec<Vec3> = (0..6)
            .map(|k| Vec3::new(0.006 + 0.006 * k as f64, 4.0e-3 - 0.7e-3 * k as f64, 0.0))
            .collect();
        let (mut kept, mut swaps) = (0, 0);
        for it in 0..3000 {
            if it % 17 == 16 {
                // The producer: breathe the wall by up to 30 µm (1 mm every
                // 600 iterations), into the next free twin.
                let f = if it % 600 == 594 { 0.8 } else { 1.0 + 0.006 * rnd() };
                let new: Vec<Vec3> = v.iter().map(|p| Vec3::new(p.x, p.y * f, p.z * f)).collect();
                moved += new.iter().zip(&last).map(|(a, b)| (a - b).norm()).fold(0.0, f64::max);
                last.copy_from_slice(&new);
                let mut next = pool.remove(0);
                next.update_twin(&new, moved).unwrap();
                // The consumer swaps it in and hands the old one back.
                pool.push(std::mem::replace(&mut current, next));
                swaps += 1;
            }
            for (k, p) in pts.iter_mut().enumerate() {
                let d = Vec3::new(rnd(), rnd(), rnd()) * 0.1e-3;
                kept += wander_and_probe(&current, p, d, range, &mut caches[k], (it, k)).1 as usize;
            }
        }
        assert!(swaps > 150);
        assert!(kept > 6000, "{kept} cached queries");
        // A motion bound that goes back is refused.
        let mut t0 = current.twin();
        assert!(t0.update_twin(&last, current.moved() - 1e-3).is_err());
        assert!(t0.update_twin(&last[1..], current.moved()).is_err());
    }

    #[test]
    fn tubes_report_signed_distance_and_inward_normal() {
        let t = StraightTube::new(Vec3::zeros(), Vec3::x(), 0.1, 2e-3, true).unwrap();
        let h = t.probe(Vec3::new(0.05, 1.5e-3, 0.0), 0.0).unwrap();
        assert!((h.distance - 0.5e-3).abs() < 1e-15);
        assert!((h.normal - Vec3::new(0.0, -1.0, 0.0)).norm() < 1e-12);
        let h = t.probe(Vec3::new(0.1005, 0.0, 0.0), 0.0).unwrap();
        assert!((h.distance + 0.5e-3).abs() < 1e-12);
        assert!((h.normal + Vec3::x()).norm() < 1e-12);

        let c = CurvedTube::new(&CurvedTubeShape {
            start: Vec3::zeros(),
            tangent: Vec3::x(),
            toward: Vec3::y(),
            inlet: 0.01,
            bend_radius: 0.05,
            angle: std::f64::consts::PI,
            outlet: 0.01,
            radius: 3e-3,
        })
        .unwrap();
        // The arc's midpoint is at (0.01 + 0.05, 0.05, 0); a point 2 mm
        // toward the bend centre from it is 1 mm from the inner wall.
        let h = c.probe(Vec3::new(0.058, 0.05, 0.0), 0.0).unwrap();
        assert!((h.distance - 1e-3).abs() < 1e-12, "{}", h.distance);
        let (e, te) = c.centreline(c.centreline_length());
        assert!((e - Vec3::new(0.0, 0.1, 0.0)).norm() < 1e-12, "{e}");
        assert!((te + Vec3::x()).norm() < 1e-12);
        assert!(CurvedTube::new(&CurvedTubeShape {
            radius: 0.06,
            ..CurvedTubeShape {
                start: Vec3::zeros(),
                tangent: Vec3::x(),
                toward: Vec3::y(),
                inlet: 0.0,
                bend_radius: 0.05,
                angle: 1.0,
                outlet: 0.0,
                radius: 0.0,
            }
        })
        .is_err());
    }

    /// Arcs beyond π: every point at ρ from the arc's centreline is at
    /// radius − ρ from the wall (atan2's negative angles were clamped to
    /// the arc's start: up to 70 mm off at 1.5π).
    #[test]
    fn a_curved_tube_beyond_half_a_turn_measures_its_wall() {
        let (r, bend) = (3e-3, 0.05);
        for angle in [0.5, 1.0, 1.2, 1.5, 1.75].map(|f| f * std::f64::consts::PI) {
            let c = CurvedTube::new(&CurvedTubeShape {
                start: Vec3::new(0.01, -0.02, 0.003),
                tangent: Vec3::new(1.0, 0.2, 0.0),
                toward: Vec3::new(0.0, 1.0, 0.3),
                inlet: 0.02,
                bend_radius: bend,
                angle,
                outlet: 0.02,
                radius: r,
            })
            .unwrap();
            let mut worst: f64 = 0.0;
            for k in 0..=200 {
                let s = 0.02 + bend * (0.05 + (angle - 0.1) * k as f64 / 200.0);
                let (p, t) = c.centreline(s);
                let u = perpendicular(t);
                let v = t.cross(&u);
                for (j, rho) in [0.0, 0.5 * r, 0.9 * r].into_iter().enumerate() {
                    let a = 0.7 * k as f64 + 2.1 * j as f64;
                    let q = p + (u * a.cos() + v * a.sin()) * rho;
                    let h = c.probe(q, 1.0).unwrap();
                    worst = worst.max((h.distance - (r - rho)).abs());
                }
            }
            assert!(worst < 1e-9, "angle {angle}: wall distance off by {worst} m");
        }
    }

    /// An open tube has two openings, at its ends, their axes out of it
    /// and their radius the ring's; a flat sheet's border is none.
    #[test]
    fn an_open_tube_has_two_openings_and_a_sheet_none() {
        let (v, t) = tube_wall(0.01, 0.05, 4e-3, 16, 10, 0.0);
        let l = TriangleLumen::new(&v, &t).unwrap();
        let mut o: Vec<&Opening> = l.openings().iter().collect();
        o.sort_by(|a, b| a.centre.x.total_cmp(&b.centre.x));
        assert_eq!(o.len(), 2, "{o:?}");
        assert!((o[0].centre - Vec3::new(0.01, 0.0, 0.0)).norm() < 1e-12);
        assert!((o[0].axis + Vec3::x()).norm() < 1e-12, "{:?}", o[0].axis);
        assert!((o[1].centre - Vec3::new(0.06, 0.0, 0.0)).norm() < 1e-12);
        assert!((o[1].axis - Vec3::x()).norm() < 1e-12);
        assert!((o[1].radius - 4e-3).abs() < 1e-12);
        assert_eq!(o[1].ring().len(), 16);
        // Beyond the far end, on the axis: the ring's apothem from the
        // continued wall, and 2 mm beyond a ring vertex radially: beyond
        // the wall, pushed back in.
        let h = l.probe(Vec3::new(0.08, 0.0, 0.0), 1.0).unwrap();
        let apothem = 4e-3 * (std::f64::consts::PI / 16.0).cos();
        assert!((h.distance - apothem).abs() < 1e-12, "{h:?}");
        let h = l.probe(Vec3::new(0.08, 0.0, 6e-3), 1.0).unwrap();
        assert!((h.distance + 2e-3).abs() < 1e-12 && h.normal.z < -0.99, "{h:?}");
        // On the axis beyond the end, nothing within 1 mm.
        assert!(l.probe(Vec3::new(0.08, 0.0, 0.0), 1e-3).is_none());
        assert!(sheet(0.0).openings().is_empty());
    }

    /// An opening's quick answer deep inside its loop (no edge within the
    /// range) is the edge loop's, for points all over the disk of twice
    /// its radius beyond its plane and ranges from 0.1 to 4 mm; and the
    /// disk it trusts lies inside the loop (the apothem of the ring).
    #[test]
    fn an_openings_quick_answer_is_the_edge_loops() {
        let (v, t) = tube_wall(0.01, 0.05, 4e-3, 16, 10, 0.0);
        let l = TriangleLumen::new(&v, &t).unwrap();
        let apothem = 4e-3 * (std::f64::consts::PI / 16.0).cos();
        let mut quick = 0;
        for o in l.openings() {
            assert!((o.inner - apothem).abs() < 1e-12, "{} vs {apothem}", o.inner);
            let slow = Opening {
                inner: 0.0,
                ..o.clone()
            };
            for k in 0..4000 {
                let a = k as f64 * 2.399963;
                let rad = 8e-3 * ((k % 97) as f64 / 97.0).sqrt();
                let p =
                    o.centre + o.axis * (1e-3 + (k % 7) as f64 * 1e-3) + o.u * (rad * a.cos()) + o.v * (rad * a.sin());
                let range = 1e-4 * (1 + k % 40) as f64;
                assert_eq!(o.probe(p, range), slow.probe(p, range), "{p:?} {range}");
                quick += (o.inner - (p - o.centre - o.axis * (p - o.centre).dot(&o.axis)).norm() > range) as usize;
            }
        }
        assert!(quick > 500, "{quick} quick answers");
    }

    /// A flat square of 4 × 4 cells on z = 0, each cut into two triangles
    /// wound toward +z (the lumen's side), its centre vertex raised by
    /// `bump` (a pit for negative: its cells then meet in valleys).
    fn sheet(bump: f64) -> TriangleLumen {
        let mut v = Vec::new();
        for j in 0..5 {
            for i in 0..5 {
                let z = if (i, j) == (2, 2) { bump } else { 0.0 };
                v.push(Vec3::new(i as f64 * 1e-3, j as f64 * 1e-3, z));
            }
        }
        let mut t = Vec::new();
        for j in 0..4u32 {
            for i in 0..4u32 {
                let a = j * 5 + i;
                t.push([a, a + 1, a + 6]);
                t.push([a, a + 6, a + 5]);
            }
        }
        TriangleLumen::new(&v, &t).unwrap()
    }

    /// Σ weight · (radius − distance)² over the overlaps of the sphere at p.
    fn overlap_sum(l: &TriangleLumen, p: Vec3, radius: f64) -> (f64, usize) {
        let mut cache = ProbeCache::default();
        let hit = l.probe_cached(p, 3.0 * radius, &mut cache).unwrap();
        let mut o = WallOverlaps::new();
        l.overlaps_cached(p, radius, &hit, &mut cache, &mut o);
        (
            o.iter().map(|o| o.weight * (radius - o.distance).powi(2)).sum(),
            o.len(),
        )
    }

    #[test]
    fn overlaps_count_a_flat_wall_once_and_both_sides_of_a_valley() {
        let flat = sheet(0.0);
        let r = 0.45e-3;
        // Over a face, a diagonal, an edge between cells and a vertex where
        // six triangles meet: one penalty, that of the plane.
        for (x, y) in [
            (1.3e-3, 1.6e-3),
            (1.5e-3, 1.5e-3),
            (2.0e-3, 1.4e-3),
            (2.0e-3, 2.0e-3),
            (2.05e-3, 1.97e-3),
        ] {
            let h = 0.4e-3;
            let (sum, pieces) = overlap_sum(&flat, Vec3::new(x, y, h), r);
            assert!(
                (sum - (r - h).powi(2)).abs() < 1e-12 * r * r,
                "at ({x}, {y}): {sum:e} over {pieces} pieces, the plane's {:e}",
                (r - h).powi(2)
            );
        }
        // Above the vertex the sum ran over its whole fan.
        assert!(overlap_sum(&flat, Vec3::new(2.0e-3, 2.0e-3, 0.4e-3), r).1 >= 7);
        // A pit 0.3 mm deep: over its centre the sphere touches the six
        // sloping faces around it (and their edges and the vertex: seven
        // pieces of positive weight). The nearest face alone pushes it
        // sideways (so a sphere pressed into the pit has no equilibrium);
        // the overlaps' sum pushes it straight out, harder.
        let pit = sheet(-0.3e-3);
        let p = Vec3::new(2.0e-3, 2.0e-3, 0.05e-3);
        let mut cache = ProbeCache::default();
        let nearest = pit.probe_cached(p, 3.0 * r, &mut cache).unwrap();
        let mut o = WallOverlaps::new();
        pit.overlaps_cached(p, r, &nearest, &mut cache, &mut o);
        let f: Vec3 = o.iter().map(|o| o.normal * (o.weight * (r - o.distance))).sum();
        let f1 = nearest.normal * (r - nearest.distance);
        assert!(o.iter().filter(|o| o.weight > 0.0).count() == 7, "{o:?}");
        assert!(f1.xy().norm() > 0.2 * f1.norm(), "the nearest face's push {f1:?}");
        assert!(f.xy().norm() < 1e-9 * f.norm(), "the overlaps' push {f:?}");
        assert!(f.z > f1.z, "{} against {}", f.z, f1.z);
    }
}
