//! Opening a closed lumen surface: flat end caps found and removed, and
//! cuts along planes the user names.
//!
//! Segmentation tools often close a vessel's ends with flat caps. A cap is
//! found as a group of triangles that
//! 1. is connected across edges, every triangle's normal within
//!    [`CapOptions::max_normal_deviation_deg`] of the first one's (region
//!    growing from each triangle in turn, largest first);
//! 2. is planar: every vertex within 1 % of the group's equivalent radius
//!    √(area/π) of the plane through its area-weighted centroid, normal to
//!    its area-weighted normal;
//! 3. is a disc (Euler characteristic V − E + F = 1) with no edge on an
//!    existing opening, compact (4π·area/perimeter² ≥
//!    [`CapOptions::min_compactness`]; a circle is 1, a strip along a tube
//!    is far below);
//! 4. is bounded by a sharp crease: the dihedral angle to every
//!    neighbouring triangle is at least [`CapOptions::min_crease_deg`];
//! 5. spans the lumen: its area is at least
//!    [`CapOptions::min_section_share`] of the lumen's cross-section in a
//!    parallel plane a tenth of the equivalent radius inside (the other
//!    triangles cut by that plane, within three equivalent radii of the
//!    cap's centre). A flat patch on the side of a vessel fails this: the
//!    section behind it runs along the vessel.
//!
//! Caps that share a vertex with another candidate are not removed (the
//! faces of a coarse polyhedron are not caps). After removal (or a cut) the
//! surface is checked again ([`check_surface`]), which traces the new
//! openings.
//!
//! A cut ([`cut_surface`]) splits every triangle the plane crosses exactly
//! (new vertices on the crossed edges, shared by both triangles of an edge)
//! and drops the part on the side the plane's normal points to; vertices
//! within 10⁻⁹ of the bounding-box diagonal of the plane count as on it, so
//! no sliver triangles appear. If the cut leaves several pieces, the largest
//! is kept and the others are reported.

use super::error::VesselError;
use crate::math::Vec3;
use crate::mesh::surface::{bbox_diagonal, check_surface, CheckOptions, CheckedSurface, SurfaceMesh};
use std::collections::HashMap;

/// Thresholds of the cap detection (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CapOptions {
    /// Largest angle between a cap triangle's normal and the cap's first
    /// triangle's (degrees).
    pub max_normal_deviation_deg: f64,
    /// Smallest dihedral angle between the cap and each neighbouring
    /// triangle (degrees).
    pub min_crease_deg: f64,
    /// Smallest 4π·area/perimeter² (1 for a circle).
    pub min_compactness: f64,
    /// Smallest cap area as a share of the lumen cross-section just inside it.
    pub min_section_share: f64,
}

impl Default for CapOptions {
    /// 3°, 45°, 0.4, 0.5.
    fn default() -> Self {
        CapOptions {
            max_normal_deviation_deg: 3.0,
            min_crease_deg: 45.0,
            min_compactness: 0.4,
            min_section_share: 0.5,
        }
    }
}

/// A planar cap found on a surface.
#[derive(Debug, Clone, PartialEq)]
pub struct Cap {
    /// Its triangles (indices into the surface it was found on).
    pub triangles: Vec<usize>,
    /// Area-weighted centroid (m).
    pub centre: Vec3,
    /// Unit normal, pointing out of the lumen.
    pub normal: Vec3,
    /// Area (m²).
    pub area: f64,
}

/// A cutting plane: the side `normal` points to is removed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CutPlane {
    /// A point of the plane (m).
    pub point: Vec3,
    /// The normal (any length but zero), toward the part to remove.
    pub normal: Vec3,
}

/// A surface opened by cuts and cap removal.
#[derive(Debug, Clone)]
pub struct Opened {
    /// The checked surface with its openings.
    pub surface: CheckedSurface,
    /// The caps removed (triangle indices refer to the surface before removal).
    pub caps: Vec<Cap>,
    /// Per cut, the sizes (triangles) of the pieces dropped because they
    /// were disconnected from the largest.
    pub dropped_pieces: Vec<Vec<usize>>,
}

/// Unit normal and area of each triangle.
fn face_geometry(m: &SurfaceMesh) -> (Vec<Vec3>, Vec<f64>) {
    m.triangles
        .iter()
        .map(|t| {
            let p = t.map(|i| m.vertices[i as usize]);
            let c = (p[1] - p[0]).cross(&(p[2] - p[0]));
            let l = c.norm();
            (if l > 0.0 { c / l } else { Vec3::zeros() }, 0.5 * l)
        })
        .unzip()
}

