//! The built-in branched aortic arch as an implicit lumen: a centreline tree
//! (the aorta from the aortic root over the arch to the descending end, and
//! the three supra-aortic branches) with radii, swept into tubes and blended
//! smoothly at the junctions; its lumen surface is extracted as an isosurface
//! (`fast-surface-nets`), cut exactly at each end plane so every end is a
//! clean open boundary loop, and remeshed isotropically
//! ([`super::remesh`]).
//!
//! Frame and aorta: those of the unbranched arch ([`crate::mesh::arch`],
//! after the defaults of Karstensen et al.'s procedural aortic-arch
//! generator, IJCARS 2023): z toward the head, +x to the patient's left, the
//! ascending aorta anterior (−y); the aortic root at z = 90 mm, the arch top
//! at z ≈ 161 mm, the descending end at the origin; lumen radius 15 mm
//! (ascending), 14 mm (arch top), 12 mm (descending).
//!
//! Branches (lumen diameters at the origin from CT angiography of 217 adult
//! arches): brachiocephalic trunk 12.5 mm, left common carotid 8.3 mm, left
//! subclavian 10.4 mm, with take-off angles of about 45°, 26° and 29°
//! (taken here from the vertical, the brachiocephalic toward the patient's
//! right, the other two toward the left). Along the aortic centreline the
//! left common carotid arises 16 mm after the brachiocephalic and the left
//! subclavian 28 mm after the carotid (Karstensen et al.'s generator). The
//! arch type (I / II / III: the brachiocephalic origin less than one, one to
//! two, or more than two left-carotid diameters below the arch top) places
//! the group: the brachiocephalic ostium (where its axis crosses the aortic
//! wall) sits 0.5, 1.5 or 2.5 carotid diameters below the top of the arch's
//! outer curvature.
//!
//! Each tube is the set where the distance to its centreline polyline, minus
//! the radius interpolated along it, is negative; the tubes are joined by the
//! polynomial smooth minimum `smin(a, b) = min(a, b) − h² k / 4`,
//! `h = max(k − |a − b|, 0) / k` (blend radius k), which rounds each junction
//! over about k.

use super::remesh::{
    graded_size, remesh, remesh_to_vertex_count, remesh_to_vertex_count_scaled, RemeshError, RemeshOptions, RemeshStats,
};
use crate::math::Vec3;
use crate::mesh::arch::ArchParams;
use crate::mesh::surface::{check_surface, BoundaryLoop, CheckOptions, SurfaceDefect, SurfaceMesh};
use fast_surface_nets::ndshape::{RuntimeShape, Shape};
use fast_surface_nets::{surface_nets, SurfaceNetsBuffer};
use std::collections::HashMap;

/// Names of the segments of the built-in arch tree, in label order
/// ([`label_vertices`] returns indices into this).
pub const SEGMENT_NAMES: [&str; 4] = ["aorta", "brachiocephalic", "left_common_carotid", "left_subclavian"];

/// Clinical aortic arch type: how far the brachiocephalic trunk's origin
/// sits below the top of the arch, in left-common-carotid diameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum ArchType {
    /// Less than one diameter (placed at 0.5).
    I,
    /// One to two diameters (placed at 1.5).
    II,
    /// More than two diameters (placed at 2.5).
    III,
}

impl ArchType {
    /// Depth of the brachiocephalic origin below the arch top, in
    /// left-common-carotid diameters, that this crate uses for the type.
    pub fn depth_in_carotid_diameters(self) -> f64 {
        match self {
            ArchType::I => 0.5,
            ArchType::II => 1.5,
            ArchType::III => 2.5,
        }
    }
}

/// Shape of the branched arch (millimetres and degrees, as anatomy is
/// quoted). Branch arrays are in the order brachiocephalic, left common
/// carotid, left subclavian.
#[derive(Debug, Clone, PartialEq)]
pub struct BranchedArchParams {
    /// The aorta: the unbranched arch's centreline and radii.
    pub aorta: ArchParams,
    /// Arch type (places the branch origins).
    pub arch_type: ArchType,
    /// Distances along the aortic centreline from the brachiocephalic to the
    /// left common carotid origin, and from there to the left subclavian (mm).
    pub branch_spacing_mm: [f64; 2],
    /// Lumen radius of each branch (mm).
    pub branch_radius_mm: [f64; 3],
    /// Take-off angle of each branch from the vertical (degrees); the
    /// brachiocephalic leans to the patient's right (−x), the others left.
    pub takeoff_deg: [f64; 3],
    /// Length of each branch from its origin on the aortic centreline to its
    /// outlet (mm).
    pub branch_length_mm: [f64; 3],
    /// Blend radius of the junctions (mm).
    pub blend_mm: f64,
}

impl Default for BranchedArchParams {
    fn default() -> Self {
        BranchedArchParams {
            aorta: ArchParams::default(),
            arch_type: ArchType::I,
            branch_spacing_mm: [16.0, 28.0],
            branch_radius_mm: [6.25, 4.15, 5.2],
            takeoff_deg: [45.0, 26.0, 29.0],
            branch_length_mm: [45.0, 55.0, 50.0],
            blend_mm: 8.0,
        }
    }
}

