//! Self-intersection of a triangle surface: a uniform grid over the
//! triangles' bounding boxes finds candidate pairs, and exact orientation
//! predicates (Shewchuk, "Adaptive precision floating-point arithmetic and
//! fast robust geometric predicates", 1997, through the `robust` crate)
//! decide each pair, so the answer does not depend on rounding.
//!
//! Two triangles intersect when they share a point other than their common
//! vertex or edge: crossing, touching, or (coplanar) overlapping. Pairs that
//! share an edge intersect only when folded onto each other (coplanar, on the
//! same side of the edge); pairs that share a vertex when the edge opposite
//! it in one meets the other, or when coplanar with overlapping corners.

use super::FastMap;
use crate::math::Vec3;
use robust::{orient2d, orient3d, Coord, Coord3D};

fn c3(p: &Vec3) -> Coord3D<f64> {
    Coord3D { x: p.x, y: p.y, z: p.z }
}

/// Sign of orient3d(a, b, c, d): which side of the plane abc d lies on.
fn o3(a: &Vec3, b: &Vec3, c: &Vec3, d: &Vec3) -> i8 {
    sign(orient3d(c3(a), c3(b), c3(c), c3(d)))
}

fn sign(x: f64) -> i8 {
    if x > 0.0 {
        1
    } else if x < 0.0 {
        -1
    } else {
        0
    }
}

/// A 2-D projection dropping the axis the plane abc faces most.
#[derive(Clone, Copy)]
struct Proj(usize);

impl Proj {
    fn of(a: &Vec3, b: &Vec3, c: &Vec3) -> Proj {
        let n = (b - a).cross(&(c - a)).abs();
        Proj(if n.x >= n.y && n.x >= n.z {
            0
        } else if n.y >= n.z {
            1
        } else {
            2
        })
    }
    fn p(self, v: &Vec3) -> Coord<f64> {
        let (i, j) = [(1, 2), (2, 0), (0, 1)][self.0];
        Coord { x: v[i], y: v[j] }
    }
    fn o2(self, a: &Vec3, b: &Vec3, c: &Vec3) -> i8 {
        sign(orient2d(self.p(a), self.p(b), self.p(c)))
    }
    /// Whether p, known collinear with a and b, lies on the closed segment ab.
    fn on_segment(self, a: &Vec3, b: &Vec3, p: &Vec3) -> bool {
        let (a, b, p) = (self.p(a), self.p(b), self.p(p));
        p.x >= a.x.min(b.x) && p.x <= a.x.max(b.x) && p.y >= a.y.min(b.y) && p.y <= a.y.max(b.y)
    }
    /// Closed segments ab and cd meet.
    fn seg_seg(self, a: &Vec3, b: &Vec3, c: &Vec3, d: &Vec3) -> bool {
        let (d1, d2) = (self.o2(c, d, a), self.o2(c, d, b));
        let (d3, d4) = (self.o2(a, b, c), self.o2(a, b, d));
        if d1 * d2 < 0 && d3 * d4 < 0 {
            return true;
        }
        (d1 == 0 && self.on_segment(c, d, a))
            || (d2 == 0 && self.on_segment(c, d, b))
            || (d3 == 0 && self.on_segment(a, b, c))
            || (d4 == 0 && self.on_segment(a, b, d))
    }
    /// p lies in the closed triangle t.
    fn in_tri(self, t: &[Vec3; 3], p: &Vec3) -> bool {
        let s = [
            self.o2(&t[0], &t[1], p),
            self.o2(&t[1], &t[2], p),
            self.o2(&t[2], &t[0], p),
        ];
        !(s.contains(&1) && s.contains(&-1))
    }
    /// Closed segment ab meets the closed triangle t (all coplanar).
    fn seg_tri(self, a: &Vec3, b: &Vec3, t: &[Vec3; 3]) -> bool {
        self.in_tri(t, a) || (0..3).any(|k| self.seg_seg(a, b, &t[k], &t[(k + 1) % 3]))
    }
    /// Closed coplanar triangles meet.
    fn tri_tri(self, p: &[Vec3; 3], q: &[Vec3; 3]) -> bool {
        self.in_tri(q, &p[0])
            || self.in_tri(p, &q[0])
            || (0..3).any(|i| (0..3).any(|j| self.seg_seg(&p[i], &p[(i + 1) % 3], &q[j], &q[(j + 1) % 3])))
    }
}

/// The closed segment ab meets the closed triangle t.
fn seg_tri(a: &Vec3, b: &Vec3, t: &[Vec3; 3]) -> bool {
    let (sa, sb) = (o3(&t[0], &t[1], &t[2], a), o3(&t[0], &t[1], &t[2], b));
    if sa == sb && sa != 0 {
        return false;
    }
    if sa == 0 && sb == 0 {
        return Proj::of(&t[0], &t[1], &t[2]).seg_tri(a, b, t);
    }
    // The line ab passes through t when it turns the same way around all
    // three edges (Plücker signs), zeros allowed.
    let e = [o3(a, b, &t[0], &t[1]), o3(a, b, &t[1], &t[2]), o3(a, b, &t[2], &t[0])];
    !(e.contains(&1) && e.contains(&-1))
}

