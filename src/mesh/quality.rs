//! Element quality metrics: dihedral angles and aspect ratio.
//!
//! The aspect ratio is the longest edge over 2√6 times the inradius, which is
//! 1 for a regular tet and grows without bound as a tet flattens.

use super::{TetMesh, TET_EDGE_LOCAL};
use crate::math::Vec3;

/// Quality summary of a mesh.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MeshQuality {
    /// Smallest dihedral angle over all tets (degrees).
    pub min_dihedral_deg: f64,
    /// Largest dihedral angle over all tets (degrees).
    pub max_dihedral_deg: f64,
    /// Largest aspect ratio (1 = regular tet).
    pub max_aspect_ratio: f64,
    /// Mean aspect ratio.
    pub mean_aspect_ratio: f64,
    /// Shortest edge (m).
    pub min_edge_m: f64,
    /// Longest edge (m).
    pub max_edge_m: f64,
}

/// The six dihedral angles (radians) of a tet, one per edge.
pub fn dihedral_angles(x: &[Vec3; 4]) -> [f64; 6] {
    let mut out = [0.0; 6];
    for (k, [i, j]) in TET_EDGE_LOCAL.iter().enumerate() {
        // The two other vertices; the angle is between the planes (i,j,o1) and (i,j,o2).
        let others: Vec<usize> = (0..4).filter(|v| v != i && v != j).collect();
        let e = (x[*j] - x[*i]).normalize();
        let proj = |v: Vec3| v - e * v.dot(&e);
        let a = proj(x[others[0]] - x[*i]);
        let b = proj(x[others[1]] - x[*i]);
        let c = (a.dot(&b) / (a.norm() * b.norm())).clamp(-1.0, 1.0);
        out[k] = c.acos();
    }
    out
}

/// Aspect ratio of a tet: longest edge / (2√6 · inradius).
pub fn aspect_ratio(x: &[Vec3; 4]) -> f64 {
    let vol = super::signed_volume(&x[0], &x[1], &x[2], &x[3]).abs();
    let area: f64 = super::TET_FACE_LOCAL
        .iter()
        .map(|f| 0.5 * (x[f[1]] - x[f[0]]).cross(&(x[f[2]] - x[f[0]])).norm())
        .sum();
    let lmax = TET_EDGE_LOCAL
        .iter()
        .map(|[i, j]| (x[*j] - x[*i]).norm())
        .fold(0.0, f64::max);
    if vol <= 0.0 {
        return f64::INFINITY;
    }
    let r_in = 3.0 * vol / area;
    lmax / (2.0 * 6f64.sqrt() * r_in)
}

impl MeshQuality {
    /// Computes the quality summary of a mesh.
    pub fn of(mesh: &TetMesh) -> MeshQuality {
        let mut q = MeshQuality {
            min_dihedral_deg: f64::INFINITY,
            max_dihedral_deg: 0.0,
            max_aspect_ratio: 0.0,
            mean_aspect_ratio: 0.0,
            min_edge_m: f64::INFINITY,
            max_edge_m: 0.0,
        };
        for tet in mesh.tets() {
            let x = tet.map(|i| mesh.rest()[i as usize]);
            for a in dihedral_angles(&x) {
                q.min_dihedral_deg = q.min_dihedral_deg.min(a.to_degrees());
                q.max_dihedral_deg = q.max_dihedral_deg.max(a.to_degrees());
            }
            let ar = aspect_ratio(&x);
            q.max_aspect_ratio = q.max_aspect_ratio.max(ar);
            q.mean_aspect_ratio += ar;
        }
        q.mean_aspect_ratio /= mesh.tets().len() as f64;
        for [a, b] in mesh.edges() {
            let l = (mesh.rest()[*b as usize] - mesh.rest()[*a as usize]).norm();
            q.min_edge_m = q.min_edge_m.min(l);
            q.max_edge_m = q.max_edge_m.max(l);
        }
        q
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regular_tet_metrics() {
        let x = [
            Vec3::new(1.0, 1.0, 1.0),
            Vec3::new(1.0, -1.0, -1.0),
            Vec3::new(-1.0, 1.0, -1.0),
            Vec3::new(-1.0, -1.0, 1.0),
        ];
        assert!((aspect_ratio(&x) - 1.0).abs() < 1e-12);
        for a in dihedral_angles(&x) {
            assert!((a.to_degrees() - 70.528_779_365_509_31).abs() < 1e-9);
        }
    }

    #[test]
    fn corner_tet_dihedrals() {
        let x = [Vec3::zeros(), Vec3::x(), Vec3::y(), Vec3::z()];
        let mut d: Vec<f64> = dihedral_angles(&x).iter().map(|a| a.to_degrees()).collect();
        d.sort_by(f64::total_cmp);
        // Three right angles at the corner edges, three of acos(1/√3) ≈ 54.74°.
        for a in &d[..3] {
            assert!((a - 54.735_610_317_245_35).abs() < 1e-9);
        }
        for a in &d[3..] {
            assert!((a - 90.0).abs() < 1e-9);
        }
    }
}
