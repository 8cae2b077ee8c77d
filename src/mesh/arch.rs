//! The built-in procedural aortic arch: a vessel wall swept along an
//! anatomically plausible centreline, meshed with conforming P1 tets.
//!
//! Shape (after the defaults of the procedural aortic-arch generator of
//! Karstensen et al., IJCARS 2023, and adult imaging studies; docs/MODELS.md,
//! "The built-in arch", in mm): z points to the head, +x
//! to the patient's left, the ascending aorta is anterior (−y). The centreline
//! runs from the descending end (0, 0, 0), where the wire enters, up the
//! descending aorta (bowing to (18, 0) at z = 128), over a circular arch of
//! radius ≈ 33 mm whose top is at z ≈ 161, and down the ascending aorta at
//! (−5, −62) to its end at z = 90 (the aortic root): ≈ 270 mm in all. A spline
//! through the reference's four control points was tried first; it kinks at
//! the arch top (curvature radius ≈ 7 mm, less than the vessel's radius), so
//! the centreline here is analytic (C¹, curvature radius ≥ 33 mm everywhere).
//! The lumen radius grows from 12 mm (descending) through 14 mm (arch top) to
//! 15 mm (ascending); the wall is 2 mm thick. Supra-aortic branches are not
//! meshed (see the README).
//!
//! The wall is a structured grid in (arc length, angle, depth): `na` rings
//! along the centreline, `nc` nodes around, `nl` node layers through the
//! wall, with the circumference periodic. Each grid cell is split into six
//! tets by the Kuhn (Freudenthal) subdivision, which is conforming across
//! cells and across the periodic seam because every cell is split the same way
//! in index space. Frames are rotation-minimising (double reflection, Wang et
//! al. 2008) so the grid does not twist.
//!
//! Node sets: `inlet` (aortic root ring, all layers), `outlet_descending`
//! (descending end ring), `inner_wall` (lumen surface), `outer_wall`.

use super::{signed_volume, TetMesh, TopologyError};
use crate::math::Vec3;
use std::collections::BTreeMap;

/// Geometry parameters of the arch (millimetres, as anatomy is quoted).
#[derive(Debug, Clone, PartialEq)]
pub struct ArchParams {
    /// (x, y) of the descending aorta where the arch begins (mm).
    pub descending_xy_mm: [f64; 2],
    /// (x, y) of the ascending aorta's axis (mm).
    pub ascending_xy_mm: [f64; 2],
    /// Height of the arch's centre (mm): where descending and ascending parts meet the arch.
    pub arch_center_z_mm: f64,
    /// Height of the ascending end (aortic root) (mm).
    pub ascending_end_z_mm: f64,
    /// Lumen radius (mm) at the descending end, the arch top and the ascending end.
    pub lumen_radius_mm: [f64; 3],
    /// Wall thickness (mm).
    pub wall_mm: f64,
}

impl Default for ArchParams {
    fn default() -> Self {
        ArchParams {
            descending_xy_mm: [18.0, 0.0],
            ascending_xy_mm: [-5.0, -62.0],
            arch_center_z_mm: 128.0,
            ascending_end_z_mm: 90.0,
            lumen_radius_mm: [12.0, 14.0, 15.0],
            wall_mm: 2.0,
        }
    }
}

