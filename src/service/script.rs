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

/// One step of a hand script that may watch the simulation (the rows of
/// `catheter.script`, docs/INSTRUMENTS.md "Scripting the switch" and
/// "A hand that watches").
#[derive(Debug, Clone, PartialEq)]
pub enum HandStep {
    /// A timed row: instrument `row.instrument`'s hub at `row.inserted_m`
    /// and `row.roll_rad` at script time `row.t_s`; naming the other
    /// instrument than the active one switches to it (it must then hold
    /// it where it was left).
    Timed(HubRow),
    /// Press the switch button at script time `t_s`: instrument `to`
    /// becomes active where it was left, whatever that is.
    Switch {
        /// Script time (s).
        t_s: f64,
        /// The instrument made active.
        to: usize,
    },
    /// From script time `t_s`, move the active instrument's hub toward
    /// `inserted_m` and `roll_rad` at `speed_m_s` and `roll_speed_rad_s`
    /// until `until` holds or `within_s` has passed; the script's clock
    /// stands still meanwhile, so the rows after it keep their spacing.
    Watch(Watch),
}

/// A watched move ([`HandStep::Watch`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Watch {
    /// Script time the move starts (s).
    pub t_s: f64,
    /// The instrument moved (the active one).
    pub instrument: usize,
    /// The farthest the hub goes (m); None: its insertion holds.
    pub inserted_m: Option<f64>,
    /// The farthest the hub turns (rad); None: its roll holds.
    pub roll_rad: Option<f64>,
    /// Insertion speed at the hub (m/s).
    pub speed_m_s: f64,
    /// Roll speed at the hub (rad/s).
    pub roll_speed_rad_s: f64,
    /// Longest the move waits for its condition (s).
    pub within_s: f64,
    /// The condition that ends it.
    pub until: Until,
    /// The row the script goes on from when the condition is met (a later
    /// one; None: the next row), to skip the tries a miss would need.
    pub then_row: Option<usize>,
}

/// What a watched move waits for, on what the hand sees of instrument
/// `rod`'s tip ([`TipWatch`]).
#[derive(Debug, Clone, PartialEq)]
pub enum Until {
    /// The tip in segment `segment`, the rod running at least `depth_m` in
    /// it back from the tip.
    In {
        /// The watched instrument.
        rod: usize,
        /// The segment's name.
        segment: String,
        /// Depth (m).
        depth_m: f64,
    },
    /// The tip's bend pointing toward segment `segment`'s opening within
    /// `within_rad` (the angle about the rod's axis behind the tip between
    /// the tip's sideways offset and the opening's, [`TipWatcher`]).
    PointsTo {
        /// The watched instrument.
        rod: usize,
        /// The segment's name.
        segment: String,
        /// Tolerance (rad).
        within_rad: f64,
    },
}

/// Default insertion speed of a watched move at the hub (m/s).
pub const WATCH_SPEED_M_S: f64 = 0.02;
/// Default roll speed of a watched move at the hub (rad/s).
pub const WATCH_ROLL_SPEED_RAD_S: f64 = 1.0;
/// Default longest wait of a watched move (s).
pub const WATCH_WITHIN_S: f64 = 10.0;
/// Default tolerance of a pointing condition (degrees).
pub const WATCH_WITHIN_DEG: f64 = 20.0;

/// A number of a script row's table or array (integers accepted).
fn number(v: &toml::Value) -> Option<f64> {
    match v {
        toml::Value::Float(x) => Some(*x),
        toml::Value::Integer(i) => Some(*i as f64),
        _ => None,
    }
}

/// An error of a script row: (the key, e.g. `[3].speed_m_s`, the message).
pub type RowError = (String, String);