/// Triangles with no vertex in common meet.
fn disjoint_pair(p: &[Vec3; 3], q: &[Vec3; 3]) -> bool {
    let dp = p.map(|v| o3(&q[0], &q[1], &q[2], &v));
    if dp.iter().all(|&s| s == dp[0]) && dp[0] != 0 {
        return false;
    }
    let dq = q.map(|v| o3(&p[0], &p[1], &p[2], &v));
    if dq.iter().all(|&s| s == dq[0]) && dq[0] != 0 {
        return false;
    }
    if dp.iter().all(|&s| s == 0) {
        return Proj::of(&q[0], &q[1], &q[2]).tri_tri(p, q);
    }
    (0..3).any(|k| seg_tri(&p[k], &p[(k + 1) % 3], q)) || (0..3).any(|k| seg_tri(&q[k], &q[(k + 1) % 3], p))
}

/// Triangles (v, a1, a2) and (v, b1, b2) sharing the vertex v meet elsewhere.
fn vertex_pair(v: &Vec3, a: [&Vec3; 2], b: [&Vec3; 2]) -> bool {
    let p = [*v, *a[0], *a[1]];
    let q = [*v, *b[0], *b[1]];
    let coplanar = o3(v, b[0], b[1], a[0]) == 0 && o3(v, b[0], b[1], a[1]) == 0;
    if !coplanar {
        return seg_tri(b[0], b[1], &p) || seg_tri(a[0], a[1], &q);
    }
    // Coplanar: the triangles overlap exactly when their corners at v do.
    let pr = Proj::of(v, a[0], a[1]);
    let inside = |c: [&Vec3; 2], x: &Vec3| {
        let o = pr.o2(v, c[0], c[1]);
        o != 0 && pr.o2(v, c[0], x) == o && pr.o2(v, x, c[1]) == o
    };
    let same_ray = |x: &Vec3, y: &Vec3| pr.o2(v, x, y) == 0 && (x - v).dot(&(y - v)) > 0.0;
    inside(a, b[0])
        || inside(a, b[1])
        || inside(b, a[0])
        || inside(b, a[1])
        || (same_ray(a[0], b[0]) && same_ray(a[1], b[1]))
        || (same_ray(a[0], b[1]) && same_ray(a[1], b[0]))
}

/// Triangles (u, w, a) and (u, w, b) sharing the edge uw are folded onto
/// each other: coplanar with a and b on the same side of uw.
fn edge_pair(u: &Vec3, w: &Vec3, a: &Vec3, b: &Vec3) -> bool {
    if o3(u, w, a, b) != 0 {
        return false;
    }
    let pr = Proj::of(u, w, a);
    let (sa, sb) = (pr.o2(u, w, a), pr.o2(u, w, b));
    sa != 0 && sa == sb
}

/// Whether triangles `s` and `t` (vertex indices) meet other than where
/// they share vertices.
pub(super) fn triangles_meet(verts: &[Vec3], s: [u32; 3], t: [u32; 3]) -> bool {
    let p = |i: u32| &verts[i as usize];
    let mut shared = [(0usize, 0usize); 3];
    let mut count = 0;
    for (i, a) in s.iter().enumerate() {
        for (j, b) in t.iter().enumerate() {
            if a == b && count < 3 {
                shared[count] = (i, j);
                count += 1;
            }
        }
    }
    match count {
        0 => disjoint_pair(&s.map(|i| *p(i)), &t.map(|i| *p(i))),
        1 => {
            let (i, j) = shared[0];
            vertex_pair(
                p(s[i]),
                [p(s[(i + 1) % 3]), p(s[(i + 2) % 3])],
                [p(t[(j + 1) % 3]), p(t[(j + 2) % 3])],
            )
        }
        2 => {
            let (u, w) = (s[shared[0].0], s[shared[1].0]);
            let a = s.iter().find(|&&x| x != u && x != w);
            let b = t.iter().find(|&&x| x != u && x != w);
            match (a, b) {
                (Some(&a), Some(&b)) => edge_pair(p(u), p(w), p(a), p(b)),
                _ => false,
            }
        }
        _ => false,
    }
}

/// A triangle spanning more grid cells than this is tested against all others.
const MAX_CELLS: i64 = 4096;