/// For each triangle and each of its edges k (t[k] → t[k+1]), the
/// neighbouring triangle across it, if any.
fn edge_neighbours(m: &SurfaceMesh) -> Vec<[Option<u32>; 3]> {
    let mut by_edge: HashMap<(u32, u32), Vec<u32>> = HashMap::with_capacity(3 * m.triangles.len() / 2);
    for (t, tri) in m.triangles.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            by_edge.entry((a.min(b), a.max(b))).or_default().push(t as u32);
        }
    }
    m.triangles
        .iter()
        .enumerate()
        .map(|(t, tri)| {
            [0, 1, 2].map(|k| {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                by_edge[&(a.min(b), a.max(b))].iter().copied().find(|&u| u != t as u32)
            })
        })
        .collect()
}

/// Finds the planar caps of a surface (triangles oriented out of the lumen).
pub fn find_planar_caps(m: &SurfaceMesh, opts: &CapOptions) -> Vec<Cap> {
    let (normals, areas) = face_geometry(m);
    let adj = edge_neighbours(m);
    let nt = m.triangles.len();
    let cos_dev = opts.max_normal_deviation_deg.to_radians().cos();
    let cos_crease = opts.min_crease_deg.to_radians().cos();
    let mut seeds: Vec<usize> = (0..nt).collect();
    seeds.sort_by(|&a, &b| areas[b].total_cmp(&areas[a]));
    let mut region_of = vec![u32::MAX; nt];
    let mut caps = Vec::new();
    let mut stack = Vec::new();
    for (rid, &seed) in seeds.iter().enumerate() {
        if region_of[seed] != u32::MAX || areas[seed] == 0.0 {
            continue;
        }
        let n0 = normals[seed];
        let mut members = vec![seed];
        region_of[seed] = rid as u32;
        stack.push(seed);
        while let Some(t) = stack.pop() {
            for u in adj[t].iter().flatten() {
                let u = *u as usize;
                if region_of[u] == u32::MAX && normals[u].dot(&n0) >= cos_dev {
                    region_of[u] = rid as u32;
                    members.push(u);
                    stack.push(u);
                }
            }
        }
        if let Some(cap) = cap_candidate(
            m, &members, rid as u32, &region_of, &normals, &areas, &adj, cos_crease, opts,
        ) {
            caps.push(cap);
        }
    }
    // Candidates touching each other are faces of a polyhedron, not caps.
    let mut owner: HashMap<u32, Vec<usize>> = HashMap::new();
    for (c, cap) in caps.iter().enumerate() {
        let mut vs: Vec<u32> = cap.triangles.iter().flat_map(|&t| m.triangles[t]).collect();
        vs.sort_unstable();
        vs.dedup();
        for v in vs {
            owner.entry(v).or_default().push(c);
        }
    }
    let mut bad = vec![false; caps.len()];
    for cs in owner.values().filter(|cs| cs.len() > 1) {
        for &c in cs {
            bad[c] = true;
        }
    }
    caps.into_iter().zip(bad).filter(|(_, b)| !b).map(|(c, _)| c).collect()
}