/// Parses the rows of a hand script: each an array `[t s, instrument,
/// inserted m, roll rad]` (a [`HandStep::Timed`] row), a table
/// `{ t_s, switch_to }` ([`HandStep::Switch`]) or a table of a watched move
/// (`t_s`, `instrument`, `inserted_m`, `roll_rad`, `speed_m_s`,
/// `roll_speed_rad_s`, `within_s`, and `until_in` with `depth_m`, or
/// `until_points_to` with `within_deg`; `watch`: the instrument whose tip
/// is watched, the moved one by default). `instruments`: how many;
/// `max_inserted[i]`: the most instrument `i` inserts. Errors name the row
/// and the field.
pub fn parse_steps(rows: &[toml::Value], instruments: usize, max_inserted: &[f64]) -> Result<Vec<HandStep>, RowError> {
    let mut out = Vec::with_capacity(rows.len());
    let inst = |k: usize, field: &str, v: f64| -> Result<usize, RowError> {
        if v.fract() != 0.0 || v < 0.0 || v >= instruments as f64 {
            return Err((
                format!("[{k}]{field}"),
                format!(
                    "{v}: the instrument is 0 (the guidewire){}",
                    if instruments > 1 { " or 1 (the catheter)" } else { "" }
                ),
            ));
        }
        Ok(v as usize)
    };
    let in_range = |key: String, v: f64, lo: f64, hi: f64, unit: &str| -> Result<f64, RowError> {
        if !v.is_finite() || v < lo || v > hi {
            return Err((key, format!("{v} {unit}: must be in [{lo}, {hi}]")));
        }
        Ok(v)
    };
    for (k, row) in rows.iter().enumerate() {
        match row {
            toml::Value::Array(a) => {
                if a.len() != 4 {
                    return Err((
                        format!("[{k}]"),
                        format!(
                            "a timed row has 4 numbers [t s, instrument, inserted m, roll rad], not {}",
                            a.len()
                        ),
                    ));
                }
                let mut v = [0.0; 4];
                for (j, x) in a.iter().enumerate() {
                    v[j] = number(x).ok_or_else(|| (format!("[{k}][{j}]"), format!("{x}: must be a number")))?;
                }
                let t_s = in_range(format!("[{k}][0]"), v[0], 0.0, 86_400.0, "s")?;
                let instrument = inst(k, "[1]", v[1])?;
                let inserted_m = in_range(format!("[{k}][2]"), v[2], 0.0, max_inserted[instrument], "m")?;
                let roll_rad = in_range(format!("[{k}][3]"), v[3], -1000.0, 1000.0, "rad")?;
                out.push(HandStep::Timed(HubRow {
                    t_s,
                    instrument,
                    inserted_m,
                    roll_rad,
                }));
            }
            toml::Value::Table(t) => {
                let get = |field: &str| -> Result<Option<f64>, RowError> {
                    match t.get(field) {
                        None => Ok(None),
                        Some(x) => number(x)
                            .map(Some)
                            .ok_or_else(|| (format!("[{k}].{field}"), format!("{x}: must be a number"))),
                    }
                };
                let name = |field: &str| -> Result<Option<String>, RowError> {
                    match t.get(field) {
                        None => Ok(None),
                        Some(toml::Value::String(s)) if !s.trim().is_empty() => Ok(Some(s.clone())),
                        Some(x) => Err((
                            format!("[{k}].{field}"),
                            format!("{x}: must name a segment of the mesh (e.g. \"left_common_carotid\")"),
                        )),
                    }
                };
                let t_s = get("t_s")?.ok_or_else(|| (format!("[{k}].t_s"), "missing: the row's time (s)".into()))?;
                let t_s = in_range(format!("[{k}].t_s"), t_s, 0.0, 86_400.0, "s")?;
                if let Some(to) = get("switch_to")? {
                    if let Some(extra) = t.keys().find(|f| *f != "t_s" && *f != "switch_to") {
                        return Err((
                            format!("[{k}].{extra}"),
                            "a switch row has t_s and switch_to only".into(),
                        ));
                    }
                    let to = inst(k, ".switch_to", to)?;
                    out.push(HandStep::Switch { t_s, to });
                    continue;
                }
                const FIELDS: [&str; 13] = [
                    "then_row",
                    "t_s",
                    "instrument",
                    "inserted_m",
                    "roll_rad",
                    "speed_m_s",
                    "roll_speed_rad_s",
                    "within_s",
                    "until_in",
                    "depth_m",
                    "until_points_to",
                    "within_deg",
                    "watch",
                ];
                if let Some(extra) = t.keys().find(|f| !FIELDS.contains(&f.as_str())) {
                    return Err((
                        format!("[{k}].{extra}"),
                        format!(
                            "unknown field: a watched row has {} (a switch row t_s and switch_to)",
                            FIELDS.join(", ")
                        ),
                    ));
                }
                let instrument = get("instrument")?
                    .ok_or_else(|| (format!("[{k}].instrument"), "missing: the instrument moved".into()))?;
                let instrument = inst(k, ".instrument", instrument)?;
                let rod = match get("watch")? {
                    Some(w) => inst(k, ".watch", w)?,
                    None => instrument,
                };
                let inserted_m = match get("inserted_m")? {
                    Some(v) => Some(in_range(
                        format!("[{k}].inserted_m"),
                        v,
                        0.0,
                        max_inserted[instrument],
                        "m",
                    )?),
                    None => None,
                };
                let roll_rad = match get("roll_rad")? {
                    Some(v) => Some(in_range(format!("[{k}].roll_rad"), v, -1000.0, 1000.0, "rad")?),
                    None => None,
                };
                if inserted_m.is_none() && roll_rad.is_none() {
                    return Err((
                        format!("[{k}].inserted_m"),
                        "a watched row moves the hub: give inserted_m (the farthest it goes), roll_rad, or both".into(),
                    ));
                }
                let speed_m_s = in_range(
                    format!("[{k}].speed_m_s"),
                    get("speed_m_s")?.unwrap_or(WATCH_SPEED_M_S),
                    1e-4,
                    0.1,
                    "m/s",
                )?;
                let roll_speed_rad_s = in_range(
                    format!("[{k}].roll_speed_rad_s"),
                    get("roll_speed_rad_s")?.unwrap_or(WATCH_ROLL_SPEED_RAD_S),
                    0.01,
                    10.0,
                    "rad/s",
                )?;
                let within_s = in_range(
                    format!("[{k}].within_s"),
                    get("within_s")?.unwrap_or(WATCH_WITHIN_S),
                    0.01,
                    600.0,
                    "s",
                )?;
                let until = match (name("until_in")?, name("until_points_to")?) {
                    (Some(segment), None) => {
                        if t.contains_key("within_deg") {
                            return Err((format!("[{k}].within_deg"), "goes with until_points_to".into()));
                        }
                        Until::In {
                            rod,
                            segment,
                            depth_m: in_range(format!("[{k}].depth_m"), get("depth_m")?.unwrap_or(0.0), 0.0, 0.5, "m")?,
                        }
                    }
                    (None, Some(segment)) => {
                        if t.contains_key("depth_m") {
                            return Err((format!("[{k}].depth_m"), "goes with until_in".into()));
                        }
                        let deg = in_range(
                            format!("[{k}].within_deg"),
                            get("within_deg")?.unwrap_or(WATCH_WITHIN_DEG),
                            0.5,
                            180.0,
                            "degrees",
                        )?;
                        Until::PointsTo {
                            rod,
                            segment,
                            within_rad: deg.to_radians(),
                        }
                    }
                    (Some(_), Some(_)) => {
                        return Err((
                            format!("[{k}].until_points_to"),
                            "a watched row waits for one condition: until_in or until_points_to".into(),
                        ))
                    }
                    (None, None) => {
                        return Err((
                            format!("[{k}].until_in"),
                            "missing: a table row is a switch (switch_to) or a watched move, which waits for \
                             until_in (a segment) or until_points_to (a segment's opening)"
                                .into(),
                        ))
                    }
                };
                let then_row = match get("then_row")? {
                    None => None,
                    Some(j) if j.fract() == 0.0 && j > k as f64 && j <= rows.len() as f64 => Some(j as usize),
                    Some(j) => {
                        return Err((
                            format!("[{k}].then_row"),
                            format!(
                                "{j}: a later row ({} to {}, the last meaning the script's end)",
                                k + 1,
                                rows.len()
                            ),
                        ))
                    }
                };
                out.push(HandStep::Watch(Watch {
                    then_row,
                    t_s,
                    instrument,
                    inserted_m,
                    roll_rad,
                    speed_m_s,
                    roll_speed_rad_s,
                    within_s,
                    until,
                }));
            }
            other => {
                return Err((
                    format!("[{k}]"),
                    format!(
                        "{other}: a row is an array [t s, instrument, inserted m, roll rad] or a table (a switch or a watched move)"
                    ),
                ))
            }
        }
    }
    Ok(out)
}

