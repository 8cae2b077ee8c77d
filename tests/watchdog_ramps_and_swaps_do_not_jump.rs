//! The haptic loop's tick on a small plate: the watchdog takes the force to
//! zero within its ramp time when the device goes silent or sends a
//! non-finite value (and the reduced state resets), and a model refreshed
//! from the full NVTMM solve swaps in mid-contact without a force jump, in
//! the same basis and in a basis recomputed at the full solve's state (the
//! background basis refresh).

mod common;

use nvtmm::haptics::contact::{ContactParams, SurfaceIndex};
use nvtmm::haptics::device::DeviceSample;
use nvtmm::haptics::servo::{flags, LoopModel, Servo, ServoParams};
use nvtmm::material::Material;
use nvtmm::math::Vec3;
use nvtmm::mesh::TetMesh;
use nvtmm::model::nvtmm::Nvtmm;
use nvtmm::model::{BlockTangent, ForceModel};
use nvtmm::reduced::{basis_rows, BasisParams, DynamicsParams, ModalBasis, Refresher};
use nvtmm::service::background::{rest_model, Background, BasisPolicy};
use nvtmm::solver::loads::{Loads, NodalLoad, TimeProfile};
use nvtmm::solver::{ImplicitEuler, ImplicitEulerParams, NewtonParams, TissueState};
use std::sync::Arc;

const R: usize = 16;
const DT: f64 = 1e-3;

struct Plate {
    mesh: TetMesh,
    model: Nvtmm,
    mass: Vec<f64>,
    fixed: Vec<u32>,
    basis: ModalBasis,
    top: f64,
    center: Vec3,
    contact: Vec<u32>,
}

fn plate() -> Plate {
    // Clamped at x = 0 and x = 24 mm.
    let p = common::contact_plate(&Material::aorta(), &["x_min", "x_max"], R);
    Plate {
        mesh: p.mesh,
        model: p.model,
        mass: p.mass,
        fixed: p.fixed,
        basis: p.basis,
        top: 0.004,
        center: p.center,
        contact: p.contact,
    }
}

fn dynamics() -> DynamicsParams {
    DynamicsParams {
        dt: DT,
        alpha: 5.0,
        beta: 1e-3,
    }
}

fn servo(p: &Plate) -> Servo<R> {
    let rows = basis_rows::<R>(&p.basis).unwrap();
    let mut refresher = Refresher::new(&p.mesh, &p.basis, &p.mass);
    let zeros = vec![Vec3::zeros(); p.mesh.num_nodes()];
    let k0 = refresher.reduced_stiffness(&p.model, &zeros);
    let m = rest_model::<R>(rows, &k0, &dynamics(), p.mesh.num_nodes()).unwrap();
    let contact = ContactParams {
        tool_radius_m: 3e-3,
        pressure_stiffness: 1e8,
        search_margin_m: 4e-3,
    };
    let index = Arc::new(SurfaceIndex::new(&p.mesh, &contact));
    let params = ServoParams {
        dt: DT,
        contact,
        device_origin: Vec3::zeros(),
        device_timeout_s: 5e-3,
        model_timeout_s: f64::INFINITY,
        model_max_age_s: f64::INFINITY,
        max_speed_m_s: 100.0,
        max_reach_m: 10.0,
        overrun_streak: 5,
        ramp_down_s: 10e-3,
        ramp_in_s: 0.05,
        swap_blend_s: 0.02,
        command_timeout_s: nvtmm::haptics::device::DEFAULT_COMMAND_TIMEOUT_S,
    };
    Servo::new(m, index, params, 0.0)
}

fn sample(pos: Vec3, seq: u64, t: f64) -> DeviceSample {
    DeviceSample {
        position: pos,
        velocity: Vec3::zeros(),
        buttons: 0,
        time_s: t,
        seq,
        gimbal_rad: [0.0; 3],
    }
}

/// One tick with the gain applied (no passivity filter here).
fn tick(s: &mut Servo<R>, smp: Option<&DeviceSample>, t: f64) -> (Vec3, u32) {
    let out = s.tick(smp, t, 0);
    let mut fl = out.flags;
    let f = s.apply_gain(out.desired, &mut fl);
    (f, fl)
}

