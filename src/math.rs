//! The two small fixed-size types every module shares: [`Vec3`] (positions,
//! displacements, forces, in SI units) and [`Mat3`] (3×3 tensors and tangent
//! blocks). Kept apart from `mesh` and `model` so that neither has to import
//! the other for a type alias.

use nalgebra::{Matrix3, Vector3};

/// A 3-vector of f64 (positions, displacements, forces: SI units).
pub type Vec3 = Vector3<f64>;

/// A 3×3 f64 matrix (tensors, tangent blocks).
pub type Mat3 = Matrix3<f64>;

/// The largest distance between matching points of `a` and `b` (m; 0 for
/// empty slices; extra points of the longer one are ignored): how far a
/// point set moved between two states. Allocates nothing.
pub fn max_distance(a: &[Vec3], b: &[Vec3]) -> f64 {
    a.iter().zip(b).map(|(p, q)| (p - q).norm()).fold(0.0, f64::max)
}

/// Area-weighted unit normal at each of `points` over `triangles` (indices
/// into `points`; a triangle's normal follows its winding), zero at points
/// no triangle uses.
pub fn vertex_normals(points: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let mut n = vec![Vec3::zeros(); points.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| points[i as usize]);
        let w = (b - a).cross(&(c - a));
        for &i in t {
            n[i as usize] += w;
        }
    }
    for v in &mut n {
        let l = v.norm();
        if l > 0.0 {
            *v /= l;
        }
    }
    n
}

/// Where on the segment a–b the point closest to `p` lies: t ∈ [0, 1] with
/// the point a + t (b − a); 0 for a degenerate segment.
pub fn segment_parameter(p: Vec3, a: Vec3, b: Vec3) -> f64 {
    let ab = b - a;
    let l2 = ab.norm_squared();
    if l2 > 0.0 {
        ((p - a).dot(&ab) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// The closest point to `p` on triangle (a, b, c) (Ericson, *Real-Time
/// Collision Detection*, 5.1.5).
pub fn closest_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}
