//! The guidewire in closed loop with the simulated Touch X, in simulated
//! time, timed as the service runs it: each tick the stylus sample drives
//! the hub (`HubDrive::command`), the hand force is the wire's axial force
//! from the step that ended before the tick plus the virtual guide
//! (`HubDrive::hand_force`), it goes through the service's own tick
//! (`HapticTick`: passivity QP, watchdog gain) to the device, and the wire
//! then steps with the new hub command.
//!
//! The hand pushes the wire into a tube with a dead end until it buckles,
//! holds, pulls back and pushes again at up to the hand's top speed (far
//! faster than the hub may follow), rolls the stylus and strays off the
//! axis. The energy the device port delivers to the hand (the simulator's
//! true sub-step motion) never exceeds what the hand put in plus the QP's
//! initial tank, and over no window more than the tank's capacity.

mod common;

use nvtmm::haptics::device::HapticDevice;
use nvtmm::haptics::passivity::{PassivityFilter, PassivityParams};
use nvtmm::haptics::tick::{Contribution, HapticTick, TickInput};
use nvtmm::haptics::touchx::{GimbalWaypoint, TouchXParams, TouchXSim, Waypoint};
use nvtmm::math::Vec3;
use nvtmm::wire::{DriveParams, HubDrive, StraightTube, Wire, WireParams};

const R: usize = 8;
const DT: f64 = 1e-3;

/// What one closed-loop run measured.
struct Run {
    /// Net energy the port delivered (J), true motion.
    net_j: f64,
    /// Largest net energy delivered over any window (J).
    worst_window_j: f64,
    /// Largest axial hub force (N).
    axial_max_n: f64,
    /// Largest force the device applied (N).
    force_max_n: f64,
    /// Lowest tank level the filter's observer saw (J).
    tank_low_j: f64,
    /// Energy the filter's observer counted as delivered and absorbed (J).
    observed: (f64, f64),
}

impl Run {
    /// Prints the run and asserts the port's promise: net energy delivered
    /// within the initial tank, every window within the tank's capacity.
    fn print_and_check_energy(&self, what: &str, p: &PassivityParams) {
        eprintln!(
            "{what}: net delivered {:.5} J, worst window {:.5} J, axial max {:.3} N, device force max {:.3} N, \
             tank low {:.5} J, observer delivered {:.5} J absorbed {:.5} J",
            self.net_j,
            self.worst_window_j,
            self.axial_max_n,
            self.force_max_n,
            self.tank_low_j,
            self.observed.0,
            self.observed.1
        );
        assert!(
            self.net_j <= p.tank_initial_j + 1e-9,
            "{what}: net delivered {} J > initial tank {} J",
            self.net_j,
            p.tank_initial_j
        );
        assert!(
            self.worst_window_j <= p.tank_max_j + 1e-9,
            "{what}: a window delivered {} J > tank {} J",
            self.worst_window_j,
            p.tank_max_j
        );
    }
}

/// A hand script: (time s, position along the drive axis m, off-axis m,
/// roll rad). On the ticks in `wild` the service gets a pose 5 cm off the
/// stylus (as the soak's wild-pose fault sends), which its watchdog
/// rejects.
fn run(script: &[(f64, f64, f64, f64)], params: &PassivityParams, wire: &WireParams, wild: &[usize]) -> Run {
    // A vessel far from the stylus: the tool never touches it; the tick's
    // force is the wire's.
    let (servo, _plate) = common::far_plate_servo::<R>(DT);
    let mut tick = HapticTick::new(servo, PassivityFilter::new(params).unwrap());

    // The wire in a 2 mm tube along x with a dead end 60 mm in.
    let tube = StraightTube::new(Vec3::new(-0.01, 0.0, 0.0), Vec3::x(), 0.07, 2e-3, true).expect("tube");
    let mut w = Wire::new(wire, Vec3::zeros(), Vec3::x(), 0.02).expect("wire");
    let mut drive = HubDrive::new(wire, w.inserted(), w.roll()).expect("drive");
    let a = Vec3::from(wire.drive.axis).normalize();
    let side = a.cross(&Vec3::x()).try_normalize(1e-9).unwrap_or(Vec3::y());
    let pts: Vec<Waypoint> = script
        .iter()
        .map(|&(t, along, off, _)| Waypoint {
            t_s: t,
            position: Vec3::from(wire.drive.origin_m) + a * along + side * off,
        })
        .collect();
    let gim: Vec<GimbalWaypoint> = script
        .iter()
        .map(|&(t, _, _, roll)| {
            let mut angles = [0.0; 3];
            angles[wire.drive.roll_index] = roll;
            GimbalWaypoint {
                t_s: t,
                angles_rad: angles,
            }
        })
        .collect();
    let mut dev = TouchXSim::new(TouchXParams::default(), &pts).unwrap();
    dev.set_gimbal_script(&gim).unwrap();
    dev.start().unwrap();

    let end = script.last().unwrap().0;
    let steps = (end / DT) as usize;
    let mut axial = 0.0;
    let (mut axial_max, mut force_max) = (0.0f64, 0.0f64);
    let (mut min_net, mut worst) = (0.0f64, 0.0f64);
    for k in 1..=steps {
        let t = k as f64 * DT;
        let mut s = dev.read(t).unwrap();
        if wild.contains(&k) {
            s.position.x += 0.05;
        }
        let cmd = drive.command(&s, t);
        let wire_part = Contribution {
            force: drive.hand_force(&s, axial),
            ..Contribution::default()
        };
        let out = tick.run_with(
            TickInput {
                sample: Some(&s),
                now_s: t,
                overrun_streak: 0,
            },
            &[Contribution::PROBE, wire_part],
        );
        let applied = dev.write_force(out.force).unwrap();
        assert!(applied.iter().all(|v| v.is_finite()), "tick {k}: force {applied:?}");
        force_max = force_max.max(applied.norm());
        w.set_hub(cmd.inserted_m, cmd.roll_rad);
        let rep = w.step(&tube).unwrap_or_else(|e| panic!("tick {k}: wire step: {e}"));
        axial = rep.hub_axial_force_n;
        axial_max = axial_max.max(axial);
        let e = dev.port_energy().unwrap();
        let net = e.delivered_j - e.absorbed_j;
        min_net = min_net.min(net);
        worst = worst.max(net - min_net).max(net);
    }
    let e = dev.port_energy().unwrap();
    let q = tick.qp_stats();
    Run {
        net_j: e.delivered_j - e.absorbed_j,
        worst_window_j: worst,
        axial_max_n: axial_max,
        force_max_n: force_max,
        tank_low_j: q.tank_low_j,
        observed: (q.delivered_j, q.absorbed_j),
    }
}