/// The timed rows a script's steps amount to if every watched move ran to
/// its limits at its start time and every switch held the instrument where
/// it was planned to be: what the configuration checks (order, switches,
/// the stylus's workspace through [`switching_hand`]) and what a hand
/// without eyes would do. `start`: each instrument's hub at the start.
/// Errors name the row.
pub fn planned_rows(steps: &[HandStep], start: &[(f64, f64)]) -> Result<Vec<HubRow>, String> {
    let mut held: Vec<(f64, f64)> = start.to_vec();
    let mut watched = vec![None; start.len()];
    let mut active = 0usize;
    let mut out = Vec::with_capacity(steps.len());
    for (k, s) in steps.iter().enumerate() {
        let row = match s {
            HandStep::Timed(r) => {
                if r.instrument != active {
                    if let Some(j) = watched.get(r.instrument).copied().flatten() {
                        return Err(format!(
                            "row {k}: instrument {} is where its watched row {j} stopped it, unknown before the \
                             run: switch to it with {{ t_s = {}, switch_to = {} }}",
                            r.instrument, r.t_s, r.instrument
                        ));
                    }
                    active = r.instrument;
                }
                if let Some(w) = watched.get_mut(r.instrument) {
                    *w = None;
                }
                *r
            }
            HandStep::Switch { t_s, to } => {
                let h = *held
                    .get(*to)
                    .ok_or_else(|| format!("row {k}: instrument {to}: there are {}", held.len()))?;
                if *to == active {
                    return Err(format!("row {k}: instrument {to} is already the active one"));
                }
                active = *to;
                HubRow {
                    t_s: *t_s,
                    instrument: *to,
                    inserted_m: h.0,
                    roll_rad: h.1,
                }
            }
            HandStep::Watch(w) => {
                if w.instrument != active {
                    return Err(format!(
                        "row {k}: a watched row moves the active instrument ({active}); switch to {} first",
                        w.instrument
                    ));
                }
                // The rows it may skip work the same instrument, so the
                // script goes on with the same one active either way.
                let skipped = steps.get(k + 1..w.then_row.unwrap_or(k + 1)).unwrap_or(&[]);
                if let Some(j) = skipped.iter().position(|s| match s {
                    HandStep::Timed(r) => r.instrument != active,
                    HandStep::Switch { .. } => true,
                    HandStep::Watch(x) => x.instrument != active,
                }) {
                    return Err(format!(
                        "row {k}: then_row skips row {}, which switches instruments; the rows it skips work \
                         instrument {active}",
                        k + 1 + j
                    ));
                }
                let h = held[active];
                if let Some(x) = watched.get_mut(active) {
                    *x = Some(k);
                }
                HubRow {
                    t_s: w.t_s,
                    instrument: active,
                    inserted_m: w.inserted_m.unwrap_or(h.0),
                    roll_rad: w.roll_rad.unwrap_or(h.1),
                }
            }
        };
        held[row.instrument] = (row.inserted_m, row.roll_rad);
        out.push(row);
    }
    Ok(out)
}