#[test]
fn the_force_ramps_to_zero_within_10_ms_when_the_device_goes_silent_or_sends_nan() {
    let p = plate();
    let mut s = servo(&p);
    // Tool sphere 1 mm into the top face.
    let pos = Vec3::new(p.center.x, p.center.y, p.top + 3e-3 - 1e-3);
    let mut t = 0.0;
    let mut seq = 0;
    let mut f = Vec3::zeros();
    for _ in 0..300 {
        seq += 1;
        t += DT;
        f = tick(&mut s, Some(&sample(pos, seq, t)), t).0;
    }
    assert!(f.z > 1e-3, "the plate pushes the tool up: {f:?}");
    assert_eq!(s.gain(), 1.0);
    // Silence: the same sample again and again.
    let last_fresh = t;
    let stale = sample(pos, seq, t);
    let mut zero_at = None;
    for _ in 0..100 {
        t += DT;
        let (f, fl) = tick(&mut s, Some(&stale), t);
        if t - last_fresh > 5e-3 + 1e-9 {
            assert!(fl & flags::DEVICE_SILENT != 0);
        }
        if f == Vec3::zeros() && zero_at.is_none() {
            zero_at = Some(t);
        }
        if let Some(z) = zero_at {
            assert_eq!(f, Vec3::zeros(), "stays at zero after {z}");
        }
    }
    let z = zero_at.expect("force reached zero");
    // Detected after the 5 ms timeout, then at most 10 ms of ramp.
    assert!(
        z - last_fresh <= 5e-3 + 10e-3 + 2.0 * DT,
        "zero after {} ms",
        (z - last_fresh) * 1e3
    );
    assert!(s.counters().watchdog_ticks > 0);

    // Fresh samples again: the force ramps back in.
    for _ in 0..400 {
        seq += 1;
        t += DT;
        f = tick(&mut s, Some(&sample(pos, seq, t)), t).0;
    }
    assert_eq!(s.gain(), 1.0);
    assert!(f.z > 1e-3);

    // One NaN sample: the reduced state resets and the force goes to zero
    // within 10 ms, then comes back.
    seq += 1;
    t += DT;
    let mut bad = sample(pos, seq, t);
    bad.position.x = f64::NAN;
    let (_, fl) = tick(&mut s, Some(&bad), t);
    assert!(fl & flags::NONFINITE != 0 && fl & flags::WATCHDOG != 0);
    assert!(s.model().dynamics.q().iter().all(|&v| v == 0.0), "state reset");
    let t_nan = t;
    let mut reached = None;
    for _ in 0..200 {
        seq += 1;
        t += DT;
        let (f, _) = tick(&mut s, Some(&sample(pos, seq, t)), t);
        if f == Vec3::zeros() && reached.is_none() {
            reached = Some(t);
        }
    }
    let r = reached.expect("force reached zero after the NaN");
    assert!(r - t_nan <= 10e-3 + DT, "{} ms", (r - t_nan) * 1e3);
    assert!(s.counters().nonfinite >= 1);
    assert!(s.gain() > 0.0, "ramping back in");
}

#[test]
fn a_refreshed_model_swaps_in_mid_contact_without_a_force_jump() {
    swap_mid_contact(false, false);
}

#[test]
fn a_model_in_a_recomputed_basis_swaps_in_mid_contact_without_a_force_jump() {
    swap_mid_contact(true, false);
}

/// The swap's state correction computed on the tick before, as the loop
/// does (`Servo::prepare`).
#[test]
fn a_refreshed_model_prepared_a_tick_ahead_swaps_in_mid_contact_without_a_force_jump() {
    swap_mid_contact(false, true);
}

