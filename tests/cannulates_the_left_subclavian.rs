//! The shipped `rt-config/cannulate_left_subclavian.toml` as it is: from
//! the guided femoral access, in the living arch (0.7 MPa), the scripted
//! hand leads with the angled-tip wire into the left subclavian artery,
//! switches to the 5 F vertebral catheter and tracks it over the wire into
//! the branch, switches back and advances the wire. The report names each
//! instrument's tip segment: the wire's tip ends at least 20 mm into the
//! left subclavian and the catheter's at least 10 mm, with no reset, no
//! penetration of either rod into the vessel's wall beyond 0.2 mm and no
//! allocation after start. Runs RT
//! threads: run it alone (`cargo test --release --test
//! cannulates_the_left_subclavian -- --nocapture`); 20 s of simulated
//! time.

mod common;

#[global_allocator]
static ALLOC: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

#[test]
fn the_wire_leads_and_the_catheter_tracks_into_the_left_subclavian() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let cfg = root.join("rt-config/cannulate_left_subclavian.toml");
    let report = common::guidewire::run_unless_the_machine_paused(&cfg);
    common::guidewire::assert_cannulated(&report, "left_subclavian");
}