/// How many hub-driven instruments a [`TipWatch`] can watch.
pub const WATCHED_RODS: usize = 4;
/// How many segment labels a [`TipWatch`] keeps pointing angles for.
pub const WATCHED_SEGMENTS: usize = 16;
/// No segment (the label of a tip not seen yet, or on an unlabelled mesh).
pub const NO_SEGMENT: u32 = u32::MAX;

/// What the scripted hand sees of the instruments' tips, as the stream
/// shows them (the publisher's [`TipWatcher`] writes it once a state
/// frame, the hand on the device's thread reads it): lock-free atomics.
#[derive(Debug)]
pub struct TipWatch {
    rods: [RodView; WATCHED_RODS],
    /// Per script step: whether it is a watched move, how long it took (s,
    /// NaN before it ended) and whether its condition held then.
    ends: Vec<(bool, AtomicU64, AtomicBool)>,
}

#[derive(Debug)]
struct RodView {
    frames: AtomicU64,
    label: AtomicU32,
    depth_bits: AtomicU64,
    angle_bits: [AtomicU64; WATCHED_SEGMENTS],
}

use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};

impl TipWatch {
    /// Nothing seen yet, room for the outcomes of `steps`.
    pub fn new(steps: &[HandStep]) -> TipWatch {
        TipWatch {
            rods: std::array::from_fn(|_| RodView {
                frames: AtomicU64::new(0),
                label: AtomicU32::new(NO_SEGMENT),
                depth_bits: AtomicU64::new(0f64.to_bits()),
                angle_bits: std::array::from_fn(|_| AtomicU64::new(std::f64::consts::PI.to_bits())),
            }),
            ends: steps
                .iter()
                .map(|s| {
                    (
                        matches!(s, HandStep::Watch(_)),
                        AtomicU64::new(f64::NAN.to_bits()),
                        AtomicBool::new(false),
                    )
                })
                .collect(),
        }
    }

    /// Instrument `rod`'s tip: its segment label ([`NO_SEGMENT`] if not
    /// seen) and how far (m) the rod runs in it back from the tip.
    pub fn tip(&self, rod: usize) -> (u32, f64) {
        match self.rods.get(rod) {
            Some(r) => (
                r.label.load(Ordering::Acquire),
                f64::from_bits(r.depth_bits.load(Ordering::Acquire)),
            ),
            None => (NO_SEGMENT, 0.0),
        }
    }

    /// The angle (rad) between where instrument `rod`'s tip bends and the
    /// opening of segment `label` (π when unknown).
    pub fn angle(&self, rod: usize, label: u32) -> f64 {
        self.rods
            .get(rod)
            .and_then(|r| r.angle_bits.get(label as usize))
            .map_or(std::f64::consts::PI, |a| f64::from_bits(a.load(Ordering::Acquire)))
    }

    /// State frames looked at for instrument `rod`.
    pub fn frames(&self, rod: usize) -> u64 {
        self.rods.get(rod).map_or(0, |r| r.frames.load(Ordering::Acquire))
    }

    /// Records what the watcher saw of instrument `rod`'s tip.
    fn set(&self, rod: usize, label: u32, depth_m: f64, angles: &[f64]) {
        let Some(r) = self.rods.get(rod) else { return };
        r.label.store(label, Ordering::Release);
        r.depth_bits.store(depth_m.to_bits(), Ordering::Release);
        for (a, &v) in r.angle_bits.iter().zip(angles) {
            a.store(v.to_bits(), Ordering::Release);
        }
        r.frames.fetch_add(1, Ordering::AcqRel);
    }

    fn end(&self, step: usize, took_s: f64, met: bool) {
        if let Some((_, t, m)) = self.ends.get(step) {
            m.store(met, Ordering::Release);
            t.store(took_s.to_bits(), Ordering::Release);
        }
    }

    /// How each watched move ended, in script order.
    pub fn report(&self) -> Vec<super::report::HandWatchReport> {
        self.ends
            .iter()
            .enumerate()
            .filter(|(_, e)| e.0)
            .map(|(row, (_, t, m))| {
                let t = f64::from_bits(t.load(Ordering::Acquire));
                super::report::HandWatchReport {
                    row,
                    reached: !t.is_nan(),
                    met: m.load(Ordering::Acquire),
                    took_s: if t.is_nan() { 0.0 } else { t },
                }
            })
            .collect()
    }
}

/// How far behind the tip (m, along the rod) the watcher takes the base of
/// the tip's bend, and how far behind that the rod's axis.
pub const POINTING_BASE_M: f64 = 0.010;
/// See [`POINTING_BASE_M`].
pub const POINTING_AXIS_M: f64 = 0.020;