/// Why the implicit lumen could not be built or meshed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ImplicitError {
    /// A parameter is out of range.
    #[error("invalid branched-arch parameter: {0}")]
    BadParameter(String),
    /// The isosurface or its cut came out unusable (a bug or an extreme
    /// parameter, reported rather than hidden).
    #[error("lumen surface: {0}")]
    Surface(#[from] SurfaceDefect),
    /// Remeshing failed.
    #[error("remeshing the lumen: {0}")]
    Remesh(#[from] RemeshError),
    /// The vertex count asked for is too small to keep enough vertices
    /// around every vessel.
    #[error("{vertices} lumen vertices are too few for this tree: {what}; ask for more nodes")]
    TooCoarse {
        /// The vertex count asked for.
        vertices: usize,
        /// What fell short.
        what: String,
    },
    /// An opening of the tree was not found on the surface.
    #[error("the lumen surface has {found} openings, the tree has {expected} ends")]
    Openings {
        /// Boundary loops found.
        found: usize,
        /// Ends of the tree.
        expected: usize,
    },
}

/// One vessel of a centreline tree: a polyline with a lumen radius at each
/// point (metres).
#[derive(Debug, Clone, PartialEq)]
pub struct Segment {
    /// Name (one of [`SEGMENT_NAMES`] for the built-in arch).
    pub name: String,
    /// Centreline points (m), from the vessel's start (root or origin on its
    /// parent) to its end.
    pub points: Vec<Vec3>,
    /// Lumen radius at each point (m).
    pub radii: Vec<f64>,
    /// Index of the parent segment (a branch starts inside its parent).
    pub parent: Option<usize>,
    /// Arc length (m) from the start where the branch proper begins: past its
    /// parent's wall plus the blend radius. Surface there and beyond carries
    /// this segment's label; before it, the parent's. Zero for a root.
    pub proper_from: f64,
    /// Whether the segment's start is an opening (the aortic root); a branch
    /// starts inside its parent.
    pub open_start: bool,
}

/// An end of the tree: where the lumen surface has an opening.
#[derive(Debug, Clone, PartialEq)]
pub struct TreeEnd {
    /// Opening name (`inlet`, `outlet_descending`, `outlet_<branch>`).
    pub name: String,
    /// Segment index.
    pub segment: usize,
    /// Centre of the end section (m).
    pub centre: Vec3,
    /// Unit normal pointing out of the lumen along the centreline.
    pub normal: Vec3,
    /// Lumen radius there (m).
    pub radius: f64,
}

/// A centreline tree with radii: the implicit lumen.
#[derive(Debug, Clone, PartialEq)]
pub struct LumenTree {
    /// The vessels, the root (aorta) first.
    pub segments: Vec<Segment>,
    /// Blend radius of the junctions (m).
    pub blend: f64,
}

/// Polynomial smooth minimum with blend radius k.
pub fn smooth_min(a: f64, b: f64, k: f64) -> f64 {
    if k <= 0.0 {
        return a.min(b);
    }
    let h = (k - (a - b).abs()).max(0.0) / k;
    a.min(b) - h * h * k * 0.25
}

/// Distance from p to a polyline with radii: (distance − radius, arc length
/// of the closest point, radius there).
fn tube_query(points: &[Vec3], radii: &[f64], p: &Vec3) -> (f64, f64, f64) {
    let mut best = (f64::INFINITY, 0.0, radii.first().copied().unwrap_or(0.0));
    let mut s0 = 0.0;
    for i in 0..points.len().saturating_sub(1) {
        let (a, b) = (points[i], points[i + 1]);
        let ab = b - a;
        let l2 = ab.norm_squared();
        let t = crate::math::segment_parameter(*p, a, b);
        let r = radii[i] + (radii[i + 1] - radii[i]) * t;
        let d = (p - (a + ab * t)).norm() - r;
        let l = l2.sqrt();
        if d < best.0 {
            best = (d, s0 + t * l, r);
        }
        s0 += l;
    }
    best
}

fn arc_lengths(points: &[Vec3]) -> Vec<f64> {
    let mut s = vec![0.0; points.len()];
    for i in 1..points.len() {
        s[i] = s[i - 1] + (points[i] - points[i - 1]).norm();
    }
    s
}

/// Resamples a polyline at (about) equal spacing `step`.
fn resample(points: &[Vec3], step: f64) -> Vec<Vec3> {
    let s = arc_lengths(points);
    let total = *s.last().unwrap_or(&0.0);
    let n = ((total / step).ceil() as usize).max(1);
    let mut out = Vec::with_capacity(n + 1);
    let mut j = 0;
    for i in 0..=n {
        let target = total * i as f64 / n as f64;
        while j + 2 < points.len() && s[j + 1] < target {
            j += 1;
        }
        let span = (s[j + 1] - s[j]).max(f64::MIN_POSITIVE);
        let w = ((target - s[j]) / span).clamp(0.0, 1.0);
        out.push(points[j] + (points[j + 1] - points[j]) * w);
    }
    out
}

impl LumenTree {
    /// The built-in branched arch (metres).
    pub fn arch(params: &BranchedArchParams) -> Result<LumenTree, ImplicitError> {
        let a = &params.aorta;
        let positive = |v: f64| v.is_finite() && v > 0.0;
        let valid = a.lumen_radius_mm.iter().all(|&r| positive(r))
            && params.branch_radius_mm.iter().all(|&r| positive(r))
            && params.branch_length_mm.iter().all(|&r| positive(r))
            && params.branch_spacing_mm.iter().all(|&r| r.is_finite() && r >= 0.0)
            && params.blend_mm.is_finite()
            && params.blend_mm >= 0.0;
        if !valid {
            return Err(ImplicitError::BadParameter(format!(
                "radii, lengths, spacings and the blend must be positive and finite: {params:?}"
            )));
        }
        let mm = 1e-3;
        // Dense samples from the descending end (u = 0) to the root (u = 1),
        // radii as in mesh::arch (linear in arc length to and from the top).
        let dense: Vec<Vec3> = (0..=3000).map(|i| a.centerline_at(i as f64 / 3000.0)).collect();
        let pts = resample(&dense, 2.0);
        let s = arc_lengths(&pts);
        let total = *s.last().unwrap_or(&1.0);
        let top = (0..pts.len())
            .max_by(|&i, &j| pts[i].z.total_cmp(&pts[j].z))
            .unwrap_or(0);
        let s_top = s[top] / total;
        let [r0, r1, r2] = a.lumen_radius_mm;
        let radius = |u: f64| {
            if u <= s_top {
                r0 + (r1 - r0) * u / s_top.max(1e-9)
            } else {
                r1 + (r2 - r1) * (u - s_top) / (1.0 - s_top).max(1e-9)
            }
        };
        let mut radii: Vec<f64> = s.iter().map(|&si| radius(si / total)).collect();
        // Root first (the flow direction).
        let mut apts = pts.clone();
        apts.reverse();
        radii.reverse();
        let s_root = arc_lengths(&apts);

        let at = |s: f64| -> Vec3 {
            let i = s_root.partition_point(|&x| x < s).clamp(1, apts.len() - 1);
            let w = ((s - s_root[i - 1]) / (s_root[i] - s_root[i - 1]).max(1e-12)).clamp(0.0, 1.0);
            apts[i - 1] + (apts[i] - apts[i - 1]) * w
        };
        let dirs: Vec<Vec3> = (0..3)
            .map(|b| {
                let phi = params.takeoff_deg[b].to_radians();
                let side = if b == 0 { -1.0 } else { 1.0 };
                Vec3::new(side * phi.sin(), 0.0, phi.cos())
            })
            .collect();
        // Where a branch from centreline arc length s along `dir` crosses
        // the aortic wall (its origin, the ostium), in mm.
        let ostium = |s: f64, dir: &Vec3| -> Vec3 {
            let o = at(s);
            let (mut lo_t, mut hi_t) = (0.0, 3.0 * r2.max(r1).max(r0));
            for _ in 0..50 {
                let m = 0.5 * (lo_t + hi_t);
                if tube_query(&apts, &radii, &(o + dir * m)).0 < 0.0 {
                    lo_t = m;
                } else {
                    hi_t = m;
                }
            }
            o + dir * lo_t
        };
        // The top of the arch's outer curvature (mm).
        let top_z = apts
            .iter()
            .zip(&radii)
            .map(|(p, r)| p.z + r)
            .fold(f64::NEG_INFINITY, f64::max);
        // The brachiocephalic ostium sits `depth` below it: bisection on its
        // position between the root and the arch top.
        let depth = params.arch_type.depth_in_carotid_diameters() * 2.0 * params.branch_radius_mm[1];
        let (mut s_lo, mut s_hi) = (0.0, total - s[top]);
        if top_z - ostium(s_lo, &dirs[0]).z < depth {
            return Err(ImplicitError::BadParameter(format!(
                "arch type {:?}: the brachiocephalic origin would sit {depth} mm below the arch top, below the aortic root",
                params.arch_type
            )));
        }
        for _ in 0..60 {
            let m = 0.5 * (s_lo + s_hi);
            if top_z - ostium(m, &dirs[0]).z > depth {
                s_lo = m;
            } else {
                s_hi = m;
            }
        }
        let s_bct = 0.5 * (s_lo + s_hi);
        let origins = [
            s_bct,
            s_bct + params.branch_spacing_mm[0],
            s_bct + params.branch_spacing_mm[0] + params.branch_spacing_mm[1],
        ];
        let aorta = Segment {
            name: SEGMENT_NAMES[0].to_string(),
            points: apts.iter().map(|p| p * mm).collect(),
            radii: radii.iter().map(|r| r * mm).collect(),
            parent: None,
            proper_from: 0.0,
            open_start: true,
        };
        let mut segments = vec![aorta];
        for b in 0..3 {
            if origins[b] <= 0.0 || origins[b] >= total {
                return Err(ImplicitError::BadParameter(format!(
                    "branch {}: origin {:.1} mm from the root is off the aorta ({total:.1} mm long)",
                    SEGMENT_NAMES[b + 1],
                    origins[b]
                )));
            }
            let o = at(origins[b]);
            let dir = dirs[b];
            let len = params.branch_length_mm[b];
            let n = ((len / 2.0).ceil() as usize).max(2);
            let points: Vec<Vec3> = (0..=n).map(|i| (o + dir * (len * i as f64 / n as f64)) * mm).collect();
            let r = params.branch_radius_mm[b] * mm;
            let mut seg = Segment {
                name: SEGMENT_NAMES[b + 1].to_string(),
                radii: vec![r; points.len()],
                points,
                parent: Some(0),
                proper_from: 0.0,
                open_start: false,
            };
            // Where the branch leaves the aorta's lumen, plus the blend.
            let parent = &segments[0];
            let sl = arc_lengths(&seg.points);
            let exit = (0..seg.points.len())
                .find(|&i| tube_query(&parent.points, &parent.radii, &seg.points[i]).0 > 0.0)
                .map(|i| sl[i])
                .ok_or_else(|| {
                    ImplicitError::BadParameter(format!("branch {} never leaves the aorta (length {len} mm)", seg.name))
                })?;
            seg.proper_from = exit + params.blend_mm * mm;
            if seg.proper_from >= *sl.last().unwrap_or(&0.0) {
                return Err(ImplicitError::BadParameter(format!(
                    "branch {} is too short: it leaves the aorta {:.1} mm from its origin",
                    seg.name,
                    exit / mm
                )));
            }
            segments.push(seg);
        }
        Ok(LumenTree {
            segments,
            blend: params.blend_mm * mm,
        })
    }

    /// Signed distance-like function of the lumen (m): negative inside.
    /// Exact for one straight tube of constant radius; a blend of tube
    /// distances elsewhere.
    pub fn sdf(&self, p: &Vec3) -> f64 {
        let mut f = f64::INFINITY;
        for (i, s) in self.segments.iter().enumerate() {
            let d = tube_query(&s.points, &s.radii, p).0;
            f = if i == 0 { d } else { smooth_min(f, d, self.blend) };
        }
        f
    }

    /// The lumen radius the surface is meshed to at p (m): the radius of
    /// the vessel whose wall is nearest to p, or the smallest radius of the
    /// vessels whose walls pass within one blend radius of p, if smaller.
    /// A junction's fillet, which curves with about the blend radius, is
    /// thus meshed at the branch's size: at the parent's, its vertex
    /// normals would differ by 60° across one triangle and the wall's
    /// prisms there would shear into flat tets.
    pub fn local_radius(&self, p: &Vec3) -> f64 {
        let mut best = (f64::INFINITY, 0.0);
        let mut near = f64::INFINITY;
        for s in &self.segments {
            let (d, _, r) = tube_query(&s.points, &s.radii, p);
            if d.abs() < best.0 {
                best = (d.abs(), r);
            }
            if d.abs() <= self.blend {
                near = near.min(r);
            }
        }
        best.1.min(near)
    }

    /// The segment label of p ([`label_vertices`]) and the lumen radius of
    /// that segment at its centreline point nearest to p (m): the radius the
    /// size and the wall thickness of the branched arch follow, so a
    /// junction (labelled with the parent) is meshed and walled like the
    /// parent, and a branch like itself from where its label starts.
    pub fn label_and_radius(&self, p: &Vec3) -> (usize, f64) {
        let mut best = (f64::INFINITY, 0usize, 0.0, 0.0);
        for (i, s) in self.segments.iter().enumerate() {
            let (d, sl, r) = tube_query(&s.points, &s.radii, p);
            if d.abs() < best.0 {
                best = (d.abs(), i, sl, r);
            }
        }
        let (_, i, sl, r) = best;
        match self
            .segments
            .get(i)
            .and_then(|s| s.parent.filter(|_| sl < s.proper_from))
        {
            Some(parent) => (parent, self.segment_radius(parent, p)),
            None => (i, r),
        }
    }

    /// The lumen radius of segment `segment` at the point of its centreline
    /// nearest to p (m); 0 for an index out of range.
    pub fn segment_radius(&self, segment: usize, p: &Vec3) -> f64 {
        self.segments
            .get(segment)
            .map(|s| tube_query(&s.points, &s.radii, p).2)
            .unwrap_or(0.0)
    }

    /// The openings of the tree: the aortic root (`inlet`), the descending
    /// end (`outlet_descending`) and each branch end (`outlet_<name>`).
    pub fn ends(&self) -> Vec<TreeEnd> {
        let mut out = Vec::new();
        for (i, s) in self.segments.iter().enumerate() {
            let n = s.points.len();
            if n < 2 {
                continue;
            }
            if s.open_start {
                out.push(TreeEnd {
                    name: if i == 0 {
                        "inlet".into()
                    } else {
                        format!("inlet_{}", s.name)
                    },
                    segment: i,
                    centre: s.points[0],
                    normal: (s.points[0] - s.points[1]).normalize(),
                    radius: s.radii[0],
                });
            }
            out.push(TreeEnd {
                name: if i == 0 {
                    "outlet_descending".into()
                } else {
                    format!("outlet_{}", s.name)
                },
                segment: i,
                centre: s.points[n - 1],
                normal: (s.points[n - 1] - s.points[n - 2]).normalize(),
                radius: s.radii[n - 1],
            });
        }
        out
    }

    /// Largest lumen radius of the tree (m).
    pub fn max_radius(&self) -> f64 {
        self.segments
            .iter()
            .flat_map(|s| s.radii.iter().copied())
            .fold(0.0, f64::max)
    }

    /// Smallest lumen radius of the tree (m).
    pub fn min_radius(&self) -> f64 {
        self.segments
            .iter()
            .flat_map(|s| s.radii.iter().copied())
            .fold(f64::INFINITY, f64::min)
    }

    /// A copy with every open end prolonged straight by `ext` (m), for
    /// extraction before the exact cut.
    fn extended(&self, ext: f64) -> LumenTree {
        let mut t = self.clone();
        for s in &mut t.segments {
            let n = s.points.len();
            let end = s.points[n - 1] + (s.points[n - 1] - s.points[n - 2]).normalize() * ext;
            s.points.push(end);
            s.radii.push(s.radii[n - 1]);
            if s.open_start {
                let start = s.points[0] + (s.points[0] - s.points[1]).normalize() * ext;
                s.points.insert(0, start);
                s.radii.insert(0, s.radii[0]);
            }
        }
        t
    }
}

/// The segment label of each point: the index (into the tree's segments,
/// [`SEGMENT_NAMES`] for the arch) of the vessel whose wall is nearest,
/// except that points of a branch before its proper start (the blended
/// junction) go to the parent.
pub fn label_vertices(tree: &LumenTree, points: &[Vec3]) -> Vec<u8> {
    points.iter().map(|p| tree.label_and_radius(p).0 as u8).collect()
}

/// An opening of the lumen surface with its name.
#[derive(Debug, Clone, PartialEq)]
pub struct NamedOpening {
    /// `inlet`, `outlet_descending`, `outlet_brachiocephalic`, …
    pub name: String,
    /// The boundary loop (vertex indices into [`LumenSurface::mesh`]).
    pub boundary: BoundaryLoop,
}

/// The remeshed lumen surface of a tree.
#[derive(Debug, Clone)]
pub struct LumenSurface {
    /// The surface (m), open at each end, normals out of the lumen.
    pub mesh: SurfaceMesh,
    /// Segment label of each vertex ([`label_vertices`]).
    pub labels: Vec<u8>,
    /// The openings, in the order of [`LumenTree::ends`].
    pub openings: Vec<NamedOpening>,
    /// Quality of the remeshed surface.
    pub stats: RemeshStats,
    /// The isosurface before remeshing (after the end cuts): triangles.
    pub isosurface_triangles: usize,
}

/// Extracts the lumen of `tree` on a grid of spacing about `h` (m), prolongs
/// each open end and cuts it exactly at its end plane: an open surface whose
/// boundary loops are the end sections, normals out of the lumen, checked
/// ([`check_surface`]: manifold, one body, oriented).
///
/// Surface nets can make a non-manifold edge where a grid face is ambiguous
/// (a saddle of the blended field crossing it); such an extraction is
/// refused by the check and redone on a grid a few percent finer or coarser
/// (up to six spacings; the error of the last is returned).
pub fn isosurface(tree: &LumenTree, h: f64) -> Result<SurfaceMesh, ImplicitError> {
    if !(h.is_finite() && h > 0.0) || h > 0.5 * tree.min_radius() {
        return Err(ImplicitError::BadParameter(format!(
            "grid spacing {h} m must be positive and at most half the smallest radius ({} m)",
            tree.min_radius()
        )));
    }
    let expected = tree.ends().len();
    let mut last = None;
    for f in [1.0, 0.973, 1.029, 0.947, 1.057, 0.921] {
        let mut mesh = extract(tree, h * f)?;
        compact(&mut mesh);
        if let Err(e) = super::remesh::input_boundary_loops(&mesh) {
            last = Some(ImplicitError::Remesh(e));
            continue;
        }
        let opts = CheckOptions {
            self_intersections: false,
            ..CheckOptions::default()
        };
        match check_surface(&mesh, &opts) {
            Ok(c) if c.report.boundary_loops.len() == expected && c.report.flipped == 0 => return Ok(c.mesh),
            Ok(c) => {
                last = Some(ImplicitError::Openings {
                    found: c.report.boundary_loops.len(),
                    expected,
                })
            }
            Err(e) => last = Some(ImplicitError::Surface(e)),
        }
    }
    Err(last.expect("at least one attempt"))
}

fn extract(tree: &LumenTree, h: f64) -> Result<SurfaceMesh, ImplicitError> {
    let ends = tree.ends();
    let ext = 4.0 * h;
    let ext_tree = tree.extended(ext);
    let k = tree.blend;
    let rmax = ext_tree
        .segments
        .iter()
        .flat_map(|s| s.radii.iter().copied())
        .fold(0.0, f64::max);
    let margin = rmax + k + 3.0 * h;
    let mut lo = Vec3::repeat(f64::INFINITY);
    let mut hi = Vec3::repeat(f64::NEG_INFINITY);
    for s in &ext_tree.segments {
        for p in &s.points {
            lo = lo.inf(p);
            hi = hi.sup(p);
        }
    }
    let lo = lo - Vec3::repeat(margin);
    let hi = hi + Vec3::repeat(margin);
    let dims = ((hi - lo) / h).map(|x| x.ceil() as u32 + 1);
    let cells = dims.x as u64 * dims.y as u64 * dims.z as u64;
    if cells > 200_000_000 {
        return Err(ImplicitError::BadParameter(format!(
            "grid spacing {h} m needs {cells} samples; use a coarser size"
        )));
    }
    let shape = RuntimeShape::<u32, 3>::new([dims.x, dims.y, dims.z]);
    let far = (rmax + k + 2.0 * h) as f32;
    let mut field = vec![far; cells as usize];
    let mut tube = vec![far; cells as usize];
    for (si, s) in ext_tree.segments.iter().enumerate() {
        tube.iter_mut().for_each(|v| *v = far);
        for i in 0..s.points.len() - 1 {
            let (a, b) = (s.points[i], s.points[i + 1]);
            let (ra, rb) = (s.radii[i], s.radii[i + 1]);
            let pad = ra.max(rb) + k + 2.0 * h;
            let blo = ((a.inf(&b) - Vec3::repeat(pad) - lo) / h).map(|x| x.floor().max(0.0) as u32);
            let bhi = ((a.sup(&b) + Vec3::repeat(pad) - lo) / h).map(|x| x.ceil() as u32);
            let ab = b - a;
            let l2 = ab.norm_squared().max(f64::MIN_POSITIVE);
            for z in blo.z..=bhi.z.min(dims.z - 1) {
                for y in blo.y..=bhi.y.min(dims.y - 1) {
                    for x in blo.x..=bhi.x.min(dims.x - 1) {
                        let p = lo + Vec3::new(x as f64, y as f64, z as f64) * h;
                        let t = ((p - a).dot(&ab) / l2).clamp(0.0, 1.0);
                        let d = ((p - (a + ab * t)).norm() - (ra + (rb - ra) * t)) as f32;
                        let idx = shape.linearize([x, y, z]) as usize;
                        if d < tube[idx] {
                            tube[idx] = d;
                        }
                    }
                }
            }
        }
        if si == 0 {
            field.copy_from_slice(&tube);
        } else {
            for (f, &t) in field.iter_mut().zip(&tube) {
                *f = smooth_min(*f as f64, t as f64, k) as f32;
            }
        }
    }
    let mut buf = SurfaceNetsBuffer::default();
    surface_nets(&field, &shape, [0; 3], [dims.x - 1, dims.y - 1, dims.z - 1], &mut buf);
    let vertices: Vec<Vec3> = buf
        .positions
        .iter()
        .map(|q| lo + Vec3::new(q[0] as f64, q[1] as f64, q[2] as f64) * h)
        .collect();
    let mut triangles: Vec<[u32; 3]> = buf.indices.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    // Normals out of the lumen: the closed isosurface encloses a positive
    // volume.
    let vol: f64 = triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| vertices[i as usize]);
            a.dot(&b.cross(&c))
        })
        .sum();
    if vol < 0.0 {
        triangles.iter_mut().for_each(|t| t.swap(1, 2));
    }
    let mut mesh = SurfaceMesh { vertices, triangles };
    for e in &ends {
        cut_end(&mut mesh, e, ext, h);
    }
    Ok(mesh)
}

