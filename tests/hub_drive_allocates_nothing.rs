//! The guidewire's RT path — read the simulated Touch X (with a scripted
//! roll), the hub drive's command, the wire's step, the hub drive's hand
//! force, the device write — allocates nothing after start, including
//! across clamping, rate limits, unwrapping and an injected NaN sample.

mod common;

use common::counting::count_allocations;
use nvtmm::haptics::touchx::{GimbalWaypoint, TouchXParams, TouchXSim, Waypoint};
use nvtmm::haptics::HapticDevice;
use nvtmm::math::Vec3;
use nvtmm::wire::drive::HubDrive;
use nvtmm::wire::{StraightTube, Wire, WireParams};

#[global_allocator]
static GLOBAL: common::counting::Counting = common::counting::Counting;

#[test]
fn hub_drive_and_wire_tick_allocate_nothing() {
    let (_, n) = count_allocations(|| std::hint::black_box(vec![1u8; 16]));
    assert!(n > 0, "the counting allocator is installed");

    let w = WireParams {
        segment_length_m: 2e-3,
        max_nodes: 40,
        ..WireParams::default()
    };
    let mut wire = Wire::new(&w, Vec3::zeros(), Vec3::x(), 0.01).expect("wire");
    let tube = StraightTube::new(Vec3::new(-0.01, 0.0, 0.0), Vec3::x(), 0.06, 1.5e-3, true).expect("tube");
    let mut drive = HubDrive::new(&w, wire.inserted(), wire.roll()).expect("drive");
    // The hand pushes in (−z) past the dead end, pulls back past 0, sways
    // off the axis, and rolls through ±π twice.
    let script = [
        Waypoint {
            t_s: 0.0,
            position: Vec3::new(0.0, 0.0, 0.0),
        },
        Waypoint {
            t_s: 0.8,
            position: Vec3::new(0.01, -0.005, -0.05),
        },
        Waypoint {
            t_s: 1.6,
            position: Vec3::new(-0.01, 0.005, 0.059),
        },
    ];
    let mut sim = TouchXSim::new(TouchXParams::default(), &script).expect("script");
    sim.set_gimbal_script(&[
        GimbalWaypoint {
            t_s: 0.0,
            angles_rad: [0.0; 3],
        },
        GimbalWaypoint {
            t_s: 1.6,
            angles_rad: [0.0, 0.0, 4.0 * std::f64::consts::PI],
        },
    ])
    .expect("gimbal script");
    sim.inject_non_finite(0.9);
    sim.start().expect("start");
    let (faults, n) = count_allocations(|| {
        let mut faults = 0;
        for i in 0..2000 {
            let t = i as f64 * 1e-3;
            let Ok(s) = sim.read(t) else { continue };
            let c = drive.command(&s, t);
            faults += c.fault as usize;
            wire.set_hub(c.inserted_m, c.roll_rad);
            let axial = match wire.step(&tube) {
                Ok(r) => r.hub_axial_force_n,
                Err(_) => {
                    wire.restore_good_state();
                    drive.reseat(wire.inserted(), wire.roll());
                    0.0
                }
            };
            let f = drive.hand_force(&s, axial);
            let _ = sim.write_force(f);
        }
        faults
    });
    assert_eq!(n, 0, "the tick allocated {n} times");
    assert_eq!(faults, 1, "the injected NaN sample");
    let c = drive.counters();
    assert!(c.clamped > 0 && c.rate_limited > 0, "{c:?}");
    assert!(wire.is_finite());
}