/// The hand's eyes, on the stream publisher's thread: from each hub-driven
/// instrument's polyline of a state frame, its tip's segment (the label of
/// the nearest labelled wall vertex at rest, [`crate::task::SegmentMap`]),
/// how far the rod runs in it, and for every segment the angle between the
/// tip's bend and the segment's opening, into a [`TipWatch`].
///
/// The angle: with B the rod's point [`POINTING_BASE_M`] behind the tip T
/// and a the rod's direction over the [`POINTING_AXIS_M`] behind B, the
/// angle between the parts of T − B and of O − B across a (O the
/// opening's centre: the mean of the segment's wall vertices in the
/// quarter nearest another segment's).
#[derive(Debug)]
pub struct TipWatcher {
    map: crate::task::SegmentMap,
    openings: Vec<Vec3>,
    watch: std::sync::Arc<TipWatch>,
    angles: Vec<f64>,
}

impl TipWatcher {
    /// The watcher of `map` writing into `watch`.
    pub fn new(map: crate::task::SegmentMap, watch: std::sync::Arc<TipWatch>) -> TipWatcher {
        let pts = map.points();
        let labels = map.labels();
        let openings = (0..map.names().len())
            .map(|l| {
                let mut near: Vec<(f64, Vec3)> = pts
                    .iter()
                    .zip(labels)
                    .filter(|(_, &m)| m as usize == l)
                    .map(|(p, _)| {
                        let d = pts
                            .iter()
                            .zip(labels)
                            .filter(|(_, &m)| m as usize != l)
                            .map(|(q, _)| (q - p).norm_squared())
                            .fold(f64::INFINITY, f64::min);
                        (d, *p)
                    })
                    .collect();
                near.sort_by(|a, b| a.0.total_cmp(&b.0));
                let n = (near.len() / 4).max(3).min(near.len()).max(1);
                let sum = near.iter().take(n).fold(Vec3::zeros(), |s, (_, p)| s + p);
                if near.is_empty() {
                    Vec3::zeros()
                } else {
                    sum / n as f64
                }
            })
            .collect();
        let n = map.names().len().min(WATCHED_SEGMENTS);
        TipWatcher {
            map,
            openings,
            watch,
            angles: vec![std::f64::consts::PI; n],
        }
    }

    /// The segments' names, in label order.
    pub fn names(&self) -> &[String] {
        self.map.names()
    }

    /// The opening's centre of segment `label` (m, at rest).
    pub fn opening(&self, label: usize) -> Option<Vec3> {
        self.openings.get(label).copied()
    }

    /// How each watched move ended ([`TipWatch::report`]).
    pub fn report(&self) -> Vec<super::report::HandWatchReport> {
        self.watch.report()
    }

    /// Looks at hub-driven instrument `rod`'s polyline (hub to tip, m).
    pub fn look(&mut self, rod: usize, line: &[[f32; 3]]) {
        let Some(tip) = line.last().map(|p| Vec3::new(p[0] as f64, p[1] as f64, p[2] as f64)) else {
            return;
        };
        let label = self.map.label_at(tip);
        let depth = label.map_or(0.0, |l| self.map.depth_in(line, l, 0.5));
        let base = point_behind(line, POINTING_BASE_M);
        let back = point_behind(line, POINTING_BASE_M + POINTING_AXIS_M);
        for (l, a) in self.angles.iter_mut().enumerate() {
            *a = match (base, back) {
                (Some(b), Some(c)) => {
                    let axis = (b - c).try_normalize(1e-9);
                    let o = self.openings[l];
                    axis.map_or(std::f64::consts::PI, |ax| {
                        let across = |v: Vec3| v - ax * ax.dot(&v);
                        let (u, w) = (across(tip - b), across(o - b));
                        match (u.try_normalize(1e-6), w.try_normalize(1e-9)) {
                            (Some(u), Some(w)) => u.dot(&w).clamp(-1.0, 1.0).acos(),
                            _ => std::f64::consts::PI,
                        }
                    })
                }
                _ => std::f64::consts::PI,
            };
        }
        self.watch
            .set(rod, label.map_or(NO_SEGMENT, u32::from), depth, &self.angles);
    }
}

/// The point `behind_m` back from the end of `line` along it (None if the
/// line is shorter).
fn point_behind(line: &[[f32; 3]], behind_m: f64) -> Option<Vec3> {
    let v = |p: &[f32; 3]| Vec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
    let mut left = behind_m;
    for w in line.windows(2).rev() {
        let (a, b) = (v(&w[0]), v(&w[1]));
        let l = (b - a).norm();
        if l >= left && l > 0.0 {
            return Some(b + (a - b) * (left / l));
        }
        left -= l;
    }
    None
}

/// A scripted hand that watches ([`crate::haptics::touchx::LiveHand`]): it
/// plays [`HandStep`]s on line, through the drive's map as
/// [`switching_hand`] does offline, and ends each watched move when what it
/// sees in a [`TipWatch`] meets the move's condition. Allocation-free after
/// construction.
#[derive(Debug, Clone)]
pub struct WatchingHand {
    steps: Vec<LiveStep>,
    axis: Vec3,
    insertion_scale: f64,
    roll_scale: f64,
    roll_index: usize,
    watch: std::sync::Arc<TipWatch>,
    /// The next step.
    k: usize,
    /// Script time the current stretch starts (s), and the active
    /// instrument's hub then.
    from_s: f64,
    from: (f64, f64),
    held: [(f64, f64); WATCHED_RODS],
    active: usize,
    /// The stylus (position, roll) and the active instrument's hub when it
    /// took the stylus up.
    anchor: (Vec3, f64, f64, f64),
    /// Script time = time − `shift` (the clock stands still during a
    /// watched move).
    shift: f64,
    /// When the watched move under way started (s, device script time).
    watch_from: Option<f64>,
    press_until: f64,
}

