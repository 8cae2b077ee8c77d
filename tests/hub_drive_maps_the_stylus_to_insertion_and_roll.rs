//! The hub drive maps the stylus to the wire's two hub motions — position
//! along the configured axis to inserted length (scaled, clamped, rate
//! limited), the stylus roll to the wire's roll (unwrapped across ±π) — and
//! maps the wire's axial resistance plus a virtual guide back to the hand.
//! An unusable sample holds the commands and zeroes the force.

use nvtmm::haptics::DeviceSample;
use nvtmm::math::Vec3;
use nvtmm::wire::drive::{DriveParams, HubDrive, MAX_DT_S};
use nvtmm::wire::{NoWall, StraightTube, Wire, WireParams};
use std::f64::consts::PI;

fn wire_with(drive: DriveParams) -> WireParams {
    WireParams {
        drive,
        ..WireParams::default()
    }
}

fn sample(position: Vec3, roll: f64) -> DeviceSample {
    DeviceSample {
        position,
        gimbal_rad: [0.0, 0.0, roll],
        ..DeviceSample::REST
    }
}

/// Wraps to (−π, π] as a device would report.
fn wrapped(a: f64) -> f64 {
    nvtmm::haptics::device::wrap_angle(a)
}

#[test]
fn insertion_is_the_scaled_projection_on_the_axis_clamped_and_rate_limited() {
    let dp = DriveParams {
        axis: [0.0, 0.0, -5.0], // normalised by the drive
        origin_m: [0.001, 0.002, 0.0],
        inserted_at_origin_m: 0.1,
        insertion_scale: 2.0,
        max_speed_m_s: 0.1,
        ..DriveParams::default()
    };
    let w = wire_with(dp);
    let mut d = HubDrive::new(&w, 0.1, 0.0).expect("drive");
    assert_eq!(d.axis(), Vec3::new(0.0, 0.0, -1.0));
    assert_eq!(d.max_inserted(), w.max_inserted_m());
    let p = Vec3::new(0.011, 0.022, -0.03);
    // target = 0.1 + 2 · 0.03; off-axis (0.01, 0.02).
    assert!((d.target(p) - 0.16).abs() < 1e-15);
    let mut t = 0.0;
    let c0 = d.command(&sample(p, 0.0), t);
    assert_eq!(c0.inserted_m, 0.1, "the first sample gives no time step: no move");
    assert!((c0.off_axis_m - (0.01f64.hypot(0.02))).abs() < 1e-15);
    // At 1 kHz and 0.1 m/s the command moves 0.1 mm a tick: 600 ticks for 60 mm.
    let mut last = c0.inserted_m;
    let mut ticks = 0;
    loop {
        t += 1e-3;
        let c = d.command(&sample(p, 0.0), t);
        assert!(c.inserted_m - last <= 0.1 * 1e-3 + 1e-15, "rate limit");
        assert!(!c.clamped && !c.fault);
        last = c.inserted_m;
        ticks += 1;
        if !c.rate_limited {
            break;
        }
        assert!(ticks < 10_000);
    }
    // 60 mm at 0.1 m/s in 1 ms ticks (one more if rounding leaves a sliver).
    assert!((600..=601).contains(&ticks), "{ticks}");
    assert!((last - 0.16).abs() < 1e-12, "{last}");
    // A long gap is credited at most MAX_DT_S.
    let back = p + Vec3::new(0.0, 0.0, 0.02); // target 0.12
    t += 1.0;
    let c = d.command(&sample(back, 0.0), t);
    assert!((last - c.inserted_m - 0.1 * MAX_DT_S).abs() < 1e-12);
    // Pulling far back clamps at 0, pushing far in at what the wire inserts.
    for (z, want) in [(0.2, 0.0), (-1.0, w.max_inserted_m())] {
        let q = Vec3::new(0.001, 0.002, z);
        let mut c = d.command(&sample(q, 0.0), t);
        for _ in 0..100_000 {
            t += 1e-3;
            c = d.command(&sample(q, 0.0), t);
            if !c.rate_limited {
                break;
            }
        }
        assert!(c.clamped, "z = {z}");
        assert!((c.inserted_m - want).abs() < 1e-12, "z = {z}: {c:?}");
    }
    assert!(d.counters().clamped > 0 && d.counters().rate_limited > 1000);
}

