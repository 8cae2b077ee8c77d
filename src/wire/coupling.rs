//! The wire against the vessel mesh: the inner wall of a tet mesh (a node
//! set, `inner_wall` on the built-in arches) as the wire's lumen, the
//! segment label of the wall nearest the tip, and the wire's contact forces
//! spread back onto the wall's nodes as point loads (barycentric on the
//! touched triangle).
//!
//! Plain data and functions; the service's wire thread
//! (`service::instrument::guidewire`) strings them together. [`wall_loads`] allocates nothing.

use super::lumen::{LumenError, TriangleLumen};
use super::rod::WireContact;
use crate::math::Vec3;
use crate::mesh::TetMesh;
use crate::reduced::compliance::LocalCompliance;
use crate::reduced::ReducedDynamics;
use nalgebra::{SMatrix, SVector};

/// Most wall point loads one wire step hands to the vessel (3 per contact
/// node, merged where triangles share a vertex).
pub const MAX_WALL_LOADS: usize = 128;

/// Why the inner wall could not be taken from a mesh.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CouplingError {
    /// The mesh has no node set of that name.
    #[error(
        "the mesh has no node set {0:?} (the inner wall; the built-in and generated arches name it \"inner_wall\")"
    )]
    NoSet(String),
    /// No boundary triangle has all three nodes in the set.
    #[error("no boundary triangle lies on node set {0:?}")]
    NoTriangles(String),
    /// No opening of the inner wall has its ring in the node set.
    #[error("node set {0:?} holds no opening of the inner wall (it has {1} openings: name the node set of one, e.g. \"outlet_descending\" or \"opening_1\")")]
    NoOpening(String, usize),
    /// The triangles do not make a lumen.
    #[error(transparent)]
    Lumen(#[from] LumenError),
}

/// The inner wall of a vessel mesh, as the wire sees it: the boundary
/// triangles whose three nodes are in the inner-wall set, renumbered to
/// their own vertices. The mesh's boundary triangles face out of the wall's
/// material, which on the inner wall is into the lumen: the winding
/// [`TriangleLumen`] wants.
#[derive(Debug, Clone)]
pub struct InnerWall {
    nodes: Vec<u32>,
    triangles: Vec<[u32; 3]>,
    rest: Vec<Vec3>,
    labels: Vec<u8>,
    names: Vec<String>,
}

impl InnerWall {
    /// The inner wall of `mesh`: its boundary triangles on node set `set`.
    pub fn from_mesh(mesh: &TetMesh, set: &str) -> Result<InnerWall, CouplingError> {
        let ids = mesh
            .node_set(set)
            .ok_or_else(|| CouplingError::NoSet(set.to_string()))?;
        let mut local = vec![u32::MAX; mesh.num_nodes()];
        for &i in ids {
            if let Some(l) = local.get_mut(i as usize) {
                *l = 0;
            }
        }
        let mut nodes = Vec::new();
        let mut triangles = Vec::new();
        for t in mesh.surface() {
            if t.iter().any(|&i| local[i as usize] == u32::MAX) {
                continue;
            }
            let tri = t.map(|i| {
                let l = &mut local[i as usize];
                if *l == 0 {
                    nodes.push(i);
                    *l = nodes.len() as u32;
                }
                *l - 1
            });
            triangles.push(tri);
        }
        if triangles.is_empty() {
            return Err(CouplingError::NoTriangles(set.to_string()));
        }
        let rest: Vec<Vec3> = nodes.iter().map(|&i| mesh.rest()[i as usize]).collect();
        let (names, labels) = match mesh.segment_labels() {
            Some((names, label)) => (names, nodes.iter().map(|&i| label[i as usize]).collect()),
            None => (Vec::new(), vec![u8::MAX; nodes.len()]),
        };
        Ok(InnerWall {
            nodes,
            triangles,
            rest,
            labels,
            names,
        })
    }

    /// The mesh node of each wall vertex.
    pub fn mesh_nodes(&self) -> &[u32] {
        &self.nodes
    }

    /// The triangles (indices into the wall's vertices), facing the lumen.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// Rest positions of the wall vertices (m).
    pub fn rest(&self) -> &[Vec3] {
        &self.rest
    }

