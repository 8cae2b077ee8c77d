//! Isotropic remeshing (mesh::vessel::remesh) on analytic surfaces, and the
//! built-in branched arch lumen (mesh::vessel::implicit).

use nvtmm::math::Vec3;
use nvtmm::mesh::surface::{check_surface, CheckOptions, SurfaceMesh};
use nvtmm::mesh::vessel::implicit::{
    label_vertices, lumen_surface, lumen_surface_with_vertices, ArchType, BranchedArchParams, LumenTree, SEGMENT_NAMES,
};
use nvtmm::mesh::vessel::remesh::{remesh, remesh_to_vertex_count, RemeshOptions, Remeshed};
use std::f64::consts::PI;

/// An open cylinder of radius r and length l along z, `na` rings of `nc`
/// vertices, normals outward.
fn cylinder(r: f64, l: f64, nc: usize, na: usize) -> SurfaceMesh {
    let mut vertices = Vec::new();
    for j in 0..na {
        for i in 0..nc {
            // Alternate rings are rotated by half a step (better triangles).
            let th = 2.0 * PI * (i as f64 + 0.5 * (j % 2) as f64) / nc as f64;
            vertices.push(Vec3::new(r * th.cos(), r * th.sin(), l * j as f64 / (na - 1) as f64));
        }
    }
    let id = |i: usize, j: usize| (j * nc + i % nc) as u32;
    let mut triangles = Vec::new();
    for j in 0..na - 1 {
        for i in 0..nc {
            triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    SurfaceMesh { vertices, triangles }
}

/// A sphere of radius r (an icosahedron subdivided `levels` times, vertices
/// pushed onto the sphere) with the cap z > h removed: one circular hole.
fn sphere_with_hole(r: f64, levels: usize, h: f64) -> SurfaceMesh {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut v: Vec<Vec3> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|p| Vec3::new(p[0], p[1], p[2]).normalize())
    .collect();
    let mut f: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut mid = std::collections::HashMap::new();
        let mut nf = Vec::with_capacity(f.len() * 4);
        let mut midpoint = |a: u32, b: u32, v: &mut Vec<Vec3>| -> u32 {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                v.push(((v[a as usize] + v[b as usize]) / 2.0).normalize());
                (v.len() - 1) as u32
            })
        };
        for [a, b, c] in f {
            let ab = midpoint(a, b, &mut v);
            let bc = midpoint(b, c, &mut v);
            let ca = midpoint(c, a, &mut v);
            nf.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        f = nf;
    }
    let keep: Vec<[u32; 3]> = f
        .into_iter()
        .filter(|t| t.iter().all(|&i| v[i as usize].z * r <= h))
        .collect();
    let mesh = SurfaceMesh {
        vertices: v.iter().map(|p| p * r).collect(),
        triangles: keep,
    };
    // Drop unused vertices (and orient outward) with the surface check.
    check_surface(&mesh, &CheckOptions::default()).unwrap().mesh
}

/// Checks a remeshed surface against its input and the target size.
/// `curvature_radius` bounds how far a flat triangle's centroid may lie from
/// the curved surface: about e² / (6 R) for an equilateral triangle of side e
/// with its corners on a sphere of radius R; e² / (4 R) leaves room for
/// uneven triangles.
fn check_remeshed(name: &str, input: &SurfaceMesh, out: &Remeshed, size: f64, curvature_radius: f64) {
    let s = out.stats;
    println!("{name}: {s:?}");
    assert!(
        (s.edge_mean - 1.0).abs() <= 0.10,
        "{name}: mean edge / size {}",
        s.edge_mean
    );
    assert!(s.min_angle_deg >= 20.0, "{name}: min angle {}", s.min_angle_deg);
    // Vertices lie on the input surface (to rounding), centroids within the
    // chord error of the longest edge.
    assert!(
        s.max_vertex_distance <= 1e-9 * size,
        "{name}: {}",
        s.max_vertex_distance
    );
    let e = s.edge_max * size;
    assert!(
        s.max_centroid_distance <= e * e / (4.0 * curvature_radius),
        "{name}: centroid distance {}",
        s.max_centroid_distance
    );
    let a = check_surface(input, &CheckOptions::default()).unwrap().report;
    let b = check_surface(&out.mesh, &CheckOptions::default()).unwrap().report;
    assert_eq!(a.boundary_loops.len(), b.boundary_loops.len(), "{name}: loops");
    for la in &a.boundary_loops {
        let lb = b
            .boundary_loops
            .iter()
            .min_by(|x, y| (x.centre - la.centre).norm().total_cmp(&(y.centre - la.centre).norm()))
            .unwrap();
        assert!(
            (la.centre - lb.centre).norm() <= 0.02 * size,
            "{name}: loop centre {:?} vs {:?}",
            la.centre,
            lb.centre
        );
        // A loop of n vertices on a circle encloses sin(2π/n)/(2π/n) of the
        // circle's area: the resampled loop may lose that much, plus 1 % for
        // the input loop's own zigzag (the sphere's hole follows its facets).
        let x = 2.0 * PI / lb.vertices.len() as f64;
        let chord_loss = 1.0 - x.sin() / x;
        assert!(
            (lb.area / la.area - 1.0).abs() <= chord_loss + 0.01,
            "{name}: loop area {} vs {}",
            lb.area,
            la.area
        );
        // Resampled to the size along the loop.
        let per_edge = lb.perimeter / lb.vertices.len() as f64 / size;
        assert!((0.8..=1.34).contains(&per_edge), "{name}: loop edge / size {per_edge}");
    }
    // Same orientation as the input: enclosed volume of the same sign.
    assert!(
        b.volume > 0.0 && (b.volume / a.volume - 1.0).abs() < 0.02,
        "{name}: volume"
    );
    assert_eq!(b.flipped, 0, "{name}: orientation kept");
}