#[test]
fn the_wire_feed_limit_caps_the_speed() {
    let dp = DriveParams {
        max_speed_m_s: 5.0,
        ..DriveParams::default()
    };
    let w = wire_with(dp);
    let feed = w.max_feed_speed_m_s();
    assert!((feed - 0.25 * 0.89e-3 / 1e-3).abs() < 1e-12);
    let mut d = HubDrive::new(&w, 0.05, 0.0).expect("drive");
    let far = Vec3::new(0.0, 0.0, -0.05);
    d.command(&sample(far, 0.0), 0.0);
    let c = d.command(&sample(far, 0.0), 1e-3);
    assert!((c.inserted_m - 0.05 - feed * 1e-3).abs() < 1e-15, "{c:?}");
}

#[test]
fn roll_is_unwrapped_across_plus_minus_pi_scaled_and_rate_limited() {
    for roll_scale in [1.0, -0.5] {
        let dp = DriveParams {
            roll_scale,
            max_roll_speed_rad_s: 1000.0,
            ..DriveParams::default()
        };
        let mut d = HubDrive::new(&wire_with(dp), 0.1, 0.25).expect("drive");
        // The stylus starts at 2.9 rad and turns +2.5 turns then back 1 turn,
        // 0.05 rad a tick; the device reports wrapped angles.
        let start = 2.9;
        let mut truth = start;
        let mut t = 0.0;
        let p = Vec3::new(0.0, 0.0, 0.0);
        let mut crossed = 0;
        let mut prev = wrapped(truth);
        d.command(&sample(p, prev), t);
        let steps_up = (2.5 * 2.0 * PI / 0.05) as usize;
        let steps_down = (2.0 * PI / 0.05) as usize;
        for k in 0..steps_up + steps_down {
            truth += if k < steps_up { 0.05 } else { -0.05 };
            t += 1e-3;
            let r = wrapped(truth);
            if (r - prev).abs() > PI {
                crossed += 1;
            }
            prev = r;
            let c = d.command(&sample(p, r), t);
            let want = 0.25 + roll_scale * (truth - start);
            assert!((c.roll_rad - want).abs() < 1e-9, "k = {k}: {} vs {want}", c.roll_rad);
        }
        assert_eq!(crossed, 4, "the reported roll crossed ±π 3 times up, once down");
    }
    // Rate limit: a 1 rad step at 2 rad/s takes 500 ticks of 1 ms.
    let dp = DriveParams {
        max_roll_speed_rad_s: 2.0,
        ..DriveParams::default()
    };
    let mut d = HubDrive::new(&wire_with(dp), 0.18, 0.0).expect("drive");
    let p = Vec3::zeros();
    d.command(&sample(p, 0.0), 0.0);
    let mut n = 0;
    let mut t = 0.0;
    loop {
        t += 1e-3;
        let c = d.command(&sample(p, 1.0), t);
        n += 1;
        if !c.rate_limited {
            assert!((c.roll_rad - 1.0).abs() < 1e-12);
            break;
        }
        assert!(c.roll_rad <= 2.0 * t + 1e-12);
    }
    assert!((500..=501).contains(&n), "{n}");
    // The roll joint is configurable: index 0 here.
    let dp = DriveParams {
        roll_index: 0,
        max_roll_speed_rad_s: 1000.0,
        ..DriveParams::default()
    };
    let mut d = HubDrive::new(&wire_with(dp), 0.18, 0.0).expect("drive");
    let mut s = sample(p, 0.7);
    d.command(&s, 0.0);
    s.gimbal_rad[0] = 0.3;
    let c = d.command(&s, 1e-3);
    assert!((c.roll_rad - 0.3).abs() < 1e-12, "{c:?}");
}

#[test]
fn the_hand_feels_the_axial_resistance_and_the_guide() {
    let dp = DriveParams {
        force_scale: 1.5,
        guide_stiffness_n_per_m: 200.0,
        guide_damping_ns_per_m: 2.0,
        max_force_n: 5.0,
        ..DriveParams::default()
    };
    let mut d = HubDrive::new(&wire_with(dp), 0.1, 0.0).expect("drive");
    // On the axis: the wire resisting insertion by 2 N pushes the hand back
    // along −axis = +z (toward the user), scaled by 1.5.
    let on = Vec3::new(0.0, 0.0, -0.02);
    let f = d.hand_force(&sample(on, 0.0), 2.0);
    assert!((f - Vec3::new(0.0, 0.0, 3.0)).norm() < 1e-12, "{f:?}");
    // Off the axis by 5 mm in x, moving at 0.1 m/s in y and 0.3 m/s along it:
    // the guide pulls back across the axis only.
    let s = DeviceSample {
        position: Vec3::new(0.005, 0.0, -0.02),
        velocity: Vec3::new(0.0, 0.1, 0.3),
        ..DeviceSample::REST
    };
    let f = d.hand_force(&s, 0.0);
    assert!((f - Vec3::new(-1.0, -0.2, 0.0)).norm() < 1e-12, "{f:?}");
    // The sum is clamped to max_force_n.
    let f = d.hand_force(&s, 10.0);
    assert!((f.norm() - 5.0).abs() < 1e-12 && f.z > 0.0, "{f:?}");
    assert_eq!(d.counters().force_clamped, 1);
    // A non-finite wire force gives no force.
    assert_eq!(d.hand_force(&s, f64::NAN), Vec3::zeros());
}