/// Cuts the surface near the end `e` with its end plane: triangles beyond it
/// are dropped, triangles across it split exactly at it. Only vertices near
/// the end (within 1.5 radii of its axis, up to the prolongation plus a
/// radius beyond) take part, so other parts of the surface that cross the
/// plane far away are left alone.
fn cut_end(mesh: &mut SurfaceMesh, e: &TreeEnd, ext: f64, h: f64) {
    let side: Vec<f64> = mesh
        .vertices
        .iter_mut()
        .map(|p| {
            let v = *p - e.centre;
            let s = v.dot(&e.normal);
            let rho = (v - e.normal * s).norm();
            if rho > 1.5 * e.radius || s < -e.radius || s > ext + 2.0 * e.radius {
                return -1.0;
            }
            // Snap vertices very near the plane onto it: no sliver pieces.
            if s.abs() < 0.1 * h {
                *p -= e.normal * s;
                return 0.0;
            }
            s
        })
        .collect();
    let mut cut_points: HashMap<(u32, u32), u32> = HashMap::new();
    let mut triangles = Vec::with_capacity(mesh.triangles.len());
    for t in &mesh.triangles {
        let s = t.map(|v| side[v as usize]);
        if s.iter().all(|&x| x <= 0.0) {
            triangles.push(*t);
            continue;
        }
        if s.iter().all(|&x| x > 0.0) {
            continue;
        }
        // Sutherland–Hodgman against s <= 0.
        let mut poly: Vec<u32> = Vec::with_capacity(4);
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let (sa, sb) = (s[k], s[(k + 1) % 3]);
            if sa <= 0.0 {
                poly.push(a);
            }
            if (sa < 0.0 && sb > 0.0) || (sa > 0.0 && sb < 0.0) {
                let key = (a.min(b), a.max(b));
                let id = *cut_points.entry(key).or_insert_with(|| {
                    let w = sa / (sa - sb);
                    let (pa, pb) = (mesh.vertices[a as usize], mesh.vertices[b as usize]);
                    let mut q = pa + (pb - pa) * w;
                    // Exactly on the plane.
                    q -= e.normal * (q - e.centre).dot(&e.normal);
                    mesh.vertices.push(q);
                    (mesh.vertices.len() - 1) as u32
                });
                poly.push(id);
            }
        }
        for k in 1..poly.len().saturating_sub(1) {
            triangles.push([poly[0], poly[k], poly[k + 1]]);
        }
    }
    mesh.triangles = triangles;
}

