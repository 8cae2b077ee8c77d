//! Rough timing of the hub drive's per-tick work (a single run with
//! `Instant` on a shared machine, not a benchmark): `HubDrive::command` plus
//! `HubDrive::hand_force` on a moving, rolling stylus, per call, as the
//! median and the 99.9th percentile of batches of 1000 calls.
//!
//! `cargo run --release --example hub_drive_timing [batches]` (default 2000).

use nvtmm::haptics::DeviceSample;
use nvtmm::math::Vec3;
use nvtmm::wire::drive::HubDrive;
use nvtmm::wire::WireParams;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let batches: usize = match std::env::args().nth(1) {
        Some(a) => a.parse()?,
        None => 2000,
    };
    let w = WireParams::default();
    let mut d = HubDrive::new(&w, 0.18, 0.0)?;
    let mut per_call_ns = Vec::with_capacity(batches);
    let mut acc = 0.0;
    let mut k = 0u64;
    for _ in 0..batches {
        let t0 = Instant::now();
        for _ in 0..1000 {
            k += 1;
            let t = k as f64 * 1e-3;
            let s = DeviceSample {
                position: Vec3::new(0.002 * (3.0 * t).sin(), 0.001, -0.04 * (0.5 * t).sin()),
                velocity: Vec3::new(0.006 * (3.0 * t).cos(), 0.0, -0.02 * (0.5 * t).cos()),
                gimbal_rad: [0.0, 0.0, nvtmm::haptics::device::wrap_angle(2.0 * t)],
                time_s: t,
                seq: k,
                ..DeviceSample::REST
            };
            let c = d.command(std::hint::black_box(&s), t);
            let f = d.hand_force(&s, std::hint::black_box(0.5));
            acc += c.inserted_m + c.roll_rad + f.z;
        }
        per_call_ns.push(t0.elapsed().as_secs_f64() * 1e9 / 1000.0);
    }
    per_call_ns.sort_by(f64::total_cmp);
    let q = |p: f64| per_call_ns[((per_call_ns.len() - 1) as f64 * p) as usize];
    println!(
        "hub drive command + hand_force: median {:.1} ns, p99.9 {:.1} ns per tick ({} batches of 1000; checksum {:.3})",
        q(0.5),
        q(0.999),
        batches,
        acc
    );
    Ok(())
}