#[test]
fn cylinder_remeshes_to_the_target_size() {
    // 10 mm radius, 60 mm long, finely tessellated (≈ 0.5 mm edges).
    let input = cylinder(0.01, 0.06, 128, 121);
    let size = 0.003;
    let out = remesh(&input, &|_| size, &RemeshOptions::default()).unwrap();
    check_remeshed("cylinder", &input, &out, size, 0.01);
    // Vertices on the cylinder (the input's facets are 0.3 % of r inside it).
    for p in &out.mesh.vertices {
        let r = (p.x * p.x + p.y * p.y).sqrt();
        assert!((r / 0.01 - 1.0).abs() < 0.005, "radius {r}");
    }
}

#[test]
fn sphere_with_a_hole_remeshes_to_the_target_size() {
    let input = sphere_with_hole(0.02, 5, 0.014);
    let size = 0.004;
    let out = remesh(&input, &|_| size, &RemeshOptions::default()).unwrap();
    check_remeshed("sphere", &input, &out, size, 0.02);
}

#[test]
fn vertex_count_is_reached_within_two_percent() {
    let input = cylinder(0.01, 0.06, 128, 121);
    for target in [400usize, 1500] {
        let (size, out) =
            remesh_to_vertex_count(&input, target, &|_| f64::INFINITY, &RemeshOptions::default(), 0.02).unwrap();
        let n = out.mesh.vertices.len();
        println!("target {target}: {n} vertices at size {size:.4e}, {:?}", out.stats);
        assert!((n as f64 / target as f64 - 1.0).abs() <= 0.02, "{target}: {n}");
    }
}

/// The branched arch's lumen surface: a clean open surface with the five
/// named openings where the tree ends, of the vessels' areas, and labels.
fn check_arch(tree: &LumenTree, size: f64) -> nvtmm::mesh::vessel::implicit::LumenSurface {
    let s = lumen_surface(tree, size).unwrap();
    println!("arch at size {size}: {:?}", s.stats);
    // One body, manifold, oriented, no self-intersection.
    let checked = check_surface(&s.mesh, &CheckOptions::default()).unwrap();
    assert_eq!(checked.report.flipped, 0);
    assert_eq!(checked.report.boundary_loops.len(), 5);
    assert!(checked.report.volume > 0.0);
    let names: Vec<&str> = s.openings.iter().map(|o| o.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "inlet",
            "outlet_descending",
            "outlet_brachiocephalic",
            "outlet_left_common_carotid",
            "outlet_left_subclavian"
        ]
    );
    for (o, e) in s.openings.iter().zip(tree.ends()) {
        let b = &o.boundary;
        // Centre on the end of the centreline, the loop in the end plane,
        // the normal along the centreline, out of the lumen.
        assert!(
            (b.centre - e.centre).norm() < 0.02 * e.radius,
            "{}: centre {:?}",
            o.name,
            b.centre
        );
        assert!(b.normal.dot(&e.normal) > 0.999, "{}: normal {:?}", o.name, b.normal);
        for &v in &b.vertices {
            let p = s.mesh.vertices[v as usize];
            assert!(
                (p - e.centre).dot(&e.normal).abs() < 1e-9,
                "{}: vertex off the end plane",
                o.name
            );
        }
        // Area of the inscribed polygon of as many vertices, within 2 %.
        let n = b.vertices.len();
        assert!(n >= 8, "{}: {n} vertices around", o.name);
        let x = 2.0 * PI / n as f64;
        let polygon = PI * e.radius * e.radius * x.sin() / x;
        assert!(
            (b.area / polygon - 1.0).abs() < 0.02,
            "{}: area {} vs {polygon}",
            o.name,
            b.area
        );
    }
    // Labels: all four segments present, and each opening's ring carries its
    // vessel's label.
    assert_eq!(s.labels.len(), s.mesh.vertices.len());
    for (i, name) in SEGMENT_NAMES.iter().enumerate() {
        let n = s.labels.iter().filter(|&&l| l as usize == i).count();
        assert!(n >= 8, "{name}: {n} vertices");
    }
    for (o, e) in s.openings.iter().zip(tree.ends()) {
        for &v in &o.boundary.vertices {
            assert_eq!(s.labels[v as usize] as usize, e.segment, "{}", o.name);
        }
    }
    assert_eq!(label_vertices(tree, &s.mesh.vertices), s.labels);
    s
}