/// Drops vertices no triangle uses.
fn compact(mesh: &mut SurfaceMesh) {
    let mut map = vec![u32::MAX; mesh.vertices.len()];
    let mut vertices = Vec::new();
    for t in &mut mesh.triangles {
        for v in t.iter_mut() {
            if map[*v as usize] == u32::MAX {
                map[*v as usize] = vertices.len() as u32;
                vertices.push(mesh.vertices[*v as usize]);
            }
            *v = map[*v as usize];
        }
    }
    mesh.vertices = vertices;
}

/// The grid spacing used for a target edge length: fine enough for the
/// target size and for the thinnest vessel.
fn grid_spacing(tree: &LumenTree, size: f64) -> f64 {
    (0.5 * size).min(0.25 * tree.min_radius())
}

/// Moves each vertex onto the zero level of the tree's function (Newton
/// steps along its gradient, central differences): the isosurface is only
/// accurate to a fraction of its grid spacing. Boundary vertices move within
/// their end plane.
fn snap_to_lumen(tree: &LumenTree, r: &mut super::remesh::Remeshed) {
    let ends = tree.ends();
    let eps = 1e-3 * tree.min_radius();
    for (p, bl) in r.mesh.vertices.iter_mut().zip(&r.boundary_loop) {
        let plane = bl.and_then(|_| {
            ends.iter()
                .min_by(|a, b| (a.centre - *p).norm().total_cmp(&(b.centre - *p).norm()))
                .map(|e| e.normal)
        });
        for _ in 0..4 {
            let f = tree.sdf(p);
            let mut g = Vec3::zeros();
            for k in 0..3 {
                let mut d = Vec3::zeros();
                d[k] = eps;
                g[k] = (tree.sdf(&(*p + d)) - tree.sdf(&(*p - d))) / (2.0 * eps);
            }
            if let Some(n) = plane {
                g -= n * n.dot(&g);
            }
            let g2 = g.norm_squared();
            if g2 < 1e-6 {
                break;
            }
            *p -= g * (f / g2);
            if f.abs() < 1e-9 {
                break;
            }
        }
    }
}