/// Presses the plate for 1.5 s, runs the full model under the loop's contact
/// forces, builds the refreshed model (in a basis recomputed at the full
/// state, warm-started, if `new_basis`), swaps it in (its correction
/// prepared first, if `prepared`) and bounds the force change per tick over
/// the cross-fade.
fn swap_mid_contact(new_basis: bool, prepared: bool) {
    let p = plate();
    let mut s = servo(&p);
    let pos = Vec3::new(p.center.x, p.center.y, p.top + 3e-3 - 1.5e-3);
    let mut t = 0.0;
    let mut seq = 0;
    let mut f_before = Vec3::zeros();
    for _ in 0..1500 {
        seq += 1;
        t += DT;
        f_before = tick(&mut s, Some(&sample(pos, seq, t)), t).0;
    }
    // The full model under the loop's contact forces, quasi-static.
    let n = p.mesh.num_nodes();
    let node_forces: Vec<(u32, Vec3)> = s.contact().nodes.iter().map(|c| (c.node, c.force)).collect();
    assert!(!node_forces.is_empty());
    let loads = Loads {
        nodal: node_forces
            .iter()
            .map(|&(i, f)| NodalLoad {
                nodes: vec![i],
                force: f,
                profile: TimeProfile::Constant { from_t0: 0.0 },
            })
            .collect(),
        gravity: Vec3::zeros(),
        pressure: None,
    };
    let params = ImplicitEulerParams {
        dt: 0.05,
        rayleigh_alpha: 20.0,
        newton: NewtonParams {
            max_iters: 10,
            rel_tol: 1e-9,
            ..NewtonParams::default()
        },
        ..ImplicitEulerParams::default()
    };
    let mut model = Nvtmm::new(&p.mesh, &Material::aorta());
    let mut solver = ImplicitEuler::new(&p.mesh, p.mass.clone(), params).unwrap();
    let mut state = TissueState::at_rest(n);
    for _ in 0..40 {
        assert!(solver.step(&mut state, &mut model, &loads, &p.fixed).ok());
    }
    let mut fbar = vec![Vec3::zeros(); n];
    for &(i, f) in &node_forces {
        fbar[i as usize] = f;
    }
    // The service gives its models the rows of the loop's first model (one
    // allocation), which is how a swap knows the basis did not change.
    let rows = s.model().dynamics.rows().clone();
    let mut bg = Background::<R> {
        model: Box::new(Nvtmm::new(&p.mesh, &Material::aorta())) as Box<dyn ForceModel>,
        solver: ImplicitEuler::new(&p.mesh, p.mass.clone(), params).unwrap(),
        fixed: p.fixed.clone(),
        refresher: Refresher::new(&p.mesh, &p.basis, &p.mass),
        rows,
        dynamics: dynamics(),
        last_sent: (s.model().offset.clone(), nalgebra::SVector::zeros(), 0),
        dt_max: 0.05,
        basis_policy: BasisPolicy::OFF,
        compliance: None,
        pressure: None,
    };
    let m: Box<LoopModel<R>> = if new_basis {
        // What the basis thread does: the modes of K at the full state,
        // warm-started from the basis in use.
        let mut k = BlockTangent::zeros(&p.mesh);
        model.add_stiffness(&state.u, &mut k);
        let nb = ModalBasis::compute(&nvtmm::reduced::BasisSpec {
            stiffness: nvtmm::reduced::Stiffness::Tangent(&k),
            mass: &p.mass,
            fixed: &p.fixed,
            r: R,
            statics: nvtmm::reduced::Statics::Compressed {
                contact: &p.contact,
                max_static: R / 2,
            },
            warm: Some(&p.basis),
            params: BasisParams::default(),
        })
        .unwrap();
        bg.refresher = Refresher::new(&p.mesh, &nb, &p.mass);
        bg.rows = basis_rows::<R>(&nb).unwrap();
        let (m, _) = bg.build_model(&state.u, &fbar, 1, Some(&p.basis.phi)).unwrap();
        let off_identity = (m.transfer - nalgebra::SMatrix::<f64, R, R>::identity()).norm();
        assert!(off_identity > 1e-3, "the basis changed: ‖T − I‖ = {off_identity:e}");
        m
    } else {
        let (m, qbar) = bg.build_model(&state.u, &fbar, 1, None).unwrap();
        assert_eq!(m.transfer, nalgebra::SMatrix::<f64, R, R>::identity());
        // What the background keeps of the model it sent (the next model's
        // transfer starts from it).
        bg.last_sent = (m.offset.clone(), qbar, 1);
        m
    };
    let ubar_max = state.u.iter().map(|u| u.norm()).fold(0.0, f64::max);
    assert!(ubar_max > 2e-4, "the full solve moved: {ubar_max}");
    // The background measured how far the swap moves a node in the same
    // basis (ū's change from the last model, at rest here, less the part
    // the shift follows); a new basis has no such bound.
    let rest = vec![Vec3::zeros(); n];
    let moved = if new_basis {
        assert_eq!(m.surface_moved_m, None);
        f64::INFINITY
    } else {
        let moved = m.surface_moved_m.expect("same basis: the swap's motion is measured");
        let expected = swap_motion(&m, &rest, &state.u);
        assert!((moved - expected).abs() <= 1e-12, "{moved:e} vs {expected:e}");
        moved
    };
    let carries = moved < nvtmm::haptics::contact::COHERENCE_SLACK_M;
    if prepared {
        // As the loop does: the tick before the swap prepares it.
        std::hint::black_box(s.prepare(&m));
    }
    let old = s.swap(m).map(|o| o.epoch);
    assert_eq!(s.counters().swaps_prepared, (prepared && !new_basis) as u64);
    // In the same basis, with ū moved less than the slack, the swap keeps
    // the contact's triangles (no search); the ticks below check that they
    // give what a fresh search gives.
    assert_eq!(s.counters().swaps_carried, carries as u64, "ū moved {ubar_max:e} m");
    eprintln!(
        "new basis {new_basis}: ū moved {ubar_max:.3e} m, a node at the carried state {moved:.3e} m, contact triangles kept over the swap: {carries}"
    );
    assert_eq!(old, None, "the old model fades out first");
    assert!(s.is_blending());
    assert_eq!(s.model().epoch, 1);
    // Over the cross-fade and after it, no tick changes the force by more
    // than 5 % of the contact force.
    let mut prev = f_before;
    let mut worst: f64 = 0.0;
    let mut retired = None;
    let index = SurfaceIndex::new(&p.mesh, &s.params().contact);
    let mut fresh = nvtmm::haptics::contact::ContactOutput::<R>::for_index(&index);
    let mut scratch = nvtmm::haptics::contact::Candidates::new();
    // The contact a fresh search finds on the model's positions now, which
    // the tick's contact (on the triangles the swap found or kept, then
    // kept) must equal to round-off.
    let mut tick_as_searched = |s: &mut Servo<R>, seq: u64, t: f64, k: usize| {
        let m = s.model();
        nvtmm::haptics::contact::evaluate_spheres(
            &index,
            &s.params().contact,
            &[pos],
            |i| index.rest(i) + m.offset[i as usize] + m.dynamics.displacement_at(i).unwrap_or_else(Vec3::zeros),
            |i| m.dynamics.rows_at(i),
            m.compliance.as_deref(),
            None,
            &mut scratch,
            &mut fresh,
        );
        let f = tick(s, Some(&sample(pos, seq, t)), t).0;
        let c = s.contact();
        let diff = (c.tool_force - fresh.tool_force).norm();
        assert!(
            diff <= 1e-9 * fresh.tool_force.norm().max(1e-9),
            "tick {k}: kept {:?} vs searched {:?}",
            c.tool_force,
            fresh.tool_force
        );
        assert!((c.reduced_stiffness - fresh.reduced_stiffness).norm() <= 1e-9 * fresh.reduced_stiffness.norm());
        f
    };
    for k in 0..60 {
        seq += 1;
        t += DT;
        let f = tick_as_searched(&mut s, seq, t, k);
        worst = worst.max((f - prev).norm());
        prev = f;
        if let Some(r) = s.take_retired() {
            retired = Some(r.epoch);
        }
    }
    eprintln!(
        "new basis {new_basis}: force before {:.5} N, after the blend {:.5} N, largest change per tick {:.2e} N ({:.2} %)",
        f_before.norm(),
        prev.norm(),
        worst,
        100.0 * worst / f_before.norm()
    );
    assert_eq!(retired, Some(0), "the old model is handed back after the blend");
    assert!(!s.is_blending());
    assert!(f_before.norm() > 1e-3);
    assert!(worst <= 0.05 * f_before.norm(), "step {worst} vs {}", f_before.norm());
    if new_basis {
        return;
    }
    // The next refresh in the same basis, ū a little further on (5 % more,
    // well within the contact's slack): the swap keeps the contact's
    // triangles, and every tick after it, through the cross-fade, still
    // gives what a fresh search gives.
    let u2: Vec<Vec3> = state.u.iter().map(|u| u * 1.05).collect();
    let (m2, _) = bg.build_model(&u2, &fbar, 2, None).unwrap();
    let moved = m2.surface_moved_m.expect("same basis: the swap's motion is measured");
    let expected = swap_motion(&m2, &state.u, &u2);
    assert!(
        (moved - expected).abs() <= 1e-12 && moved < nvtmm::haptics::contact::COHERENCE_SLACK_M,
        "the swap moved a node {moved:e} m, expected {expected:e} m"
    );
    s.swap(m2);
    assert_eq!(
        s.counters().swaps_carried,
        carries as u64 + 1,
        "the swap kept the contact's triangles"
    );
    for k in 0..40 {
        seq += 1;
        t += DT;
        tick_as_searched(&mut s, seq, t, k);
        if k == 0 {
            eprintln!(
                "the first tick after the second swap searched {} spheres",
                s.contact().searches
            );
        }
    }
    eprintln!(
        "second swap, ū moved {:.3e} m, a node at the carried state {moved:.3e} m: the contact's triangles kept, every tick as a fresh search",
        0.05 * ubar_max
    );
}

/// How far a swap to `m` (same basis) moves a node: the largest
/// ‖ū_new − ū_old + Φᵢ s‖, its position at the carried state δq + s
/// against its position at δq in the previous model.
fn swap_motion(m: &LoopModel<R>, u_old: &[Vec3], u_new: &[Vec3]) -> f64 {
    u_new
        .iter()
        .zip(u_old)
        .enumerate()
        .map(|(i, (a, b))| (a - b + m.dynamics.rows_at(i as u32).unwrap() * m.shift).norm())
        .fold(0.0, f64::max)
}
