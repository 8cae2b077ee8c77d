//! The passivity QP on a thread marked RT: clarabel's per-solve allocation
//! is served by the RT pool, and the thread makes no system-allocator call.
//! Also: a pool block freed by another thread goes back to the pool.
//! (Integration test: it installs `RtAllocator` as this binary's global
//! allocator.)

use nvtmm::haptics::passivity::{PassivityFilter, PassivityParams};
use nvtmm::math::Vec3;
use nvtmm::rt::alloc::{self, RtAllocator};

#[global_allocator]
static ALLOC: RtAllocator = RtAllocator;

/// Throw-away clarabel solves run on the RT thread after the ticks.
const PRIMES: u64 = 200;

#[test]
fn qp_allocates_nothing_on_the_rt_thread() {
    // Built off the RT thread (allocates), used on it.
    let mut filter = PassivityFilter::new(&PassivityParams::default()).unwrap();
    let (sys, handoff, solves, exact, before) = std::thread::spawn(move || {
        let info = alloc::enter_rt(1 << 20).unwrap();
        assert!(info.installed, "{info:?}");
        // The first solve on this thread frees clarabel's set-up timer block
        // (a system block): prime moves that free before the loop.
        filter.prime();
        let sys0 = alloc::thread_system_calls();
        let before = alloc::stats();
        let mut s = 0x9E3779B97F4A7C15u64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut x = Vec3::zeros();
        for k in 0..5000 {
            let v = Vec3::new(next(), next(), next()) * 0.4;
            x += v * 1e-3;
            let f_des = Vec3::new(next(), next(), next()) * if k % 7 == 0 { 40.0 } else { 6.0 };
            let out = filter.filter(f_des, x, v);
            assert!(out.force.iter().all(|c| c.is_finite()));
        }
        // Most of those solves are answered by the exact active-set step
        // without clarabel; these run clarabel itself, as the loop does
        // when no active set is certified.
        for _ in 0..PRIMES {
            filter.prime();
        }
        // A block allocated here and freed on another thread.
        let handoff = Box::new([7u8; 100]);
        let sys = alloc::thread_system_calls() - sys0;
        alloc::leave_rt();
        let st = filter.stats();
        (sys, handoff, st.solves, st.exact, before)
    })
    .join()
    .unwrap();
    let after = alloc::stats();
    assert_eq!(sys, 0, "system-allocator calls from the RT thread");
    assert_eq!(after.system_calls_on_rt, before.system_calls_on_rt);
    assert!(solves > 4000, "most random ticks need the QP: {solves}");
    let clarabel_solves = solves - exact + PRIMES;
    assert!(
        after.pool_allocs - before.pool_allocs >= clarabel_solves,
        "clarabel's per-solve allocation should come from the pool ({clarabel_solves} clarabel solves): {after:?}"
    );
    assert!(after.pool_high_water_bytes > 0 && after.pool_high_water_bytes < 1 << 20);
    // Cross-thread free: back into the pool.
    let frees = alloc::stats().pool_frees + alloc::stats().deferred_frees;
    assert_eq!(handoff[99], 7);
    drop(handoff);
    let s = alloc::stats();
    assert_eq!(s.pool_frees + s.deferred_frees, frees + 1, "{s:?}");
    assert_eq!(s.exhausted_fallbacks, 0);
    eprintln!("{s:?}");
}