    /// Unit normal of each wall vertex at rest, into the lumen: the
    /// area-weighted mean of its triangles' normals.
    pub fn vertex_normals(&self) -> Vec<Vec3> {
        crate::math::vertex_normals(&self.rest, &self.triangles)
    }

    /// The wall's normal compliance at each vertex (m/N): how far the
    /// vessel model lets the vertex go per newton pushed along its normal,
    /// n_aᵀ (Φ_a K_r⁻¹ Φ_aᵀ + ΔW_aa) n_a — the reduced model's static
    /// response (K_r of `dynamics`, its active block) plus, when the model
    /// has one, the residual compliance of contact anywhere (`residual`),
    /// which together are the full model's static compliance at the node
    /// (docs/REDUCED.md). The wire puts it in series with its contact
    /// penalty ([`TriangleLumen::set_compliance`]). Zero at vertices the
    /// basis does not move; None if K_r is not positive definite.
    pub fn normal_compliance<const R: usize>(
        &self,
        dynamics: &ReducedDynamics<R>,
        residual: Option<&LocalCompliance>,
    ) -> Option<Vec<f64>> {
        let r = dynamics.active();
        let mut k: SMatrix<f64, R, R> = *dynamics.stiffness();
        for i in r..R {
            k[(i, i)] = 1.0;
        }
        let chol = k.cholesky()?;
        let normals = self.vertex_normals();
        let mut out = Vec::with_capacity(self.nodes.len());
        for (&node, n) in self.nodes.iter().zip(&normals) {
            let reduced = match dynamics.rows_at(node) {
                Some(rows) => {
                    let mut g: SVector<f64, R> = rows.tr_mul(n);
                    for v in g.iter_mut().skip(r) {
                        *v = 0.0;
                    }
                    let q = chol.solve(&g);
                    g.dot(&q)
                }
                None => 0.0,
            };
            let res = residual
                .and_then(|c| c.block(node, node))
                .map(|b| n.dot(&(b * n)))
                .unwrap_or(0.0);
            let c = reduced + res;
            out.push(if c.is_finite() && c > 0.0 { c } else { 0.0 });
        }
        Some(out)
    }

    /// The wall at rest as a lumen for the wire.
    pub fn lumen(&self) -> Result<TriangleLumen, LumenError> {
        TriangleLumen::new(&self.rest, &self.triangles)
    }

    /// Access through an opening, by the name of a mesh node set holding
    /// its ring (`outlet_descending` on the built-in arches, `opening_<k>`
    /// on a generated mesh): the hub `depth_m` beyond the opening's plane
    /// on its axis, in the opening's continuation ([`TriangleLumen`]
    /// continues every opening by a straight rigid tube), and the insertion
    /// axis into the vessel. `lumen` is this wall's ([`InnerWall::lumen`]).
    /// The opening chosen is the one with the most ring vertices in the set.
    pub fn access_through(
        &self,
        mesh: &TetMesh,
        lumen: &TriangleLumen,
        set: &str,
        depth_m: f64,
    ) -> Result<(Vec3, Vec3), CouplingError> {
        let ids = mesh
            .node_set(set)
            .ok_or_else(|| CouplingError::NoSet(set.to_string()))?;
        let in_set: std::collections::HashSet<u32> = ids.iter().copied().collect();
        let best = lumen
            .openings()
            .iter()
            .map(|o| {
                let k = o
                    .ring()
                    .iter()
                    .filter(|&&v| in_set.contains(&self.nodes[v as usize]))
                    .count();
                (k, o)
            })
            .max_by_key(|(k, _)| *k);
        match best {
            Some((k, o)) if k > 0 => Ok((o.centre + o.axis * depth_m, -o.axis)),
            _ => Err(CouplingError::NoOpening(set.to_string(), lumen.openings().len())),
        }
    }