fn finish(
    tree: &LumenTree,
    iso_tris: usize,
    mut remeshed: super::remesh::Remeshed,
) -> Result<LumenSurface, ImplicitError> {
    snap_to_lumen(tree, &mut remeshed);
    let checked = check_surface(
        &remeshed.mesh,
        &CheckOptions {
            self_intersections: false,
            ..CheckOptions::default()
        },
    )?;
    let mesh = checked.mesh;
    let ends = tree.ends();
    let loops = checked.report.boundary_loops;
    if loops.len() != ends.len() {
        return Err(ImplicitError::Openings {
            found: loops.len(),
            expected: ends.len(),
        });
    }
    let mut openings = Vec::with_capacity(ends.len());
    let mut used = vec![false; loops.len()];
    for e in &ends {
        let (j, _) = loops
            .iter()
            .enumerate()
            .filter(|(j, _)| !used[*j])
            .map(|(j, l)| (j, (l.centre - e.centre).norm()))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .ok_or(ImplicitError::Openings {
                found: loops.len(),
                expected: ends.len(),
            })?;
        used[j] = true;
        openings.push(NamedOpening {
            name: e.name.clone(),
            boundary: loops[j].clone(),
        });
    }
    let labels = label_vertices(tree, &mesh.vertices);
    Ok(LumenSurface {
        mesh,
        labels,
        openings,
        stats: remeshed.stats,
        isosurface_triangles: iso_tris,
    })
}