fn wire() -> WireParams {
    WireParams {
        segment_length_m: 3e-3,
        max_nodes: 40,
        drive: DriveParams {
            axis: [1.0, 0.0, 0.0],
            origin_m: [0.0; 3],
            inserted_at_origin_m: 0.02,
            ..DriveParams::default()
        },
        ..WireParams::default()
    }
}

#[test]
fn a_careless_hand_striking_about_gets_no_more_than_it_put_in_plus_the_tank() {
    let p = PassivityParams::default();
    // Fast strikes along and across the axis (up to ~1 m/s), the guide
    // saturating, the hub rate-limited: a seeded random walk of waypoints.
    let mut rng = 7u64;
    let mut next = || {
        rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut script = vec![(0.0, 0.0, 0.0, 0.0), (0.2, 0.0, 0.0, 0.0)];
    let mut t = 0.2;
    for _ in 0..60 {
        t += 0.02 + 0.15 * next();
        script.push((t, -0.01 + 0.04 * next(), -0.03 + 0.06 * next(), -1.0 + 2.0 * next()));
    }
    script.push((t + 0.3, 0.0, 0.0, 0.0));
    let r = run(&script, &p, &wire(), &[]);
    r.print_and_check_energy("careless hand", &p);
    assert!(
        r.force_max_n > 1.0,
        "the hand felt the wire and the guide: {} N",
        r.force_max_n
    );
}

#[test]
fn pushing_the_wire_into_a_dead_end_delivers_no_more_than_went_in_plus_the_tank() {
    let p = PassivityParams::default();
    // Along the axis (×3 on the hub): the dead end is 40 mm of wire away,
    // 13 mm of stylus. Push 10 mm past it slowly, hold, pull back fast,
    // strike in fast, wobble across the axis and roll, withdraw.
    let script = [
        (0.0, 0.0, 0.0, 0.0),
        (0.2, 0.0, 0.0, 0.0),
        (1.2, 0.023, 0.0, 0.0),
        (1.7, 0.023, 0.0, 0.0),
        (1.75, 0.0, 0.0, 0.0),
        (2.0, 0.0, 0.0, 0.0),
        (2.05, 0.025, 0.0, 0.0),
        (2.3, 0.025, 0.004, 1.0),
        (2.5, 0.020, -0.004, -1.0),
        (2.7, 0.024, 0.003, 0.5),
        (3.0, 0.024, 0.0, 0.0),
        (3.3, 0.0, 0.0, 0.0),
        (3.6, 0.0, 0.0, 0.0),
    ];
    let r = run(&script, &p, &wire(), &[]);
    r.print_and_check_energy("dead end", &p);
    assert!(
        r.axial_max_n > 1.0,
        "the wire was pushed into the dead end: {} N",
        r.axial_max_n
    );
    assert!(r.force_max_n > 1.0, "the hand felt it: {} N", r.force_max_n);
}

#[test]
fn a_wild_pose_neither_credits_nor_charges_the_tank() {
    let p = PassivityParams::default();
    // Pushing on the wire in the dead end (the hand feels ~3 N) when the
    // service gets single poses 5 cm off: the force times such a jump would
    // be a 0.15 J credit or charge to the tank's observer.
    let script = [
        (0.0, 0.0, 0.0, 0.0),
        (0.2, 0.0, 0.0, 0.0),
        (1.2, 0.023, 0.0, 0.0),
        (2.5, 0.023, 0.002, 0.0),
        (3.0, 0.0, 0.0, 0.0),
    ];
    let wild = [1100, 1500, 1501, 2000, 2600];
    let r = run(&script, &p, &wire(), &wild);
    let observed = r.observed.0 - r.observed.1;
    assert!(r.force_max_n > 1.0, "the hand felt the wire: {} N", r.force_max_n);
    assert!(
        (observed - r.net_j).abs() < 5e-3,
        "the observer counted {observed} J net, the port delivered {} J",
        r.net_j
    );
    r.print_and_check_energy("wild poses", &p);
}