/// A step with its condition resolved to labels.
#[derive(Debug, Clone, Copy, PartialEq)]
enum LiveStep {
    Timed(HubRow),
    Switch(f64, usize),
    Watch {
        t_s: f64,
        limit: (Option<f64>, Option<f64>),
        speed: (f64, f64),
        within_s: f64,
        rod: usize,
        label: u32,
        /// Depth (m) for `In`, or the tolerance (rad) for `PointsTo`.
        enough: f64,
        pointing: bool,
        /// The step after it when its condition is met.
        then: usize,
    },
}

impl LiveStep {
    fn t_s(&self) -> f64 {
        match self {
            LiveStep::Timed(r) => r.t_s,
            LiveStep::Switch(t, _) => *t,
            LiveStep::Watch { t_s, .. } => *t_s,
        }
    }
}

impl WatchingHand {
    /// The hand playing `steps` through `drive`, instrument `k` starting at
    /// `start[k]`, seeing `watch`; `names`: the mesh's segment names, in
    /// label order. Errors name the row whose segment is unknown.
    pub fn new(
        steps: &[HandStep],
        drive: &crate::wire::DriveParams,
        start: &[(f64, f64)],
        names: &[String],
        watch: std::sync::Arc<TipWatch>,
    ) -> Result<WatchingHand, String> {
        let axis = Vec3::from(drive.axis)
            .try_normalize(1e-12)
            .ok_or("drive.axis is zero")?;
        if start.is_empty() || start.len() > WATCHED_RODS || drive.insertion_scale <= 0.0 {
            return Err(format!(
                "the hand drives 1 to {WATCHED_RODS} instruments through a positive insertion_scale"
            ));
        }
        let label = |k: usize, field: &str, s: &str| -> Result<u32, String> {
            names
                .iter()
                .position(|n| n == s)
                .filter(|&l| l < WATCHED_SEGMENTS)
                .map(|l| l as u32)
                .ok_or_else(|| {
                    format!(
                        "[{k}].{field}: \"{s}\" is not a segment of the mesh (it has {})",
                        if names.is_empty() {
                            "no labels".to_string()
                        } else {
                            names.join(", ")
                        }
                    )
                })
        };
        let mut live = Vec::with_capacity(steps.len());
        for (k, s) in steps.iter().enumerate() {
            live.push(match s {
                HandStep::Timed(r) => LiveStep::Timed(*r),
                HandStep::Switch { t_s, to } => LiveStep::Switch(*t_s, *to),
                HandStep::Watch(w) => {
                    let (rod, label, enough, pointing) = match &w.until {
                        Until::In { rod, segment, depth_m } => (*rod, label(k, "until_in", segment)?, *depth_m, false),
                        Until::PointsTo {
                            rod,
                            segment,
                            within_rad,
                        } => (*rod, label(k, "until_points_to", segment)?, *within_rad, true),
                    };
                    LiveStep::Watch {
                        t_s: w.t_s,
                        limit: (w.inserted_m, w.roll_rad),
                        speed: (w.speed_m_s, w.roll_speed_rad_s),
                        within_s: w.within_s,
                        rod,
                        label,
                        enough,
                        pointing,
                        then: w.then_row.unwrap_or(k + 1),
                    }
                }
            });
        }
        let mut held = [(0.0, 0.0); WATCHED_RODS];
        held[..start.len()].copy_from_slice(start);
        let stylus = drive.stylus_at(start[0].0);
        Ok(WatchingHand {
            steps: live,
            axis,
            insertion_scale: drive.insertion_scale,
            roll_scale: drive.roll_scale,
            roll_index: drive.roll_index.min(2),
            watch,
            k: 0,
            from_s: 0.0,
            from: start[0],
            held,
            active: 0,
            anchor: (stylus, 0.0, start[0].0, start[0].1),
            shift: 0.0,
            watch_from: None,
            press_until: f64::NEG_INFINITY,
        })
    }

    /// The stylus (position, roll) that puts the active instrument's hub at
    /// `hub`.
    fn stylus(&self, hub: (f64, f64)) -> (Vec3, f64) {
        let (s0, r0, i0, h0) = self.anchor;
        let roll = if self.roll_scale != 0.0 {
            r0 + (hub.1 - h0) / self.roll_scale
        } else {
            r0
        };
        (s0 + self.axis * ((hub.0 - i0) / self.insertion_scale), roll)
    }

    fn pose(&self, t: f64, hub: (f64, f64), rate: f64) -> crate::haptics::touchx::HandPose {
        let (position, roll) = self.stylus(hub);
        let mut gimbal_rad = [0.0; 3];
        gimbal_rad[self.roll_index] = roll;
        crate::haptics::touchx::HandPose {
            position,
            velocity: self.axis * (rate / self.insertion_scale),
            gimbal_rad,
            buttons: if t < self.press_until {
                super::instrument::SWITCH_BUTTON
            } else {
                0
            },
        }
    }

