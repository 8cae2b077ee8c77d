//! Two instruments' point loads on the reduced model add up, tick after
//! tick: the haptic tick given two contributions steps the vessel exactly
//! as under one contribution carrying both sets of loads, and not as under
//! the second set alone (what a replacing `set_point_loads` per instrument
//! would leave). Their hand forces add before the passivity filter, and a
//! tick with three instruments allocates nothing.

mod common;

use common::counting::{count_allocations, Counting};
use nvtmm::haptics::device::DeviceSample;
use nvtmm::haptics::passivity::{PassivityFilter, PassivityParams};
use nvtmm::haptics::tick::{Contribution, HapticTick, TickInput};
use nvtmm::math::Vec3;

#[global_allocator]
static ALLOC: Counting = Counting;

const R: usize = 8;
const DT: f64 = 1e-3;

fn plate_tick() -> (HapticTick<R>, Vec<u32>, Vec3) {
    let (servo, plate) = common::far_plate_servo::<R>(DT);
    let tick = HapticTick::new(servo, PassivityFilter::new(&PassivityParams::default()).unwrap());
    (tick, plate.contact.clone(), plate.center)
}

fn input(sample: &DeviceSample, k: usize) -> TickInput<'_> {
    TickInput {
        sample: Some(sample),
        now_s: k as f64 * DT,
        overrun_streak: 0,
    }
}

fn sample(k: usize) -> DeviceSample {
    DeviceSample {
        seq: k as u64,
        time_s: k as f64 * DT,
        ..DeviceSample::REST
    }
}

#[test]
fn two_instruments_point_loads_add_up_and_the_tick_allocates_nothing() {
    let (mut two, nodes, _) = plate_tick();
    let (mut one, _, _) = plate_tick();
    let (mut last_only, _, _) = plate_tick();
    assert!(nodes.len() >= 4, "{} contact nodes", nodes.len());
    // Instrument A presses two top nodes down; instrument B presses one of
    // them again and a third: the same node loaded by both must add.
    let down = Vec3::new(0.0, 0.0, -0.05);
    let a = [(nodes[0], down), (nodes[1], down * 0.5)];
    let b = [(nodes[1], down * 0.7), (nodes[2], Vec3::new(0.01, 0.0, -0.03))];
    let both: Vec<(u32, Vec3)> = a.iter().chain(&b).copied().collect();
    let fa = Vec3::new(0.1, 0.0, 0.0);
    let fb = Vec3::new(0.0, 0.2, 0.0);
    two.prime();
    for k in 1..=200 {
        let s = sample(k);
        let parts = [
            Contribution::PROBE,
            Contribution {
                point_loads: &a,
                force: fa,
                ..Contribution::default()
            },
            Contribution {
                point_loads: &b,
                force: fb,
                ..Contribution::default()
            },
        ];
        let (out_two, allocations) = count_allocations(|| two.run_with(input(&s, k), &parts));
        if k > 1 {
            assert_eq!(allocations, 0, "tick {k} allocated");
        }
        let out_one = one.run_with(
            input(&s, k),
            &[
                Contribution::PROBE,
                Contribution {
                    point_loads: &both,
                    force: fa + fb,
                    ..Contribution::default()
                },
            ],
        );
        last_only.run_with(
            input(&s, k),
            &[
                Contribution::PROBE,
                Contribution {
                    point_loads: &b,
                    ..Contribution::default()
                },
            ],
        );
        assert_eq!(two.servo().point_loads().len(), 4);
        // The hand forces add up before the filter.
        assert!((out_two.desired - (fa + fb)).norm() < 1e-12, "{:?}", out_two.desired);
        assert!((out_two.desired - out_one.desired).norm() < 1e-12);
    }
    let q_two = *two.servo().model().dynamics.q();
    let q_one = *one.servo().model().dynamics.q();
    let q_last = *last_only.servo().model().dynamics.q();
    assert!(q_two.norm() > 0.0, "the loads moved the vessel");
    assert!(
        (q_two - q_one).norm() <= 1e-12 * q_one.norm(),
        "summed contributions {q_two:?} vs one contribution with both {q_one:?}"
    );
    assert!(
        (q_two - q_last).norm() > 0.1 * q_two.norm(),
        "the second instrument's loads did not replace the first's"
    );
    // The share the loads caused is the whole state here (no contact).
    let part = two.servo().point_load_part().q;
    assert!((part - q_two).norm() <= 1e-9 * q_two.norm(), "{part:?} vs {q_two:?}");
}