impl ArchParams {
    /// The centreline point (mm) at curve parameter u in [0, 1]: descending
    /// part on [0, 1/3], arch on [1/3, 2/3], ascending part on [2/3, 1]
    /// (the parameter is not arc length; callers resample).
    pub(crate) fn centerline_at(&self, u: f64) -> Vec3 {
        let d = nalgebra::Vector2::from(self.descending_xy_mm);
        let a = nalgebra::Vector2::from(self.ascending_xy_mm);
        let zc = self.arch_center_z_mm;
        if u <= 1.0 / 3.0 {
            // Bows from the origin to d with a vertical tangent at the top.
            let w = 3.0 * u;
            let xy = d * (std::f64::consts::FRAC_PI_2 * w).sin();
            Vec3::new(xy.x, xy.y, zc * w)
        } else if u <= 2.0 / 3.0 {
            let th = std::f64::consts::PI * (1.0 - (3.0 * u - 1.0));
            let c = (d + a) * 0.5;
            let r = (a - d).norm() * 0.5;
            let h = (a - d) / (2.0 * r).max(f64::MIN_POSITIVE);
            let xy = c + h * r * th.cos();
            Vec3::new(xy.x, xy.y, zc + r * th.sin())
        } else {
            let w = 3.0 * u - 2.0;
            Vec3::new(a.x, a.y, zc + (self.ascending_end_z_mm - zc) * w)
        }
    }
}

/// Structured grid resolution of the wall.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct ArchGrid {
    /// Rings along the centreline.
    pub axial: usize,
    /// Nodes around the circumference.
    pub circumferential: usize,
    /// Node layers through the wall thickness (≥ 2).
    pub layers: usize,
}

impl ArchGrid {
    /// Number of nodes of this grid.
    pub fn nodes(&self) -> usize {
        self.axial * self.circumferential * self.layers
    }
    /// Number of tets of this grid.
    pub fn tets(&self) -> usize {
        6 * (self.axial - 1) * self.circumferential * (self.layers - 1)
    }
}

/// A generated arch: the mesh (metres) and what a scene may want to know
/// about how it was built.
#[derive(Debug, Clone)]
pub struct Arch {
    /// The tetrahedral wall mesh (SI units).
    pub mesh: TetMesh,
    /// The grid it was built from.
    pub grid: ArchGrid,
    /// Centreline samples (m), one per ring, descending end first.
    pub centerline: Vec<Vec3>,
    /// Arc length (m) along the centreline of each ring.
    pub ring_arclength: Vec<f64>,
    /// Index of the ring at the arch top (highest centreline point).
    pub top_ring: usize,
}

impl Arch {
    /// Node index of grid point (ring `a`, angle index `c`, layer `l`).
    pub fn node(&self, a: usize, c: usize, l: usize) -> usize {
        node_index(&self.grid, a, c, l)
    }
}

/// Error for impossible arch requests.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ArchError {
    /// Too few nodes were requested for a closed tube wall.
    #[error("--nodes {0} is too small: the arch needs at least {1} nodes")]
    TooFewNodes(usize, usize),
    /// Too many nodes were requested.
    #[error("--nodes {0} is too large: at most {1} nodes are supported")]
    TooManyNodes(usize, usize),
    /// An invalid grid was requested.
    #[error("invalid arch grid: {0}")]
    BadGrid(String),
    /// The generated mesh failed validation (a bug, reported rather than hidden).
    #[error("generated arch mesh is invalid: {0}")]
    Topology(#[from] TopologyError),
}

/// Smallest node count [`generate`] accepts.
pub const MIN_NODES: usize = 8 * 4 * 2;
/// Largest node count [`generate`] accepts.
pub const MAX_NODES: usize = 5_000_000;

fn node_index(g: &ArchGrid, a: usize, c: usize, l: usize) -> usize {
    (a * g.circumferential + (c % g.circumferential)) * g.layers + l
}

/// A sampled centreline: point, unit tangent, arc length.
struct Centerline {
    pts: Vec<Vec3>,
    tan: Vec<Vec3>,
    s: Vec<f64>,
}

