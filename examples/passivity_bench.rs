//! Solve time and iterations of the passivity QP on random data, on a
//! thread marked RT (the allocator of the `nvtmm` binary).
//!
//! `cargo run --release --example passivity_bench -- [ticks]`

use nvtmm::haptics::passivity::{PassivityFilter, PassivityParams};
use nvtmm::math::Vec3;
use nvtmm::rt::alloc::{self, RtAllocator};
use nvtmm::rt::clock::now_ns;

#[global_allocator]
static ALLOC: RtAllocator = RtAllocator;

fn main() {
    let ticks: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(20_000);
    let mut filter = PassivityFilter::new(&PassivityParams::default()).expect("default parameters are valid");
    let mut times = Vec::with_capacity(ticks);
    let handle = std::thread::spawn(move || {
        let info = alloc::enter_rt(1 << 20).expect("RT pool");
        filter.prime();
        let sys0 = alloc::thread_system_calls();
        let mut s = 0x9E3779B97F4A7C15u64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        // A wall-like signal: a slowly varying desired force with jumps, a
        // stylus moving at up to 0.2 m/s.
        let mut x = Vec3::zeros();
        for k in 0..ticks {
            let v = Vec3::new(next(), next(), next()) * 0.4;
            x += v * 1e-3;
            let f_des = Vec3::new(next(), next(), next()) * if k % 50 == 0 { 20.0 } else { 6.0 };
            let t0 = now_ns();
            let out = filter.filter(f_des, x, v);
            times.push((now_ns() - t0) as f64 * 1e-3);
            std::hint::black_box(out);
        }
        let sys = alloc::thread_system_calls() - sys0;
        alloc::leave_rt(); // the filter is dropped below, off the pool
        (times, *filter.stats(), sys, info)
    });
    let (mut times, st, sys, info) = handle.join().expect("bench thread");
    times.sort_by(|a, b| a.total_cmp(b));
    let q = |p: f64| times[((p * times.len() as f64) as usize).min(times.len() - 1)];
    println!("ticks {ticks}, pool installed {}", info.installed);
    println!(
        "filter() time us: median {:.1}, p99 {:.1}, p99.9 {:.1}, max {:.1}",
        q(0.5),
        q(0.99),
        q(0.999),
        times[times.len() - 1]
    );
    println!(
        "iterations: median {}, p99 {}, max {}",
        st.iter_quantile(0.5),
        st.iter_p99(),
        st.iter_quantile(1.0)
    );
    println!(
        "solves {}: {} exact on their active set, {} by the interior-point solver; shortcuts {}",
        st.solves,
        st.exact,
        st.solves - st.exact,
        st.interior
    );
    println!(
        "active: norm {}, rate {} (exceeded {}), energy {}; fallbacks {}",
        st.active_norm,
        st.active_rate,
        st.rate_exceeded,
        st.active_energy,
        st.fallbacks()
    );
    println!(
        "system-allocator calls on the RT thread: {sys}; allocator {:?}",
        alloc::stats()
    );
}