#[allow(clippy::too_many_arguments)]
fn cap_candidate(
    m: &SurfaceMesh,
    members: &[usize],
    rid: u32,
    region_of: &[u32],
    normals: &[Vec3],
    areas: &[f64],
    adj: &[[Option<u32>; 3]],
    cos_crease: f64,
    opts: &CapOptions,
) -> Option<Cap> {
    let area: f64 = members.iter().map(|&t| areas[t]).sum();
    let mut normal: Vec3 = members.iter().map(|&t| normals[t] * areas[t]).sum();
    normal = normal.try_normalize(0.0)?;
    let centre: Vec3 = members
        .iter()
        .map(|&t| m.triangles[t].iter().map(|&i| m.vertices[i as usize]).sum::<Vec3>() / 3.0 * areas[t])
        .sum::<Vec3>()
        / area;
    let r_eq = (area / std::f64::consts::PI).sqrt();
    let mut verts: Vec<u32> = members.iter().flat_map(|&t| m.triangles[t]).collect();
    verts.sort_unstable();
    verts.dedup();
    if verts
        .iter()
        .any(|&v| (m.vertices[v as usize] - centre).dot(&normal).abs() > 0.01 * r_eq)
    {
        return None;
    }
    // Border edges, creases, Euler characteristic.
    let mut perimeter = 0.0;
    let mut interior_edges = 0usize;
    let mut border_edges = 0usize;
    for &t in members {
        let tri = m.triangles[t];
        for k in 0..3 {
            match adj[t][k] {
                None => return None, // touches an existing opening
                Some(u) if region_of[u as usize] == rid => interior_edges += 1,
                Some(u) => {
                    if normals[u as usize].dot(&normal) > cos_crease {
                        return None;
                    }
                    border_edges += 1;
                    perimeter += (m.vertices[tri[(k + 1) % 3] as usize] - m.vertices[tri[k] as usize]).norm();
                }
            }
        }
    }
    let edges = interior_edges / 2 + border_edges;
    if verts.len() as i64 - edges as i64 + members.len() as i64 != 1 || border_edges == 0 {
        return None;
    }
    if 4.0 * std::f64::consts::PI * area / (perimeter * perimeter) < opts.min_compactness {
        return None;
    }
    // The lumen's section just inside the cap, from the other triangles.
    let origin = centre - normal * (0.1 * r_eq);
    let reach2 = (3.0 * r_eq).powi(2);
    let mut section = 0.0;
    for (t, tri) in m.triangles.iter().enumerate() {
        if region_of[t] == rid {
            continue;
        }
        let p = tri.map(|i| m.vertices[i as usize]);
        let d = p.map(|q| (q - origin).dot(&normal));
        let mut pts = Vec::with_capacity(2);
        for k in 0..3 {
            let (a, b) = (k, (k + 1) % 3);
            if (d[a] < 0.0) != (d[b] < 0.0) {
                pts.push(p[a] + (p[b] - p[a]) * (d[a] / (d[a] - d[b])));
            }
        }
        if pts.len() != 2 || pts.iter().any(|q| (q - origin).norm_squared() > reach2) {
            continue;
        }
        let (mut a, mut b) = (pts[0] - origin, pts[1] - origin);
        if (b - a).dot(&normal.cross(&normals[t])) < 0.0 {
            std::mem::swap(&mut a, &mut b);
        }
        section += 0.5 * a.cross(&b).dot(&normal);
    }
    if section <= 0.0 || area < opts.min_section_share * section {
        return None;
    }
    Some(Cap {
        triangles: members.to_vec(),
        centre,
        normal,
        area,
    })
}

/// Cuts a surface with a plane, dropping the side the normal points to;
/// `index` only names the cut in errors. The result is not checked.
pub fn cut_surface(m: &SurfaceMesh, plane: &CutPlane, index: usize) -> Result<SurfaceMesh, VesselError> {
    let bad = |what: &str| VesselError::BadCut {
        index,
        point: plane.point,
        normal: plane.normal,
        what: what.to_string(),
    };
    if !plane.point.iter().chain(plane.normal.iter()).all(|x| x.is_finite()) {
        return Err(bad("the point and normal must be finite"));
    }
    let n = plane
        .normal
        .try_normalize(0.0)
        .ok_or_else(|| bad("the normal is zero"))?;
    let eps = 1e-9 * bbox_diagonal(&m.vertices);
    let d: Vec<f64> = m
        .vertices
        .iter()
        .map(|p| {
            let x = (p - plane.point).dot(&n);
            if x.abs() <= eps {
                0.0
            } else {
                x
            }
        })
        .collect();
    let used = |f: &dyn Fn(f64) -> bool| m.triangles.iter().flatten().any(|&v| f(d[v as usize]));
    if !used(&|x| x > 0.0) {
        return Err(bad(
            "the plane does not cross the surface (nothing lies on the side the normal points to)",
        ));
    }
    if !used(&|x| x < 0.0) {
        return Err(bad("the cut removes the whole surface (flip the normal?)"));
    }
    let mut out = SurfaceMesh {
        vertices: m.vertices.clone(),
        triangles: Vec::with_capacity(m.triangles.len()),
    };
    let mut on_edge: HashMap<(u32, u32), u32> = HashMap::new();
    for tri in &m.triangles {
        if tri.iter().all(|&v| d[v as usize] <= 0.0) {
            out.triangles.push(*tri);
            continue;
        }
        let mut poly: Vec<u32> = Vec::with_capacity(4);
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            let (da, db) = (d[a as usize], d[b as usize]);
            if da <= 0.0 {
                poly.push(a);
            }
            if (da < 0.0 && db > 0.0) || (da > 0.0 && db < 0.0) {
                let (lo, hi) = (a.min(b), a.max(b));
                let id = *on_edge.entry((lo, hi)).or_insert_with(|| {
                    let (pl, ph) = (m.vertices[lo as usize], m.vertices[hi as usize]);
                    let (dl, dh) = (d[lo as usize], d[hi as usize]);
                    out.vertices.push(pl + (ph - pl) * (dl / (dl - dh)));
                    (out.vertices.len() - 1) as u32
                });
                poly.push(id);
            }
        }
        for k in 1..poly.len().saturating_sub(1) {
            out.triangles.push([poly[0], poly[k], poly[k + 1]]);
        }
    }
    Ok(out)
}