#[test]
fn unusable_samples_hold_the_commands_and_zero_the_force() {
    let dp = DriveParams {
        max_roll_speed_rad_s: 1000.0,
        ..DriveParams::default()
    };
    let mut d = HubDrive::new(&wire_with(dp), 0.18, 0.0).expect("drive");
    let p = Vec3::new(0.0, 0.0, -0.01);
    d.command(&sample(p, 0.1), 0.0);
    let good = d.command(&sample(p, 0.2), 1e-3);
    let bad = [
        sample(p, f64::NAN),
        sample(p, 7.0), // beyond one turn: a device fault
        sample(Vec3::new(f64::NAN, 0.0, 0.0), 0.2),
        DeviceSample {
            velocity: Vec3::new(0.0, f64::INFINITY, 0.0),
            ..sample(p, 0.2)
        },
    ];
    for (i, s) in bad.iter().enumerate() {
        let c = d.command(s, 2e-3 + i as f64 * 1e-3);
        assert!(c.fault, "{i}");
        assert_eq!((c.inserted_m, c.roll_rad), (good.inserted_m, good.roll_rad), "{i}");
        assert_eq!(d.hand_force(s, 1.0), Vec3::zeros(), "{i}");
    }
    assert_eq!(d.counters().faults, 4);
    // The next good sample continues from where the commands held.
    let c = d.command(&sample(p, 0.2), 0.01);
    assert!(!c.fault && c.inserted_m > good.inserted_m);
    assert!((c.roll_rad - 0.1).abs() < 1e-12, "roll since the first sample: {c:?}");
    // Reseating after a wire reset keeps counting the stylus roll from there.
    d.reseat(0.05, 1.0);
    let c = d.command(&sample(p, 0.3), 0.011);
    assert!((c.roll_rad - 1.1).abs() < 1e-12, "{c:?}");
    assert!(c.inserted_m > 0.05 && c.inserted_m < 0.051);
}

#[test]
fn the_drive_steers_a_wire_and_feels_a_dead_end() {
    // A wire in a straight tube capped 40 mm in; the hub drive's axis is the
    // device's −z, the wire's insertion axis the scene's +x.
    let w = WireParams {
        segment_length_m: 2e-3,
        max_nodes: 48,
        ..WireParams::default()
    };
    let mut wire = Wire::new(&w, Vec3::zeros(), Vec3::x(), 0.01).expect("wire");
    let tube = StraightTube::new(Vec3::new(-0.01, 0.0, 0.0), Vec3::x(), 0.05, 1.5e-3, true).expect("tube");
    let mut d = HubDrive::new(&w, wire.inserted(), wire.roll()).expect("drive");
    // Stylus at z such that the target is 30 mm, rolled by 0.4 rad.
    let z30 = -(0.03 - w.drive.inserted_at_origin_m) / w.drive.insertion_scale;
    let s = sample(Vec3::new(0.0, 0.0, z30), 0.0);
    d.command(&s, 0.0);
    let s = sample(Vec3::new(0.0, 0.0, z30), 0.4);
    let mut t = 0.0;
    for _ in 0..400 {
        t += 1e-3;
        let c = d.command(&s, t);
        wire.set_hub(c.inserted_m, c.roll_rad);
        wire.step(&tube).expect("step");
    }
    assert!((wire.inserted() - 0.03).abs() < 1e-9, "{}", wire.inserted());
    assert!((wire.roll() - 0.4).abs() < 1e-12);
    // Free in the tube: little resistance, the guide holds the stylus.
    let rep = wire.step(&NoWall).expect("step");
    let f_free = d.hand_force(&s, rep.hub_axial_force_n);
    assert!(f_free.norm() < 0.1, "{f_free:?}");
    // Push past the cap (at 40 mm from the tube start: 30 mm in from the hub).
    let z60 = -(0.06 - w.drive.inserted_at_origin_m) / w.drive.insertion_scale;
    let s = sample(Vec3::new(0.0, 0.0, z60), 0.4);
    let mut f = Vec3::zeros();
    for _ in 0..1000 {
        t += 1e-3;
        let c = d.command(&s, t);
        wire.set_hub(c.inserted_m, c.roll_rad);
        let rep = wire.step(&tube).expect("step");
        f = d.hand_force(&s, rep.hub_axial_force_n);
    }
    // The hand is pushed back toward the user (+z), against its push (−z).
    println!(
        "dead end: wire inserted {:.4} m, hand force {:.3} N along +z; free: {:.2e} N",
        wire.inserted(),
        f.z,
        f_free.norm()
    );
    assert!(f.z > 0.5, "the dead end is felt: {f:?}");
    assert!(
        f.x.abs() < 1e-12 && f.y.abs() < 1e-12,
        "on the axis, no guide force: {f:?}"
    );
}

