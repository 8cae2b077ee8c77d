//! The whole haptic chain in closed loop, in simulated time: the simulated
//! Touch X (scripted hand, stylus dynamics, quantized encoders, force
//! saturation) → contact with the reduced NVTMM model → passivity QP →
//! watchdog gain → the device. At the stiffest material of the test range
//! (E = 10 MPa) and approach speeds up to 0.5 m/s, the energy the device
//! port delivers to the hand never exceeds what the hand put in plus the
//! QP's initial tank (measured with the device's true velocity).

mod common;

use nvtmm::haptics::contact::{ContactParams, SurfaceIndex};
use nvtmm::haptics::device::HapticDevice;
use nvtmm::haptics::passivity::{PassivityFilter, PassivityParams};
use nvtmm::haptics::servo::{Servo, ServoParams};
use nvtmm::haptics::tick::{HapticTick, TickInput};
use nvtmm::haptics::touchx::{TouchXParams, TouchXSim, Waypoint};
use nvtmm::material::Material;
use nvtmm::math::Vec3;
use nvtmm::reduced::{basis_rows, DynamicsParams, Refresher};
use nvtmm::service::background::rest_model;
use std::sync::Arc;

const R: usize = 16;
const DT: f64 = 1e-3;

/// Runs one press at `speed` (m/s); returns (delivered, absorbed, max force, max depth).
fn press(speed: f64) -> (f64, f64, f64, f64) {
    let mat = Material {
        youngs_pa: 10e6,
        ..Material::aorta()
    };
    let common::ContactPlate {
        mesh,
        model,
        mass,
        basis,
        center,
        ..
    } = common::contact_plate(&mat, &["x_min", "x_max", "z_min"], R);
    let zeros = vec![Vec3::zeros(); mesh.num_nodes()];
    let rows = basis_rows::<R>(&basis).unwrap();
    let k0 = Refresher::new(&mesh, &basis, &mass).reduced_stiffness(&model, &zeros);
    let dynp = DynamicsParams {
        dt: DT,
        alpha: 5.0,
        beta: 1e-3,
    };
    let first = rest_model::<R>(rows, &k0, &dynp, mesh.num_nodes()).unwrap();
    let cp = ContactParams {
        tool_radius_m: 3e-3,
        pressure_stiffness: 1e9,
        search_margin_m: 3e-3,
    };
    let index = Arc::new(SurfaceIndex::new(&mesh, &cp));
    let sp = ServoParams {
        dt: DT,
        contact: cp,
        device_origin: center,
        device_timeout_s: 5e-3,
        model_timeout_s: f64::INFINITY,
        model_max_age_s: f64::INFINITY,
        max_speed_m_s: 100.0,
        max_reach_m: 10.0,
        overrun_streak: 5,
        ramp_down_s: 10e-3,
        ramp_in_s: 0.0,
        swap_blend_s: 0.02,
        command_timeout_s: nvtmm::haptics::device::DEFAULT_COMMAND_TIMEOUT_S,
    };
    let servo = Servo::new(first, index, sp, 0.0);
    let qp = PassivityParams::default();
    let filter = PassivityFilter::new(&qp).unwrap();
    // The service's own tick: contact -> reduced step -> QP -> watchdog gain.
    let mut tick = HapticTick::new(servo, filter);
    // Device frame = scene frame shifted by `center` (the wall top there).
    let above = Vec3::new(0.0, 0.0, 3e-3 + 5e-3);
    let inside = Vec3::new(0.0, 0.0, 3e-3 - 4e-3);
    let travel = (above - inside).norm() / speed;
    let pts = [
        Waypoint {
            t_s: 0.0,
            position: above,
        },
        Waypoint {
            t_s: 0.2,
            position: above,
        },
        Waypoint {
            t_s: 0.2 + travel,
            position: inside,
        },
        Waypoint {
            t_s: 0.6 + travel,
            position: inside,
        },
        Waypoint {
            t_s: 0.6 + 2.0 * travel,
            position: above,
        },
        Waypoint {
            t_s: 1.2 + 2.0 * travel,
            position: above,
        },
    ];
    let mut dev = TouchXSim::new(TouchXParams::default(), &pts).unwrap();
    dev.start().unwrap();
    let (mut max_f, mut max_depth) = (0.0f64, 0.0f64);
    let steps = ((1.2 + 2.0 * travel) / DT) as usize;
    for k in 1..=steps {
        let t = k as f64 * DT;
        let s = dev.read(t).unwrap();
        let out = tick.run(TickInput {
            sample: Some(&s),
            now_s: t,
            overrun_streak: 0,
        });
        let applied = dev.write_force(out.force).unwrap();
        max_f = max_f.max(applied.norm());
        max_depth = max_depth.max(out.depth);
        assert!(applied.iter().all(|v| v.is_finite()));
    }
    let e = dev.port_energy().unwrap();
    (e.delivered_j, e.absorbed_j, max_f, max_depth)
}

#[test]
fn energy_delivered_never_exceeds_energy_absorbed_plus_the_tank() {
    let tank = PassivityParams::default().tank_initial_j;
    for speed in [0.02, 0.1, 0.3, 0.5] {
        let (out, inn, max_f, depth) = press(speed);
        eprintln!(
            "speed {speed} m/s: delivered {out:.5} J, absorbed {inn:.5} J, net {:.5} J, max force {max_f:.3} N, max depth {:.3} mm",
            out - inn,
            depth * 1e3
        );
        assert!(max_f > 0.5, "the wall was touched and pushed back: {max_f} N");
        assert!(
            out - inn <= tank,
            "speed {speed}: net delivered {} J > tank {tank} J",
            out - inn
        );
        assert!(max_f <= 7.9 + 1e-9, "saturated to the peak force");
    }
}