    /// Whether watched move condition holds now.
    fn met(&self, rod: usize, label: u32, enough: f64, pointing: bool) -> bool {
        if pointing {
            self.watch.frames(rod) > 0 && self.watch.angle(rod, label) <= enough
        } else {
            let (l, depth) = self.watch.tip(rod);
            l == label && depth >= enough
        }
    }
}

/// Moves `x` toward `to` by at most `by` (≥ 0).
fn toward(x: f64, to: f64, by: f64) -> f64 {
    if to > x {
        (x + by).min(to)
    } else {
        (x - by).max(to)
    }
}

impl crate::haptics::touchx::LiveHand for WatchingHand {
    fn at(&mut self, t: f64) -> crate::haptics::touchx::HandPose {
        loop {
            let s = t - self.shift;
            let Some(step) = self.steps.get(self.k).copied() else {
                return self.pose(t, self.held[self.active], 0.0);
            };
            match step {
                LiveStep::Timed(r) if r.instrument == self.active => {
                    if s >= r.t_s {
                        self.held[self.active] = (r.inserted_m, r.roll_rad);
                        self.from = self.held[self.active];
                        self.from_s = r.t_s;
                        self.k += 1;
                        continue;
                    }
                    let span = (r.t_s - self.from_s).max(1e-9);
                    let u = ((s - self.from_s) / span).clamp(0.0, 1.0);
                    let pi = std::f64::consts::PI;
                    let e = 0.5 * (1.0 - (pi * u).cos());
                    let de = 0.5 * pi * (pi * u).sin() / span;
                    let hub = (
                        self.from.0 + (r.inserted_m - self.from.0) * e,
                        self.from.1 + (r.roll_rad - self.from.1) * e,
                    );
                    self.held[self.active] = hub;
                    return self.pose(t, hub, (r.inserted_m - self.from.0) * de);
                }
                LiveStep::Timed(HubRow { t_s, instrument, .. }) | LiveStep::Switch(t_s, instrument) => {
                    if s < t_s {
                        return self.pose(t, self.held[self.active], 0.0);
                    }
                    // The newly active instrument takes the stylus up where
                    // it is.
                    let here = self.stylus(self.held[self.active]);
                    self.active = instrument.min(WATCHED_RODS - 1);
                    let h = self.held[self.active];
                    self.anchor = (here.0, here.1, h.0, h.1);
                    self.press_until = t + SWITCH_PRESS_S;
                    self.from = h;
                    self.from_s = t_s;
                    self.k += 1;
                }
                LiveStep::Watch {
                    t_s,
                    limit,
                    speed,
                    within_s,
                    rod,
                    label,
                    enough,
                    pointing,
                    then,
                } => {
                    if s < t_s {
                        return self.pose(t, self.held[self.active], 0.0);
                    }
                    let started = *self.watch_from.get_or_insert(t);
                    let dt = t - started;
                    let hub = (
                        limit.0.map_or(self.from.0, |to| toward(self.from.0, to, speed.0 * dt)),
                        limit.1.map_or(self.from.1, |to| toward(self.from.1, to, speed.1 * dt)),
                    );
                    self.held[self.active] = hub;
                    let met = self.met(rod, label, enough, pointing);
                    if met || dt >= within_s {
                        self.watch.end(self.k, dt, met);
                        self.watch_from = None;
                        let next = if met { then } else { self.k + 1 };
                        // Past skipped rows, the script goes on as from
                        // the row before the one it goes to.
                        let resume = match next.checked_sub(1).and_then(|j| self.steps.get(j)) {
                            Some(prev) if next > self.k + 1 => prev.t_s(),
                            _ => t_s,
                        };
                        self.shift = t - resume;
                        self.from = hub;
                        self.from_s = resume;
                        self.k = next;
                        continue;
                    }
                    let rate = limit.0.map_or(0.0, |to| {
                        if (hub.0 - to).abs() > 0.0 {
                            speed.0 * (to - hub.0).signum()
                        } else {
                            0.0
                        }
                    });
                    return self.pose(t, hub, rate);
                }
            }
        }
    }

    fn clone_box(&self) -> Box<dyn crate::haptics::touchx::LiveHand> {
        Box::new(self.clone())
    }
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

    fn rows(text: &str) -> Vec<toml::Value> {
        let t: toml::Table = toml::from_str(&format!("script = {text}")).unwrap();
        t["script"].as_array().unwrap().clone()
    }

