//! A straight circular tube wall meshed with conforming P1 tets: the
//! benchmark geometry of pressurized-vessel checks (Lamé's thick-walled
//! cylinder, the thin-wall compliance r²/(E h)).
//!
//! The axis is z, from z = 0 to z = length. The grid is the built-in arch's
//! (rings along the axis, nodes around, node layers through the wall, Kuhn
//! subdivision; see [`super::arch`]), so the tube and the arch share their
//! element shapes. Node sets: `end_0` (ring at z = 0, all layers), `end_1`
//! (ring at z = length), `inner_wall` (lumen surface), `outer_wall`.

use super::arch::{kuhn_wall_tets, wall_node_sets, ArchError, ArchGrid};
use super::TetMesh;
use crate::math::Vec3;

/// Geometry of a straight tube (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TubeParams {
    /// Inner (lumen) radius (m).
    pub inner_radius: f64,
    /// Outer radius (m), > `inner_radius`.
    pub outer_radius: f64,
    /// Length along z (m).
    pub length: f64,
}

/// Generates the tube on `grid` (rings along z, nodes around, layers
/// through the wall). Node (ring a, angle c, layer l) is at angle 2πc/nc and
/// radius a + (b − a) l/(layers − 1), so layer 0 is exactly on the inner
/// circle's polygon and the last layer on the outer one.
pub fn generate(params: &TubeParams, grid: ArchGrid) -> Result<TetMesh, ArchError> {
    if grid.axial < 2 || grid.circumferential < 3 || grid.layers < 2 {
        return Err(ArchError::BadGrid(format!(
            "need axial >= 2, circumferential >= 3, layers >= 2; got {grid:?}"
        )));
    }
    let TubeParams {
        inner_radius: a,
        outer_radius: b,
        length,
    } = *params;
    if !(a > 0.0 && b > a && length > 0.0 && b.is_finite() && length.is_finite()) {
        return Err(ArchError::BadGrid(format!(
            "need 0 < inner_radius < outer_radius and length > 0; got {params:?}"
        )));
    }
    let mut rest = Vec::with_capacity(grid.nodes());
    for ring in 0..grid.axial {
        let z = length * ring as f64 / (grid.axial - 1) as f64;
        for c in 0..grid.circumferential {
            let th = 2.0 * std::f64::consts::PI * c as f64 / grid.circumferential as f64;
            for l in 0..grid.layers {
                let r = a + (b - a) * l as f64 / (grid.layers - 1) as f64;
                rest.push(Vec3::new(r * th.cos(), r * th.sin(), z));
            }
        }
    }
    let tets = kuhn_wall_tets(&grid, &rest);
    let sets = wall_node_sets(&grid, "end_0", "end_1");
    Ok(TetMesh::new(rest, tets, sets)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tube_volume_and_sets() {
        let p = TubeParams {
            inner_radius: 0.01,
            outer_radius: 0.012,
            length: 0.02,
        };
        let grid = ArchGrid {
            axial: 3,
            circumferential: 64,
            layers: 3,
        };
        let mesh = generate(&p, grid).unwrap();
        assert_eq!(mesh.num_nodes(), grid.nodes());
        assert_eq!(mesh.tets().len(), grid.tets());
        // A polygonal annulus: area (n/2) sin(2π/n) (b² − a²).
        let n = 64.0;
        let exact = 0.5 * n * (2.0 * std::f64::consts::PI / n).sin() * (0.012f64.powi(2) - 0.01f64.powi(2)) * 0.02;
        assert!((mesh.total_volume() - exact).abs() < 1e-9 * exact.max(1e-12) + 1e-15);
        for set in ["end_0", "end_1", "inner_wall", "outer_wall"] {
            assert!(mesh.node_set(set).is_some_and(|s| !s.is_empty()), "{set}");
        }
        assert!(generate(
            &TubeParams {
                outer_radius: 0.009,
                ..p
            },
            grid
        )
        .is_err());
    }
}