/// Applies the cuts in order, then removes the planar caps; refuses a
/// surface left without an opening. Each step re-checks the surface
/// (without the self-intersection test: cutting and removing triangles
/// cannot create one).
pub fn open_surface(surface: &CheckedSurface, cuts: &[CutPlane], caps: &CapOptions) -> Result<Opened, VesselError> {
    let opts = CheckOptions {
        self_intersections: false,
        check_unit: false,
        keep_largest_body: true,
        ..CheckOptions::default()
    };
    let mut s = surface.clone();
    let mut dropped_pieces = Vec::new();
    for (i, plane) in cuts.iter().enumerate() {
        let cut = cut_surface(&s.mesh, plane, i)?;
        s = check_surface(&cut, &opts).map_err(|source| VesselError::Recheck {
            step: format!("cut {i}"),
            source,
        })?;
        dropped_pieces.push(s.report.dropped_bodies.clone());
    }
    let found = find_planar_caps(&s.mesh, caps);
    if !found.is_empty() {
        let mut remove = vec![false; s.mesh.triangles.len()];
        for c in &found {
            for &t in &c.triangles {
                remove[t] = true;
            }
        }
        let kept = SurfaceMesh {
            vertices: s.mesh.vertices.clone(),
            triangles: s
                .mesh
                .triangles
                .iter()
                .zip(&remove)
                .filter(|(_, r)| !**r)
                .map(|(t, _)| *t)
                .collect(),
        };
        let opts = CheckOptions {
            keep_largest_body: false,
            ..opts
        };
        s = check_surface(&kept, &opts).map_err(|source| VesselError::Recheck {
            step: format!("removing {} planar cap(s)", found.len()),
            source,
        })?;
    }
    if s.report.boundary_loops.is_empty() {
        return Err(VesselError::NoOpening {
            triangles: s.mesh.triangles.len(),
        });
    }
    Ok(Opened {
        surface: s,
        caps: found,
        dropped_pieces,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tube along z, optionally closed by fan caps around a centre vertex.
    fn tube(capped: bool) -> SurfaceMesh {
        let (r, len, around, rings) = (0.005, 0.04, 24usize, 9usize);
        let mut s = SurfaceMesh::open_tube(r, len, around, rings);
        let id = |j: usize, k: usize| (j * around + k % around) as u32;
        if capped {
            let c0 = s.vertices.len() as u32;
            s.vertices.push(Vec3::zeros());
            s.vertices.push(Vec3::new(0.0, 0.0, len));
            for k in 0..around {
                s.triangles.push([c0, id(0, k + 1), id(0, k)]);
                s.triangles.push([c0 + 1, id(rings - 1, k), id(rings - 1, k + 1)]);
            }
        }
        s
    }

    #[test]
    fn caps_of_a_tube_are_found_and_the_wall_is_not() {
        let caps = find_planar_caps(&tube(true), &CapOptions::default());
        assert_eq!(caps.len(), 2);
        for c in &caps {
            assert_eq!(c.triangles.len(), 24);
            assert!(c.normal.z.abs() > 1.0 - 1e-12);
            // The bottom cap faces -z at z = 0, the top one +z at z = 40 mm.
            let z = if c.normal.z > 0.0 { 0.04 } else { 0.0 };
            assert!((c.centre - Vec3::new(0.0, 0.0, z)).norm() < 1e-12, "{:?}", c.centre);
            assert!((c.area - 12.0 * 0.005f64.powi(2) * (std::f64::consts::TAU / 24.0).sin()).abs() < 1e-15);
        }
        assert!(find_planar_caps(&tube(false), &CapOptions::default()).is_empty());
    }

    #[test]
    fn a_cut_splits_crossing_triangles_on_the_plane() {
        let s = tube(false);
        let plane = CutPlane {
            point: Vec3::new(0.0, 0.0, 0.0123),
            normal: Vec3::new(0.0, 0.0, 1.0),
        };
        let cut = cut_surface(&s, &plane, 0).unwrap();
        let c = check_surface(
            &cut,
            &CheckOptions {
                keep_largest_body: true,
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(c.report.boundary_loops.len(), 2);
        let top = c.report.boundary_loops.iter().find(|l| l.centre.z > 0.01).unwrap();
        for &v in &top.vertices {
            assert!((c.mesh.vertices[v as usize].z - 0.0123).abs() < 1e-15);
        }
        assert!(top.normal.z > 1.0 - 1e-12);
        assert!(c.mesh.vertices.iter().all(|p| p.z <= 0.0123 + 1e-15));
        let e = cut_surface(
            &s,
            &CutPlane {
                normal: Vec3::zeros(),
                ..plane
            },
            3,
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("cut 3") && e.to_string().contains("normal is zero"),
            "{e}"
        );
    }
}
