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

/// One row of a hand script that works several hub-driven instruments with
/// one stylus: at `t_s` (s), instrument `instrument` (0, 1, … in the order
/// the switch button cycles them) has its hub at `inserted_m` (m) and
/// `roll_rad` (rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HubRow {
    /// Script time (s).
    pub t_s: f64,
    /// Which hub-driven instrument.
    pub instrument: usize,
    /// Its inserted length (m).
    pub inserted_m: f64,
    /// Its roll (rad).
    pub roll_rad: f64,
}

/// How long the scripted hand holds the switch button down (s).
pub const SWITCH_PRESS_S: f64 = 0.05;

/// A switching hand's script for the simulated Touch X: the stylus's
/// waypoints and gimbal angles (device frame) and its buttons, on one clock.
#[derive(Debug, Clone, PartialEq)]
pub struct SwitchingHand {
    /// Stylus waypoints.
    pub points: Vec<crate::haptics::touchx::Waypoint>,
    /// Gimbal angles.
    pub gimbal: Vec<crate::haptics::touchx::GimbalWaypoint>,
    /// Buttons: (time s, buttons held from then on).
    pub buttons: Vec<(f64, u32)>,
}

/// The stylus motions, gimbal angles and button presses that drive
/// hub-driven instruments through `rows` with one stylus, each
/// instrument's hub mapped from the stylus by `drive`
/// ([`crate::wire::HubDrive`]), instrument `k` starting at `start[k]`
/// (inserted m, roll rad). Instrument 0 is active at the start and follows
/// the stylus's absolute position (`drive.inserted_at_origin_m`); a row
/// naming another instrument than the active one presses the switch button
/// ([`crate::service::instrument::SWITCH_BUTTON`]) at its time, for
/// [`SWITCH_PRESS_S`], with the stylus still: the newly active instrument
/// takes the stylus up where it is ([`crate::wire::HubDrive::engage`]), so
/// such a row must hold that instrument where it was left (its previous
/// row, or its start). Between rows of one instrument the hub moves
/// linearly (as the eased stylus moves it). Errors name the row.
pub fn switching_hand(
    rows: &[HubRow],
    drive: &crate::wire::DriveParams,
    start: &[(f64, f64)],
) -> Result<SwitchingHand, String> {
    use crate::haptics::touchx::{GimbalWaypoint, Waypoint};
    let axis = Vec3::from(drive.axis)
        .try_normalize(1e-12)
        .ok_or("drive.axis is zero")?;
    if drive.insertion_scale <= 0.0 || start.is_empty() {
        return Err("the drive's insertion_scale must be positive, with one instrument at least".into());
    }
    let roll_scale = drive.roll_scale;
    // The stylus (position, unwrapped roll) and, for the active
    // instrument, where it took the stylus up: (stylus, hub) at the anchor.
    let mut held: Vec<(f64, f64)> = start.to_vec();
    let mut active = 0usize;
    let mut stylus = drive.stylus_at(start[0].0);
    let mut stylus_roll = 0.0;
    let mut anchor = (stylus, stylus_roll, start[0].0, start[0].1);
    let mut out = SwitchingHand {
        points: Vec::new(),
        gimbal: Vec::new(),
        buttons: Vec::new(),
    };
    let mut last_t = f64::NEG_INFINITY;
    let mut last_press = f64::NEG_INFINITY;
    for (k, r) in rows.iter().enumerate() {
        if r.t_s.partial_cmp(&last_t) != Some(std::cmp::Ordering::Greater) {
            return Err(format!("row {k}: time {} s must be after the previous row's", r.t_s));
        }
        let Some(h) = held.get(r.instrument).copied() else {
            return Err(format!(
                "row {k}: instrument {}: there are {} (0 to {})",
                r.instrument,
                held.len(),
                held.len() - 1
            ));
        };
        if r.instrument != active {
            if (r.inserted_m - h.0).abs() > 1e-9 || (r.roll_rad - h.1).abs() > 1e-9 {
                return Err(format!(
                    "row {k}: switching to instrument {} at {} s: it takes the stylus up where it was left, \
                     at {} m and {} rad; give those values here and move it in the rows after",
                    r.instrument, r.t_s, h.0, h.1
                ));
            }
            if r.t_s - last_press < 2.0 * SWITCH_PRESS_S {
                return Err(format!(
                    "row {k}: a switch at {} s, less than {} s after the previous one",
                    r.t_s,
                    2.0 * SWITCH_PRESS_S
                ));
            }
            active = r.instrument;
            anchor = (stylus, stylus_roll, h.0, h.1);
            out.buttons.push((r.t_s, super::instrument::SWITCH_BUTTON));
            out.buttons.push((r.t_s + SWITCH_PRESS_S, 0));
            last_press = r.t_s;
        } else {
            stylus = anchor.0 + axis * ((r.inserted_m - anchor.2) / drive.insertion_scale);
            if roll_scale != 0.0 {
                stylus_roll = anchor.1 + (r.roll_rad - anchor.3) / roll_scale;
            }
        }
        held[active] = (r.inserted_m, r.roll_rad);
        // The first row's roll is the instrument's start: the stylus roll
        // counts from there.
        let mut angles = [0.0; 3];
        if let Some(a) = angles.get_mut(drive.roll_index) {
            *a = stylus_roll;
        }
        out.points.push(Waypoint {
            t_s: r.t_s,
            position: stylus,
        });
        out.gimbal.push(GimbalWaypoint {
            t_s: r.t_s,
            angles_rad: angles,
        });
        last_t = r.t_s;
    }
    if out.points.is_empty() {
        out.points.push(Waypoint {
            t_s: 0.0,
            position: stylus,
        });
        out.gimbal.push(GimbalWaypoint {
            t_s: 0.0,
            angles_rad: [0.0; 3],
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::{DriveParams, HubDrive, WireParams};

    /// The scripted stylus, fed through two hub drives with the loop's
    /// selector, puts each instrument where the script says, and the one
    /// not worked holds.
    #[test]
    fn a_switching_script_drives_each_instrument_where_its_rows_say() {
        use crate::haptics::device::DeviceSample;
        use crate::service::instrument::Selector;
        let wire = WireParams::default();
        let d: DriveParams = wire.drive;
        let row = |t_s, instrument, inserted_m, roll_rad| HubRow {
            t_s,
            instrument,
            inserted_m,
            roll_rad,
        };
        let rows = [
            row(0.0, 0, 0.20, 0.0),
            row(1.0, 0, 0.23, 0.5),
            row(1.5, 1, 0.18, 0.0),
            row(2.5, 1, 0.21, -0.4),
            row(3.0, 0, 0.23, 0.5),
            row(4.0, 0, 0.215, 0.5),
        ];
        let hand = switching_hand(&rows, &d, &[(0.20, 0.0), (0.18, 0.0)]).unwrap();
        assert_eq!(hand.buttons, vec![(1.5, 1), (1.55, 0), (3.0, 1), (3.05, 0)]);
        // Sample the script as the simulated device would (cosine-eased
        // between rows, so the stylus is still at each row) and drive.
        let at = |t: f64| {
            let p = &hand.points;
            let k = p.iter().rposition(|w| w.t_s <= t).unwrap();
            let (a, b) = (&p[k], &p[(k + 1).min(p.len() - 1)]);
            let g = &hand.gimbal;
            let s = if b.t_s > a.t_s {
                let u = ((t - a.t_s) / (b.t_s - a.t_s)).min(1.0);
                0.5 * (1.0 - (std::f64::consts::PI * u).cos())
            } else {
                0.0
            };
            let buttons = hand.buttons.iter().rev().find(|b| b.0 <= t).map_or(0, |b| b.1);
            DeviceSample {
                position: a.position + (b.position - a.position) * s,
                buttons,
                gimbal_rad: [
                    0.0,
                    0.0,
                    g[k].angles_rad[2] + (g[(k + 1).min(g.len() - 1)].angles_rad[2] - g[k].angles_rad[2]) * s,
                ],
                ..DeviceSample::REST
            }
        };
        let mut drives = [
            HubDrive::new(&wire, 0.20, 0.0).unwrap(),
            HubDrive::new(&wire, 0.18, 0.0).unwrap(),
        ];
        let mut sel = Selector::new([true, true]);
        let mut hubs = [(0.20, 0.0), (0.18, 0.0)];
        let mut t = 0.0;
        while t < 4.5 {
            let s = at(t);
            sel.update(Some(&s));
            for (k, dr) in drives.iter_mut().enumerate() {
                let h = sel.hand(k, Some(&s), t);
                if h.active {
                    if h.engaged {
                        dr.engage(&s);
                    }
                    let c = dr.command(&s, t);
                    hubs[k] = (c.inserted_m, c.roll_rad);
                }
            }
            t += 1e-3;
            if (t - 2.6).abs() < 5e-4 {
                assert!(
                    (hubs[0].0 - 0.23).abs() < 1e-6 && (hubs[0].1 - 0.5).abs() < 1e-6,
                    "the wire held: {hubs:?}"
                );
                assert!(
                    (hubs[1].0 - 0.21).abs() < 1e-6 && (hubs[1].1 + 0.4).abs() < 1e-6,
                    "{hubs:?}"
                );
            }
        }
        assert!(
            (hubs[0].0 - 0.215).abs() < 1e-6 && (hubs[0].1 - 0.5).abs() < 1e-6,
            "{hubs:?}"
        );
        assert!((hubs[1].0 - 0.21).abs() < 1e-6, "the catheter held: {hubs:?}");
        assert_eq!(sel.switches(), 2);
        // A switch row that moves the instrument it takes up is refused.
        let bad = [row(0.0, 0, 0.20, 0.0), row(1.0, 1, 0.25, 0.0)];
        let e = switching_hand(&bad, &d, &[(0.20, 0.0), (0.18, 0.0)]).unwrap_err();
        assert!(e.contains("row 1") && e.contains("0.18"), "{e}");
        let e = switching_hand(&[row(0.0, 2, 0.2, 0.0)], &d, &[(0.2, 0.0), (0.18, 0.0)]).unwrap_err();
        assert!(e.contains("instrument 2"), "{e}");
    }
}
