//! The simulated hand's script: where the scripted press of the default
//! run touches the vessel and the waypoints the simulated Touch X follows.

use super::config::InteractionConfig;
use crate::math::Vec3;
use crate::mesh::TetMesh;
use crate::scene::Scene;

/// The scripted press for the simulated device: approach a wall point along
/// its outward normal, press, slide along the wall, release. Returns the
/// scene-frame waypoints (time s, tool centre m).
pub fn scripted_press(
    point: Vec3,
    normal: Vec3,
    tangent: Vec3,
    cfg: &InteractionConfig,
    radius: f64,
    seconds: f64,
) -> Vec<(f64, Vec3)> {
    let out = point + normal * (radius + cfg.clearance_m);
    let pressed = point + normal * (radius - cfg.press_depth_m);
    let slid = pressed + tangent * cfg.slide_m;
    let slid_out = out + tangent * cfg.slide_m;
    let ph = cfg.phases_s;
    let mut pts = Vec::new();
    let mut t = 0.0;
    loop {
        pts.push((t, out));
        t += ph[0];
        pts.push((t, out));
        t += ph[1];
        pts.push((t, pressed));
        t += ph[2];
        pts.push((t, pressed));
        t += ph[3];
        pts.push((t, slid));
        t += ph[4];
        pts.push((t, slid));
        t += ph[5];
        pts.push((t, slid_out));
        t += 0.5;
        if !cfg.repeat || t > seconds + 1.0 {
            pts.push((t, out));
            break;
        }
    }
    pts
}

/// The wall point the script presses: the surface node nearest the contact
/// region's centre (or the highest outer-wall node), its outward normal and
/// a tangent.
pub fn press_target(mesh: &TetMesh, scene: &Scene) -> (u32, Vec3, Vec3, Vec3) {
    let rest = mesh.rest();
    let normals = mesh.surface_vertex_normals();
    let candidates: Vec<u32> = match mesh.node_set("outer_wall") {
        Some(s) if !s.is_empty() => s.to_vec(),
        _ => mesh.surface_nodes(),
    };
    let center = scene
        .reduced
        .as_ref()
        .and_then(|r| r.contact_region.as_ref())
        .and_then(|c| c.center)
        .map(Vec3::from);
    let node = candidates
        .iter()
        .copied()
        .min_by(|&a, &b| {
            let key = |i: u32| match center {
                Some(c) => (rest[i as usize] - c).norm(),
                None => -rest[i as usize].z,
            };
            key(a).total_cmp(&key(b))
        })
        .unwrap_or(0);
    let n = normals.get(node as usize).copied().unwrap_or(Vec3::z());
    let n = if n.norm() > 0.5 { n } else { Vec3::z() };
    // A tangent: the horizontal direction orthogonal to n closest to x.
    let mut t = Vec3::x() - n * n.x;
    if t.norm() < 1e-6 {
        t = Vec3::y() - n * n.y;
    }
    (node, rest[node as usize], n, t.normalize())
}