fn sample_centerline(params: &ArchParams, n: usize) -> Centerline {
    // Dense sampling, then resample at equal arc length.
    let dense = 30_000;
    let mut pts: Vec<Vec3> = Vec::with_capacity(dense + 1);
    let mut cum = Vec::with_capacity(dense + 1);
    let mut acc = 0.0;
    for i in 0..=dense {
        let x = params.centerline_at(i as f64 / dense as f64);
        if let Some(prev) = pts.last() {
            acc += (x - prev).norm();
        }
        pts.push(x);
        cum.push(acc);
    }
    let total = acc;
    let n = n.max(2);
    let mut out = Centerline {
        pts: Vec::with_capacity(n),
        tan: Vec::with_capacity(n),
        s: Vec::with_capacity(n),
    };
    let mut j = 0;
    for i in 0..n {
        let target = total * i as f64 / (n - 1) as f64;
        while j + 1 < dense && cum[j + 1] < target {
            j += 1;
        }
        let span = (cum[j + 1] - cum[j]).max(f64::MIN_POSITIVE);
        let w = ((target - cum[j]) / span).clamp(0.0, 1.0);
        let u = (j as f64 + w) / dense as f64;
        let x = params.centerline_at(u);
        let h = 0.5 / dense as f64;
        let d = params.centerline_at((u + h).min(1.0)) - params.centerline_at((u - h).max(0.0));
        out.pts.push(x);
        out.tan.push(d.normalize());
        out.s.push(target);
    }
    out
}

/// Total centreline length (mm) of an arch shape.
pub fn centerline_length_mm(params: &ArchParams) -> f64 {
    *sample_centerline(params, 2).s.last().unwrap_or(&0.0)
}

/// Chooses the grid whose node count is closest to `target` (within 0.75 % for
/// any target in range) with the best-shaped cells: element sizes along,
/// around and through the wall as equal as the count allows.
pub fn grid_for_nodes(params: &ArchParams, target: usize) -> Result<ArchGrid, ArchError> {
    if target < MIN_NODES {
        return Err(ArchError::TooFewNodes(target, MIN_NODES));
    }
    if target > MAX_NODES {
        return Err(ArchError::TooManyNodes(target, MAX_NODES));
    }
    let length = centerline_length_mm(params);
    let r_mean = params.lumen_radius_mm.iter().sum::<f64>() / 3.0 + params.wall_mm / 2.0;
    let circ = 2.0 * std::f64::consts::PI * r_mean;
    let mut best: Option<(f64, ArchGrid)> = None;
    for layers in 2..=6 {
        for nc in 8..=400 {
            let ring = nc * layers;
            let na = ((target as f64) / ring as f64).round() as usize;
            if na < 4 {
                continue;
            }
            let g = ArchGrid {
                axial: na,
                circumferential: nc,
                layers,
            };
            let err = (g.nodes() as f64 - target as f64).abs() / target as f64;
            if err > 0.0075 {
                continue;
            }
            let h = [
                length / (na - 1) as f64,
                circ / nc as f64,
                params.wall_mm / (layers - 1) as f64,
            ];
            let hmax = h.iter().cloned().fold(0.0, f64::max);
            let hmin = h.iter().cloned().fold(f64::INFINITY, f64::min);
            // Cell aspect first; a count error costs as much as 10% aspect per 0.1%.
            let score = hmax / hmin + 100.0 * err;
            if best.as_ref().is_none_or(|(s, _)| score < *s) {
                best = Some((score, g));
            }
        }
    }
    best.map(|(_, g)| g)
        .ok_or(ArchError::BadGrid(format!("no grid within 0.75% of {target} nodes")))
}

/// Generates the arch with about `nodes` nodes (within 0.75 %).
pub fn generate(params: &ArchParams, nodes: usize) -> Result<Arch, ArchError> {
    let grid = grid_for_nodes(params, nodes)?;
    generate_grid(params, grid)
}

