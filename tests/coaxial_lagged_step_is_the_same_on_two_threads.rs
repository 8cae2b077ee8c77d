//! The lagged coupled step with the catheter's half on a worker thread
//! (`Coaxial::step_on`) gives the single-threaded lagged step's result to
//! the bit, over hundreds of steps in a curved tube: the wire leading, the
//! pair rolled, the wire pulled back inside, a restore to the last good
//! state on the way. And the lagged coupling is not the Gauss–Seidel one.

mod common;

use nvtmm::math::Vec3;
use nvtmm::rt::thread::RtRequest;
use nvtmm::wire::catheter::{catheter_params, TipShape};
use nvtmm::wire::coaxial::{CatheterWorker, Coaxial, CoaxialReport, Coupling};
use nvtmm::wire::WireParams;

fn tube() -> nvtmm::wire::CurvedTube {
    common::two_radian_bend(4e-3)
}

fn pair(coupling: Coupling) -> Coaxial {
    let w = WireParams {
        max_nodes: 96,
        ..WireParams::default()
    };
    let c = catheter_params(5.0, TipShape::Vertebral);
    let mut p = Coaxial::new(&w, &c, Vec3::zeros(), Vec3::x(), 0.02, 0.015).expect("pair");
    p.set_coupling(coupling);
    p
}

/// Step k's hubs: the wire leads at 50 mm/s, the catheter follows, both
/// roll; then the wire comes back inside.
fn hubs(p: &mut Coaxial, k: usize) {
    let t = k as f64 * 1e-3;
    let wi = if k < 600 {
        0.02 + 0.05 * t
    } else {
        0.05 - 0.08 * (t - 0.6)
    };
    p.set_hubs(wi, 0.3 * t, 0.015 + 0.04 * t, -0.5 * t);
}

fn bits(p: &Coaxial) -> Vec<u64> {
    [p.wire(), p.catheter()]
        .iter()
        .flat_map(|r| r.positions().iter().chain(r.velocities()))
        .flat_map(|x| x.iter().map(|c| c.to_bits()).collect::<Vec<_>>())
        .collect()
}

fn same(
    a: &Result<CoaxialReport, nvtmm::wire::coaxial::CoaxialFault>,
    b: &Result<CoaxialReport, nvtmm::wire::coaxial::CoaxialFault>,
) -> bool {
    // Reports hold f64s: compare their bits through Debug's exact
    // round-trip formatting.
    format!("{a:?}") == format!("{b:?}")
}

#[test]
fn the_threaded_lagged_step_is_the_single_threaded_one_to_the_bit() {
    let lumen = tube();
    let mut one = pair(Coupling::Lagged);
    let mut two = pair(Coupling::Lagged);
    let mut gs = pair(Coupling::GaussSeidel);
    let request = RtRequest {
        fifo_priority: None,
        cpu: None,
        prefault_stack_bytes: 0,
    };
    let mut worker = CatheterWorker::spawn(&request, None).expect("worker");
    let (mut sheath, mut walls, mut apart) = (0usize, 0usize, 0.0_f64);
    for k in 0..900 {
        for p in [&mut one, &mut two, &mut gs] {
            hubs(p, k);
        }
        let a = one.step(&lumen);
        let b = two.step_on(&lumen, &mut worker);
        let _ = gs.step(&lumen);
        assert!(same(&a, &b), "step {k}: reports differ\n{a:?}\n{b:?}");
        assert!(bits(&one) == bits(&two), "step {k}: states differ");
        if let Ok(r) = &a {
            sheath += r.wire.sheath_contacts;
            walls += one.wall_contacts().count();
        }
        apart = apart.max((one.catheter().tip() - gs.catheter().tip()).norm());
        if k % 100 == 0 {
            one.save_good_state();
            two.save_good_state();
        }
        // A restore (as after a fault): the next step couples afresh.
        if k == 450 || a.is_err() {
            one.restore_good_state();
            two.restore_good_state();
        }
    }
    assert!(
        sheath > 1000 && walls > 100,
        "no test: {sheath} sheath and {walls} wall contacts"
    );
    // The lagged coupling is another scheme: its catheter ends elsewhere.
    assert!(apart > 1e-9, "the lagged pair followed the Gauss-Seidel one exactly");
    assert_eq!(worker.stop(), 0);
}

#[test]
fn a_gauss_seidel_pair_steps_in_the_callers_thread_as_before() {
    let lumen = tube();
    let mut a = pair(Coupling::GaussSeidel);
    let mut b = pair(Coupling::GaussSeidel);
    let request = RtRequest {
        fifo_priority: None,
        cpu: None,
        prefault_stack_bytes: 0,
    };
    let mut worker = CatheterWorker::spawn(&request, None).expect("worker");
    for k in 0..200 {
        hubs(&mut a, k);
        hubs(&mut b, k);
        let ra = a.step(&lumen);
        let rb = b.step_on(&lumen, &mut worker);
        assert!(same(&ra, &rb), "step {k}");
    }
    assert!(bits(&a) == bits(&b));
    assert_eq!(Coupling::from_name("lagged"), Some(Coupling::Lagged));
    assert_eq!(
        Coupling::from_name(Coupling::GaussSeidel.name()),
        Some(Coupling::GaussSeidel)
    );
}

/// A worker asleep past the steps (its wake time seconds ahead): the
/// pair's thread takes each step back and runs it itself, with the same
/// result to the bit.
#[test]
fn a_step_the_worker_has_not_begun_is_taken_back_with_the_same_result() {
    let lumen = tube();
    let mut one = pair(Coupling::Lagged);
    let mut two = pair(Coupling::Lagged);
    let request = RtRequest {
        fifo_priority: None,
        cpu: None,
        prefault_stack_bytes: 0,
    };
    let mut worker = CatheterWorker::spawn(&request, None).expect("worker");
    // After its first step the worker sleeps until 2 s from now.
    worker.wake_at(nvtmm::rt::clock::now_ns() + 2_000_000_000);
    for k in 0..300 {
        hubs(&mut one, k);
        hubs(&mut two, k);
        let a = one.step(&lumen);
        let b = two.step_on(&lumen, &mut worker);
        assert!(same(&a, &b), "step {k}: reports differ\n{a:?}\n{b:?}");
        assert!(bits(&one) == bits(&two), "step {k}: states differ");
    }
    // Every lagged step but the first (a Gauss-Seidel one) and the one the
    // worker may have claimed before it slept.
    assert!(worker.taken_back() >= 297, "{} taken back", worker.taken_back());
    assert_eq!(worker.stop(), 0);
}