#[test]
fn branched_arch_lumen_is_clean_with_five_named_openings() {
    let tree = LumenTree::arch(&BranchedArchParams::default()).unwrap();
    check_arch(&tree, 0.003);
}

#[test]
fn every_branch_keeps_eight_vertices_around_at_a_coarse_size() {
    let tree = LumenTree::arch(&BranchedArchParams::default()).unwrap();
    // 10 mm is coarser than every branch's circumference / 8.
    let s = check_arch(&tree, 0.010);
    // Half-way along each branch, the vertices in a slab one local size
    // thick leave no angular gap wider than two eighths of a turn.
    for (b, seg) in tree.segments.iter().enumerate().skip(1) {
        let (o, end) = (seg.points[0], *seg.points.last().unwrap());
        let axis = (end - o).normalize();
        let mid = o + (end - o) * 0.6;
        let r = seg.radii[0];
        let slab = 2.0 * PI * r / 8.0;
        let u = axis.cross(&Vec3::z()).normalize();
        let w = axis.cross(&u);
        let mut ang: Vec<f64> = s
            .mesh
            .vertices
            .iter()
            .zip(&s.labels)
            .filter(|(p, &l)| l as usize == b && (*p - mid).dot(&axis).abs() <= slab / 2.0)
            .map(|(p, _)| {
                let d = p - mid;
                d.dot(&w).atan2(d.dot(&u))
            })
            .collect();
        ang.sort_by(f64::total_cmp);
        assert!(ang.len() >= 8, "{}: {} vertices in the slab", seg.name, ang.len());
        let mut gap: f64 = ang[0] + 2.0 * PI - ang[ang.len() - 1];
        for k in 1..ang.len() {
            gap = gap.max(ang[k] - ang[k - 1]);
        }
        assert!(gap <= 2.0 * (2.0 * PI / 8.0) + 1e-9, "{}: angular gap {gap}", seg.name);
    }
}

#[test]
fn arch_types_lower_the_brachiocephalic_origin() {
    let mut prev: Option<(f64, f64)> = None;
    for t in [ArchType::I, ArchType::II, ArchType::III] {
        let p = BranchedArchParams {
            arch_type: t,
            ..BranchedArchParams::default()
        };
        let tree = LumenTree::arch(&p).unwrap();
        // Depth of the brachiocephalic ostium (where its axis leaves the
        // aorta) below the top of the arch's outer curvature, in carotid
        // diameters.
        let aorta = &tree.segments[0];
        let top = aorta
            .points
            .iter()
            .zip(&aorta.radii)
            .map(|(p, r)| p.z + r)
            .fold(f64::NEG_INFINITY, f64::max);
        let b = &tree.segments[1];
        let axis = (b.points[1] - b.points[0]).normalize();
        let aorta_only = LumenTree {
            segments: vec![aorta.clone()],
            blend: 0.0,
        };
        let mut t_in = 0.0;
        while aorta_only.sdf(&(b.points[0] + axis * t_in)) < 0.0 {
            t_in += 1e-5;
        }
        let ostium = b.points[0] + axis * t_in;
        let depth = (top - ostium.z) / (2.0 * tree.segments[2].radii[0]);
        let want = t.depth_in_carotid_diameters();
        println!("{t:?}: depth {depth:.3} carotid diameters");
        assert!((depth - want).abs() < 0.01, "{t:?}: {depth}");
        let o = b.points[0];
        if let Some((d0, z0)) = prev {
            assert!(depth > d0 && o.z < z0);
        }
        prev = Some((depth, o.z));
        // Each type meshes.
        if t != ArchType::I {
            let s = lumen_surface(&tree, 0.004).unwrap();
            assert_eq!(s.openings.len(), 5);
        }
    }
}

#[test]
fn arch_surface_reaches_a_vertex_count() {
    let tree = LumenTree::arch(&BranchedArchParams::default()).unwrap();
    let (size, s) = lumen_surface_with_vertices(&tree, 2000, 0.02).unwrap();
    let n = s.mesh.vertices.len();
    println!("2000 vertices: {n} at size {size:.4e}");
    assert!((n as f64 / 2000.0 - 1.0).abs() <= 0.02, "{n}");
}