/// Generates the arch on an explicit grid.
pub fn generate_grid(params: &ArchParams, grid: ArchGrid) -> Result<Arch, ArchError> {
    if grid.axial < 2 || grid.circumferential < 3 || grid.layers < 2 {
        return Err(ArchError::BadGrid(format!(
            "need axial >= 2, circumferential >= 3, layers >= 2; got {grid:?}"
        )));
    }
    if !(params.wall_mm > 0.0 && params.lumen_radius_mm.iter().all(|r| *r > 0.0)) {
        return Err(ArchError::BadGrid("radii and wall thickness must be positive".into()));
    }
    let cl = sample_centerline(params, grid.axial);
    let total = *cl.s.last().unwrap_or(&1.0);
    let top_ring = (0..grid.axial)
        .max_by(|&a, &b| cl.pts[a].z.total_cmp(&cl.pts[b].z))
        .unwrap_or(0);
    let s_top = cl.s[top_ring] / total;
    let [r0, r1, r2] = params.lumen_radius_mm;
    let radius = |u: f64| {
        if u <= s_top {
            r0 + (r1 - r0) * u / s_top.max(1e-9)
        } else {
            r1 + (r2 - r1) * (u - s_top) / (1.0 - s_top).max(1e-9)
        }
    };

    // Rotation-minimising frames by double reflection.
    let t0 = cl.tan[0];
    let seed = if t0.x.abs() < 0.9 { Vec3::x() } else { Vec3::y() };
    let mut normal = (seed - t0 * seed.dot(&t0)).normalize();
    let mut normals = Vec::with_capacity(grid.axial);
    normals.push(normal);
    for i in 0..grid.axial - 1 {
        let v1 = cl.pts[i + 1] - cl.pts[i];
        let c1 = v1.dot(&v1);
        let r_l = normal - v1 * (2.0 / c1 * v1.dot(&normal));
        let t_l = cl.tan[i] - v1 * (2.0 / c1 * v1.dot(&cl.tan[i]));
        let v2 = cl.tan[i + 1] - t_l;
        let c2 = v2.dot(&v2);
        normal = if c2 > 0.0 {
            r_l - v2 * (2.0 / c2 * v2.dot(&r_l))
        } else {
            r_l
        };
        normal = (normal - cl.tan[i + 1] * normal.dot(&cl.tan[i + 1])).normalize();
        normals.push(normal);
    }

    let mm = 1e-3;
    let mut rest = Vec::with_capacity(grid.nodes());
    for (a, &n) in normals.iter().enumerate() {
        let u = cl.s[a] / total;
        let t = cl.tan[a];
        let b = t.cross(&n);
        let r_in = radius(u);
        for c in 0..grid.circumferential {
            let th = 2.0 * std::f64::consts::PI * c as f64 / grid.circumferential as f64;
            let dir = n * th.cos() + b * th.sin();
            for l in 0..grid.layers {
                let r = r_in + params.wall_mm * l as f64 / (grid.layers - 1) as f64;
                rest.push((cl.pts[a] + dir * r) * mm);
            }
        }
    }

    let tets = kuhn_wall_tets(&grid, &rest);
    let sets = wall_node_sets(&grid, "outlet_descending", "inlet");

    let mesh = TetMesh::new(rest, tets, sets)?;
    Ok(Arch {
        mesh,
        grid,
        centerline: cl.pts.iter().map(|p| p * mm).collect(),
        ring_arclength: cl.s.iter().map(|s| s * mm).collect(),
        top_ring,
    })
}

/// The tets of a structured wall grid (rings × around × layers, periodic
/// around) whose node positions are `rest` in [`ArchGrid`] numbering: each
/// cell split into six by the Kuhn (Freudenthal) subdivision, which is
/// conforming across cells and across the periodic seam because every cell
/// is split the same way in index space; tets are oriented positively.
pub(crate) fn kuhn_wall_tets(grid: &ArchGrid, rest: &[Vec3]) -> Vec<[u32; 4]> {
    const PERMS: [[usize; 3]; 6] = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
    let mut tets = Vec::with_capacity(grid.tets());
    for a in 0..grid.axial - 1 {
        for c in 0..grid.circumferential {
            for l in 0..grid.layers - 1 {
                for perm in PERMS {
                    let mut corner = [a, c, l];
                    let mut tet = [0u32; 4];
                    tet[0] = node_index(grid, corner[0], corner[1], corner[2]) as u32;
                    for (k, &axis) in perm.iter().enumerate() {
                        corner[axis] += 1;
                        tet[k + 1] = node_index(grid, corner[0], corner[1], corner[2]) as u32;
                    }
                    let v = tet.map(|i| rest[i as usize]);
                    if signed_volume(&v[0], &v[1], &v[2], &v[3]) < 0.0 {
                        tet.swap(2, 3);
                    }
                    tets.push(tet);
                }
            }
        }
    }
    tets
}