    /// Bad rows are refused naming the row and the field.
    #[test]
    fn a_bad_script_row_names_its_row_and_field() {
        let max = [0.5, 0.5];
        let err = |text: &str| parse_steps(&rows(text), 2, &max).unwrap_err();
        assert_eq!(err("[[0.0, 0, 0.1, 0.0], [1.0, 2, 0.1, 0.0]]").0, "[1][1]");
        assert_eq!(err("[[0.0, 0, 0.1]]").0, "[0]");
        assert_eq!(err("[[0.0, 0, 0.9, 0.0]]").0, "[0][2]");
        let e = err(r#"[{ t_s = 1.0, instrument = 0, inserted_m = 0.2, until_in = "a", speed_m_s = 5.0 }]"#);
        assert_eq!(e.0, "[0].speed_m_s", "{e:?}");
        let e = err(r#"[{ t_s = 1.0, instrument = 0, inserted_m = 0.2, until_in = "a", speed = 0.01 }]"#);
        assert_eq!(e.0, "[0].speed", "{e:?}");
        let e = err(r#"[{ t_s = 1.0, instrument = 0, inserted_m = 0.2 }]"#);
        assert_eq!(e.0, "[0].until_in", "{e:?}");
        let e = err(r#"[{ t_s = 1.0, instrument = 0, inserted_m = 0.2, until_in = "a", then_row = 0 }]"#);
        assert_eq!(e.0, "[0].then_row", "{e:?}");
        let e = err(r#"[{ t_s = 1.0, switch_to = 1, instrument = 0 }]"#);
        assert_eq!(e.0, "[0].instrument", "{e:?}");
        assert_eq!(err(r#"["x"]"#).0, "[0]");
        // A timed switch after a watched move cannot know where it was left.
        let steps = parse_steps(
            &rows(
                r#"[[0.0, 0, 0.1, 0.0], [0.5, 1, 0.1, 0.0],
                   { t_s = 1.0, instrument = 1, inserted_m = 0.2, until_in = "a" },
                   [2.0, 0, 0.1, 0.0], [3.0, 1, 0.2, 0.0]]"#,
            ),
            2,
            &max,
        )
        .unwrap();
        let e = planned_rows(&steps, &[(0.1, 0.0), (0.1, 0.0)]).unwrap_err();
        assert!(e.contains("row 4") && e.contains("switch_to = 1"), "{e}");
    }

    /// The watching hand advances until what it sees meets the condition,
    /// goes on from `then_row`, switches where a row says, and plays timed
    /// rows as the offline hand does.
    #[test]
    fn the_watching_hand_stops_when_its_condition_is_met_and_skips_the_tries() {
        use crate::haptics::touchx::LiveHand;
        let wire = WireParams::default();
        let d = wire.drive;
        let steps = parse_steps(
            &rows(
                r#"[[0.0, 0, 0.20, 0.0],
                   { t_s = 1.0, instrument = 0, inserted_m = 0.30, until_in = "b", depth_m = 0.01, speed_m_s = 0.02, within_s = 3.0, then_row = 4 },
                   [2.0, 0, 0.20, 0.0],
                   { t_s = 2.1, instrument = 0, inserted_m = 0.30, until_in = "b", within_s = 3.0 },
                   { t_s = 3.0, switch_to = 1 },
                   [4.0, 1, 0.25, 0.5]]"#,
            ),
            2,
            &[1.0, 1.0],
        )
        .unwrap();
        let names = ["a".to_string(), "b".to_string()];
        let watch = std::sync::Arc::new(TipWatch::new(&steps));
        let start = [(0.20, 0.0), (0.18, 0.0)];
        let mut hand = WatchingHand::new(&steps, &d, &start, &names, watch.clone()).unwrap();
        let hub = |p: &crate::haptics::touchx::HandPose| {
            (p.position - d.stylus_at(0.20)).dot(&Vec3::from(d.axis).normalize()) * d.insertion_scale + 0.20
        };
        let mut t = 0.0;
        let mut pose = hand.at(t);
        // 1.5 s into the watched advance: 30 mm at 20 mm/s.
        while t < 2.5 {
            t += 1e-3;
            pose = hand.at(t);
        }
        assert!((hub(&pose) - 0.23).abs() < 1e-4, "{}", hub(&pose));
        // The tip is seen 12 mm into "b": the hand holds, and goes on at
        // row 4 (the switch, 0.9 s of script after row 3's time).
        watch.set(0, 1, 0.012, &[]);
        pose = hand.at(t + 1e-3);
        let held = hub(&pose);
        assert!((held - 0.23).abs() < 1e-4, "{held}");
        let met_at = t;
        let mut pressed = None;
        while t < met_at + 3.0 {
            t += 1e-3;
            pose = hand.at(t);
            if pose.buttons != 0 && pressed.is_none() {
                pressed = Some(t);
            }
        }
        let pressed = pressed.expect("the switch button");
        assert!((pressed - met_at - 0.9).abs() < 2e-3, "pressed {pressed}, met {met_at}");
        // The catheter took the stylus up where it was: 70 mm of its hub
        // further by the end, rolled by 0.5 rad.
        let moved = (pose.position - d.stylus_at(0.20)).dot(&Vec3::from(d.axis).normalize()) * d.insertion_scale;
        assert!((moved - (0.03 + 0.07)).abs() < 1e-4, "{moved}");
        assert!((pose.gimbal_rad[d.roll_index] - 0.5 / d.roll_scale).abs() < 1e-9);
        let r = watch.report();
        assert_eq!(r.len(), 2);
        assert!(r[0].reached && r[0].met && (r[0].took_s - 1.5).abs() < 2e-3, "{r:?}");
        assert!(!r[1].reached, "{r:?}");
    }
}