/// The first intersecting pair (lowest first index, then second) and the
/// number of intersecting pairs, or `None`.
pub(super) fn first_intersection(verts: &[Vec3], tris: &[[u32; 3]]) -> Option<(usize, usize, usize)> {
    let n = tris.len();
    if n < 2 {
        return None;
    }
    let boxes: Vec<(Vec3, Vec3)> = tris
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| verts[i as usize]);
            (a.inf(&b).inf(&c), a.sup(&b).sup(&c))
        })
        .collect();
    let origin = boxes.iter().fold(Vec3::repeat(f64::INFINITY), |m, b| m.inf(&b.0));
    let mean_extent = boxes.iter().map(|(lo, hi)| (hi - lo).max()).sum::<f64>() / n as f64;
    let h = 2.0 * mean_extent;
    if !(h > 0.0 && h.is_finite()) {
        return None;
    }
    let cell = |p: &Vec3| -> [i64; 3] {
        let c = (p - origin) / h;
        [c.x.floor() as i64, c.y.floor() as i64, c.z.floor() as i64]
    };
    let overlap = |i: usize, j: usize| {
        let (a, b) = (&boxes[i], &boxes[j]);
        (0..3).all(|k| a.0[k] <= b.1[k] && b.0[k] <= a.1[k])
    };
    let mut grid: FastMap<[i64; 3], Vec<u32>> = FastMap::with_capacity_and_hasher(2 * n, Default::default());
    let mut big = Vec::new();
    let mut is_big = vec![false; n];
    for (t, (lo, hi)) in boxes.iter().enumerate() {
        let (a, b) = (cell(lo), cell(hi));
        let span = (0..3).fold(1i64, |s, k| s.saturating_mul(b[k] - a[k] + 1));
        if span > MAX_CELLS {
            big.push(t);
            is_big[t] = true;
            continue;
        }
        for x in a[0]..=b[0] {
            for y in a[1]..=b[1] {
                for z in a[2]..=b[2] {
                    grid.entry([x, y, z]).or_default().push(t as u32);
                }
            }
        }
    }
    let mut best: Option<(usize, usize)> = None;
    let mut pairs = 0usize;
    let mut found = |i: usize, j: usize| {
        let (i, j) = (i.min(j), i.max(j));
        pairs += 1;
        if best.is_none_or(|b| (i, j) < b) {
            best = Some((i, j));
        }
    };
    for (key, ids) in &grid {
        for (k, &i) in ids.iter().enumerate() {
            for &j in &ids[k + 1..] {
                let (i, j) = (i as usize, j as usize);
                if !overlap(i, j) {
                    continue;
                }
                // Test each pair once: in the cell holding the corner where
                // the two boxes' overlap begins.
                if cell(&boxes[i].0.sup(&boxes[j].0)) != *key {
                    continue;
                }
                if triangles_meet(verts, tris[i], tris[j]) {
                    found(i, j);
                }
            }
        }
    }
    for &b in &big {
        for t in 0..n {
            if t == b || (is_big[t] && t < b) || !overlap(b, t) {
                continue;
            }
            if triangles_meet(verts, tris[b], tris[t]) {
                found(b, t);
            }
        }
    }
    best.map(|(i, j)| (i, j, pairs))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f64, y: f64, z: f64) -> Vec3 {
        Vec3::new(x, y, z)
    }

    #[test]
    fn crossing_touching_and_apart() {
        let verts = vec![
            v(0.0, 0.0, 0.0),
            v(1.0, 0.0, 0.0),
            v(0.0, 1.0, 0.0),
            // A triangle piercing the first.
            v(0.2, 0.2, -1.0),
            v(0.2, 0.2, 1.0),
            v(0.3, 0.5, 1.0),
            // One above it.
            v(0.2, 0.2, 0.5),
            v(0.4, 0.2, 0.5),
            v(0.2, 0.4, 0.6),
        ];
        assert!(triangles_meet(&verts, [0, 1, 2], [3, 4, 5]));
        assert!(!triangles_meet(&verts, [0, 1, 2], [6, 7, 8]));
        // Sharing vertex 0, the second turned up out of the plane: apart.
        let mut w = verts.clone();
        w.push(v(-1.0, 0.0, 0.5));
        w.push(v(0.0, -1.0, 0.5));
        assert!(!triangles_meet(&w, [0, 1, 2], [0, 9, 10]));
        // Sharing vertex 0 with the opposite edge through the first: meet.
        w.push(v(0.3, 0.3, -1.0));
        w.push(v(0.3, 0.3, 1.0));
        assert!(triangles_meet(&w, [0, 1, 2], [0, 11, 12]));
        // Sharing edge 0-1: apart when bent, folded when coplanar on one side.
        w.push(v(0.5, 0.5, 0.5));
        w.push(v(0.5, 0.3, 0.0));
        assert!(!triangles_meet(&w, [0, 1, 2], [1, 0, 13]));
        assert!(triangles_meet(&w, [0, 1, 2], [1, 0, 14]));
        // Coplanar, sharing vertex 0, corners overlapping.
        w.push(v(1.0, 0.5, 0.0));
        w.push(v(0.5, 1.0, 0.0));
        assert!(triangles_meet(&w, [0, 1, 2], [0, 15, 16]));
        assert!(!triangles_meet(&w, [0, 1, 15], [0, 16, 2]));
    }
}