    /// The segment (`aorta`, `left_subclavian`, …) of the wall vertex
    /// nearest `p`, with the wall at `positions` (one per wall vertex);
    /// None if the mesh has no segment labels. Brute force: for reports,
    /// not for the RT path.
    pub fn segment_at(&self, positions: &[Vec3], p: Vec3) -> Option<&str> {
        let v = positions
            .iter()
            .enumerate()
            .min_by(|a, b| (a.1 - p).norm_squared().total_cmp(&(b.1 - p).norm_squared()))?
            .0;
        self.labels
            .get(v)
            .and_then(|&l| self.names.get(l as usize))
            .map(|s| s.as_str())
    }
}

/// A point load on a wall node: the mesh node and the force on it (N).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallLoad {
    /// Mesh node.
    pub node: u32,
    /// Force on the tissue (N).
    pub force: Vec3,
}

/// The wire's contact forces on the wall as point loads on `wall`'s mesh
/// nodes: each contact's reaction −(normal force + friction) spread over the
/// vertices of the triangle it touches by the barycentric weights of the
/// wall point, merged per node, into `out` (cleared first). Returns how many
/// contacts did not fit (their force is dropped). Allocates nothing.
pub fn wall_loads(
    wall: &InnerWall,
    lumen: &TriangleLumen,
    contacts: &[WireContact],
    out: &mut heapless::Vec<WallLoad, MAX_WALL_LOADS>,
) -> usize {
    out.clear();
    let mut dropped = 0;
    for c in contacts {
        let f = -(c.normal * c.normal_force + c.friction);
        if !f.iter().all(|v| v.is_finite()) {
            dropped += 1;
            continue;
        }
        // The triangle the step found (the lumen has not moved since);
        // a contact from elsewhere is probed again.
        let t = if (c.triangle as usize) < lumen.triangles().len() {
            c.triangle as usize
        } else {
            match lumen.probe_triangle(c.point, 1e-3) {
                Some((_, t)) => t,
                None => {
                    dropped += 1;
                    continue;
                }
            }
        };
        let w = lumen.barycentric(t, c.point);
        let tri = lumen.triangles()[t];
        let mut fits = true;
        for k in 0..3 {
            let node = wall.nodes[tri[k] as usize];
            match out.iter_mut().find(|l| l.node == node) {
                Some(l) => l.force += f * w[k],
                None => {
                    if out.push(WallLoad { node, force: f * w[k] }).is_err() {
                        fits = false;
                    }
                }
            }
        }
        if !fits {
            dropped += 1;
        }
    }
    dropped
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn contact_force_spreads_barycentrically_and_sums() {
        let v = [Vec3::zeros(), Vec3::new(1e-3, 0.0, 0.0), Vec3::new(0.0, 1e-3, 0.0)];
        let t = [[0u32, 1, 2]];
        let wall = InnerWall {
            nodes: vec![10, 11, 12],
            triangles: t.to_vec(),
            rest: v.to_vec(),
            labels: vec![0; 3],
            names: vec!["aorta".into()],
        };
        let lumen = wall.lumen().unwrap();
        let c = WireContact {
            node: 2,
            point: Vec3::new(0.25e-3, 0.25e-3, 0.0),
            normal: Vec3::z(),
            normal_force: 2.0,
            friction: Vec3::new(0.1, 0.0, 0.0),
            penetration: 1e-5,
            wall_deflection: 0.0,
            triangle: crate::wire::lumen::NO_TRIANGLE,
        };
        let mut out = heapless::Vec::new();
        assert_eq!(wall_loads(&wall, &lumen, &[c], &mut out), 0);
        let sum: Vec3 = out.iter().map(|l| l.force).sum();
        assert!((sum - Vec3::new(-0.1, 0.0, -2.0)).norm() < 1e-12, "{sum}");
        let f10 = out.iter().find(|l| l.node == 10).unwrap().force;
        assert!((f10.z + 1.0).abs() < 1e-12, "{f10}");
        assert_eq!(wall.segment_at(wall.rest(), Vec3::new(1e-3, 0.0, 0.0)), Some("aorta"));
        // With the triangle the step found: the same loads, no probe.
        let mut known = heapless::Vec::new();
        assert_eq!(
            wall_loads(&wall, &lumen, &[WireContact { triangle: 0, ..c }], &mut known),
            0
        );
        assert_eq!(known, out);
    }
}