/// The lumen surface of `tree` remeshed to edge length `size` (m), graded
/// so every vessel keeps at least 8 vertices around ([`graded_size`]).
pub fn lumen_surface(tree: &LumenTree, size: f64) -> Result<LumenSurface, ImplicitError> {
    if !(size.is_finite() && size > 0.0) {
        return Err(ImplicitError::BadParameter(format!("size {size} m must be positive")));
    }
    let iso = isosurface(tree, grid_spacing(tree, size))?;
    let radius = |p: &Vec3| tree.local_radius(p);
    let field = graded_size(size, 8, &radius);
    let r = remesh(&iso, &field, &RemeshOptions::default())?;
    finish(tree, iso.triangles.len(), r)
}

/// The fewest vertices around each vessel of `tree` that
/// [`lumen_surface_with_vertices`] accepts.
pub const MIN_NODES_AROUND: usize = 8;

/// How many vertices each segment of `tree` keeps around, at its thinnest:
/// the surface is cut by planes normal to the segment's centreline at each
/// centreline point (of a branch: past its proper start plus one radius),
/// and at each cut the vertices of that segment's label just before the
/// plane, at the ends of the edges it crosses within 1.5 radii of the axis,
/// are counted (a ring of k vertices counts k). The smallest count over the
/// cuts and over the segment's openings is returned per segment
/// (`usize::MAX` for a segment with no cut).
pub fn nodes_around(tree: &LumenTree, mesh: &SurfaceMesh, labels: &[u8]) -> Vec<usize> {
    let mut edges: Vec<(u32, u32)> = mesh
        .triangles
        .iter()
        .flat_map(|t| (0..3).map(move |k| (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]))))
        .collect();
    edges.sort_unstable();
    edges.dedup();
    let label = |v: u32| labels.get(v as usize).copied().unwrap_or(u8::MAX) as usize;
    let mut out = vec![usize::MAX; tree.segments.len()];
    let mut below = Vec::new();
    for (si, seg) in tree.segments.iter().enumerate() {
        let own: Vec<(u32, u32)> = edges
            .iter()
            .copied()
            .filter(|&(a, b)| label(a) == si && label(b) == si)
            .collect();
        let n = seg.points.len();
        let mut arc = 0.0;
        for i in 1..n.saturating_sub(1) {
            arc += (seg.points[i] - seg.points[i - 1]).norm();
            let r = seg.radii[i];
            if seg.parent.is_some() && arc < seg.proper_from + r {
                continue;
            }
            let p = seg.points[i];
            let axis = (seg.points[i + 1] - seg.points[i - 1]).normalize();
            below.clear();
            for &(a, b) in &own {
                let (pa, pb) = (mesh.vertices[a as usize], mesh.vertices[b as usize]);
                let (da, db) = ((pa - p).dot(&axis), (pb - p).dot(&axis));
                if (da < 0.0) != (db < 0.0) {
                    let q = pa + (pb - pa) * (da / (da - db));
                    if (q - p).norm() < 1.5 * r {
                        below.push(if da < 0.0 { a } else { b });
                    }
                }
            }
            below.sort_unstable();
            below.dedup();
            if below.len() >= 3 {
                out[si] = out[si].min(below.len());
            }
        }
    }
    out
}