/// The node sets of a structured wall grid: the first and last rings (all
/// layers) under the given names, `inner_wall` (layer 0) and `outer_wall`
/// (the last layer), each sorted.
pub(crate) fn wall_node_sets(grid: &ArchGrid, first_ring: &str, last_ring: &str) -> BTreeMap<String, Vec<u32>> {
    let mut sets = BTreeMap::new();
    let ring = |a: usize| -> Vec<u32> {
        (0..grid.circumferential)
            .flat_map(|c| (0..grid.layers).map(move |l| (c, l)))
            .map(|(c, l)| node_index(grid, a, c, l) as u32)
            .collect()
    };
    let layer = |l: usize| -> Vec<u32> {
        (0..grid.axial)
            .flat_map(|a| (0..grid.circumferential).map(move |c| (a, c)))
            .map(|(a, c)| node_index(grid, a, c, l) as u32)
            .collect()
    };
    sets.insert(first_ring.to_string(), ring(0));
    sets.insert(last_ring.to_string(), ring(grid.axial - 1));
    sets.insert("inner_wall".to_string(), layer(0));
    sets.insert("outer_wall".to_string(), layer(grid.layers - 1));
    for v in sets.values_mut() {
        v.sort_unstable();
    }
    sets
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::quality::MeshQuality;

    #[test]
    fn paper_sizes_within_one_percent() {
        let p = ArchParams::default();
        for n in [1458usize, 5832, 23328] {
            let g = grid_for_nodes(&p, n).unwrap();
            let err = (g.nodes() as f64 - n as f64).abs() / n as f64;
            assert!(err <= 0.01, "{n}: got {} ({err})", g.nodes());
        }
    }

    #[test]
    fn small_arch_is_valid_and_well_shaped() {
        let arch = generate(&ArchParams::default(), 1458).unwrap();
        let m = &arch.mesh;
        assert_eq!(m.report().inverted, 0);
        assert_eq!(m.num_nodes(), arch.grid.nodes());
        assert_eq!(m.tets().len(), arch.grid.tets());
        let q = MeshQuality::of(m);
        assert!(q.min_dihedral_deg > 5.0, "{q:?}");
        // Length ≈ 276 mm; the wall volume ≈ 2π r t L.
        let len = arch.ring_arclength.last().unwrap();
        assert!((0.25..0.30).contains(len), "length {len}");
        let vol = m.total_volume();
        let expect = 2.0 * std::f64::consts::PI * 0.0145 * 0.002 * len;
        assert!((vol / expect - 1.0).abs() < 0.1, "volume {vol} vs {expect}");
        // Closed tube wall: surface = inner + outer + two end annuli.
        let g = arch.grid;
        let expect_tris = 2 * 2 * (g.axial - 1) * g.circumferential + 2 * 2 * g.circumferential * (g.layers - 1);
        assert_eq!(m.surface().len(), expect_tris);
        for set in ["inlet", "outlet_descending", "inner_wall", "outer_wall"] {
            assert!(!m.node_set(set).unwrap().is_empty(), "{set}");
        }
    }

    #[test]
    fn tiny_requests_are_refused() {
        assert!(matches!(
            generate(&ArchParams::default(), 10),
            Err(ArchError::TooFewNodes(10, _))
        ));
    }
}