/// A scripted hand's map (`DriveParams::stylus_at`, `gimbal_for`) is the
/// inverse of the drive's: the stylus point it gives asks for the same
/// inserted length, and the gimbal angles for the same roll.
#[test]
fn the_scripted_hands_map_inverts_the_drive() {
    let d = DriveParams {
        axis: [0.0, 2.0, -2.0],
        origin_m: [0.01, -0.02, 0.03],
        inserted_at_origin_m: 0.12,
        insertion_scale: 3.0,
        roll_index: 1,
        roll_scale: -0.5,
        ..DriveParams::default()
    };
    let drive = HubDrive::new(&wire_with(d), 0.0, 0.0).unwrap();
    for ins in [0.02, 0.12, 0.175] {
        assert!((drive.target(d.stylus_at(ins)) - ins).abs() < 1e-12, "{ins}");
    }
    assert_eq!(d.gimbal_for(0.4), [0.0, -0.8, 0.0]);
    let held = DriveParams { roll_scale: 0.0, ..d };
    assert_eq!(held.gimbal_for(0.4), [0.0; 3]);
}

/// Switching instruments lets go of one and takes hold of another where the
/// stylus happens to be: engaging anchors the drive at its present commands,
/// so neither the stylus's absolute position nor the roll it made while the
/// drive was idle moves the hub; the stylus's motions from there on do, at
/// the usual scale.
#[test]
fn engaging_takes_the_stylus_up_where_it_is() {
    let dp = DriveParams {
        axis: [0.0, 0.0, -1.0],
        inserted_at_origin_m: 0.1,
        insertion_scale: 2.0,
        max_speed_m_s: 0.1,
        roll_scale: 1.0,
        ..DriveParams::default()
    };
    let w = wire_with(dp);
    let mut d = HubDrive::new(&w, 0.1, 0.0).expect("drive");
    let mut t = 0.0;
    // Taken at the origin with the stylus unrolled, driven to 0.12 m and
    // 0.5 rad.
    d.command(&sample(Vec3::zeros(), 0.0), t);
    for _ in 0..2000 {
        t += 1e-3;
        d.command(&sample(Vec3::new(0.0, 0.0, -0.01), 0.5), t);
    }
    let held = d.command(&sample(Vec3::new(0.0, 0.0, -0.01), 0.5), t);
    assert!((held.inserted_m - 0.12).abs() < 1e-12 && (held.roll_rad - 0.5).abs() < 1e-12);
    // Idle while the stylus wanders (another instrument is active): it
    // ends 40 mm further in and rolled past ±π.
    let away = sample(Vec3::new(0.0, 0.0, -0.05), wrapped(2.9 + 1.0));
    d.engage(&away);
    assert!(
        (d.target(away.position) - 0.12).abs() < 1e-12,
        "the stylus maps to the present insertion"
    );
    for _ in 0..100 {
        t += 1e-3;
        let c = d.command(&away, t);
        assert!((c.inserted_m - 0.12).abs() < 1e-12, "no jump: {}", c.inserted_m);
        assert!((c.roll_rad - 0.5).abs() < 1e-12, "no roll: {}", c.roll_rad);
    }
    // From here the stylus drives it as before: 5 mm of stylus is 10 mm of
    // wire, a further 0.3 rad of stylus roll is 0.3 rad of wire.
    let on = sample(Vec3::new(0.0, 0.0, -0.055), wrapped(3.9 + 0.3));
    let mut c = d.command(&on, t);
    for _ in 0..2000 {
        t += 1e-3;
        c = d.command(&on, t);
    }
    assert!((c.inserted_m - 0.13).abs() < 1e-9, "{}", c.inserted_m);
    assert!((c.roll_rad - 0.8).abs() < 1e-9, "{}", c.roll_rad);
    // An unusable sample engages nothing.
    let before = d.target(on.position);
    d.engage(&sample(Vec3::new(f64::NAN, 0.0, 0.0), 0.0));
    assert_eq!(d.target(on.position), before);
}