/// The lumen surface of `tree` with `vertices` vertices (within the relative
/// `tolerance`), graded as in [`lumen_surface`]: a uniform size capped so
/// that every vessel keeps [`MIN_NODES_AROUND`] vertices around.
///
/// When even the capped size everywhere gives more vertices than asked
/// (small counts: the aorta itself is then at its cap), the size becomes
/// c·r everywhere (r the local lumen radius) and the factor c is searched,
/// up to 2π/8 (eight edges of the size around); the result is then
/// measured ([`nodes_around`]) and refused with
/// [`ImplicitError::TooCoarse`] if any vessel keeps fewer than eight
/// vertices around. Returns the largest target edge length used (m) with
/// the surface.
pub fn lumen_surface_with_vertices(
    tree: &LumenTree,
    vertices: usize,
    tolerance: f64,
) -> Result<(f64, LumenSurface), ImplicitError> {
    // The isosurface grid follows the size estimate from the area of a
    // coarse extraction.
    let coarse = isosurface(tree, 0.25 * tree.min_radius())?;
    let area = super::remesh::surface_area(&coarse);
    let size0 = (2.0 * area / (3f64.sqrt() * vertices.max(4) as f64)).sqrt();
    let iso = isosurface(tree, grid_spacing(tree, size0))?;
    let c0 = super::remesh::around_cap(MIN_NODES_AROUND);
    let radius = |p: &Vec3| tree.local_radius(p);
    let cap = |p: &Vec3| c0 * radius(p);
    let opts = RemeshOptions::default();
    let (size, r) = match remesh_to_vertex_count(&iso, vertices, &cap, &opts, tolerance) {
        Ok((s, r)) => (s.min(c0 * tree.max_radius()), r),
        Err(RemeshError::CountNotReached { best, .. }) if best > vertices => {
            let c_max = 2.0 * std::f64::consts::PI / MIN_NODES_AROUND as f64;
            let start = (c0 * (best as f64 / vertices as f64).sqrt()).min(c_max);
            let (c, r) = remesh_to_vertex_count_scaled(&iso, vertices, &radius, start, c_max, &opts, tolerance)
                .map_err(|e| match e {
                    RemeshError::CountNotReached { best, .. } => ImplicitError::TooCoarse {
                        vertices,
                        what: format!(
                            "with {MIN_NODES_AROUND} edges around every vessel the surface still has {best} vertices"
                        ),
                    },
                    e => ImplicitError::Remesh(e),
                })?;
            (c * tree.max_radius(), r)
        }
        Err(e) => return Err(e.into()),
    };
    let surface = finish(tree, iso.triangles.len(), r)?;
    let around = nodes_around(tree, &surface.mesh, &surface.labels);
    if let Some((si, &k)) = around
        .iter()
        .enumerate()
        .filter(|(_, &k)| k < MIN_NODES_AROUND)
        .min_by_key(|(_, &k)| k)
    {
        return Err(ImplicitError::TooCoarse {
            vertices,
            what: format!(
                "the {} (lumen radius {:.2} mm) keeps only {k} vertices around; at least {MIN_NODES_AROUND} are needed",
                tree.segments[si].name,
                tree.segments[si].radii.iter().copied().fold(f64::INFINITY, f64::min) * 1e3
            ),
        });
    }
    Ok((size, surface))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smooth_min_is_below_min_only_within_the_blend() {
        assert_eq!(smooth_min(1.0, 3.0, 1.0), 1.0);
        assert!((smooth_min(1.0, 1.0, 1.0) - 0.75).abs() < 1e-15);
        assert_eq!(smooth_min(2.0, -1.0, 0.0), -1.0);
    }

    #[test]
    fn arch_tree_matches_the_unbranched_arch() {
        let t = LumenTree::arch(&BranchedArchParams::default()).unwrap();
        assert_eq!(t.segments.len(), 4);
        let a = &t.segments[0];
        // Root at (−5, −62, 90) mm, descending end at the origin.
        assert!((a.points[0] - Vec3::new(-5e-3, -62e-3, 90e-3)).norm() < 1e-9);
        assert!(a.points.last().unwrap().norm() < 1e-9);
        assert!((a.radii[0] - 15e-3).abs() < 1e-9 && (a.radii.last().unwrap() - 12e-3).abs() < 1e-9);
        // Inside on the centreline, outside far away.
        assert!(t.sdf(&a.points[10]) < -0.01);
        assert!(t.sdf(&Vec3::new(0.3, 0.0, 0.0)) > 0.2);
        // Arch types move the branches toward the root.
        let p = BranchedArchParams {
            arch_type: ArchType::III,
            ..BranchedArchParams::default()
        };
        let t3 = LumenTree::arch(&p).unwrap();
        assert!(t3.segments[1].points[0].z < t.segments[1].points[0].z);
    }
}
