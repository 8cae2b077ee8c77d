//! The shipped cannulation scenarios as they are, one after another in one
//! test binary (each runs the RT service; two at once would share the
//! loop's CPU): `rt-config/cannulate_left_subclavian.toml`,
//! `cannulate_brachiocephalic.toml` and `cannulate_left_common_carotid.toml`.
//! From the guided femoral access, in the living arch (0.7 MPa), the
//! scripted hand works an angled-tip wire and a 5 F vertebral catheter
//! over it with the switch button (docs/scenes.md "Cannulation
//! scenarios"). The report names each instrument's tip segment: the wire's
//! tip ends at least 20 mm into the target branch and the catheter's at
//! least 10 mm, with no reset, no penetration of either rod into the
//! vessel's wall, nor of the wire into the catheter's, beyond 0.2 mm and
//! no allocation after start. The carotid's hand watches where the wire's
//! tip goes and tries again when it misses (docs/INSTRUMENTS.md "A hand
//! that watches"): the test also checks that a try found the carotid and
//! that the catheter's watched advance met its condition. The rods take a fixed
//! number of Newton iterations past their configured ones
//! (`wire.max_extra_iterations`), so the outcome does not hang on the
//! machine's load (docs/WIRE.md "A fixed budget of extra iterations").
//! Runs RT threads: run it alone (`cargo test --release --test
//! cannulates_the_supra_aortic_branches -- --nocapture`); 13 to 47 s of
//! simulated time each.

mod common;

use std::sync::Mutex;

#[global_allocator]
static ALLOC: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

/// One service at a time: the test harness runs tests on parallel threads.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn cannulates(file: &str, target: &str) -> nvtmm::service::Report {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let report = common::guidewire::run_unless_the_machine_paused(&root.join("rt-config").join(file));
    common::guidewire::assert_cannulated(&report, target);
    report
}

/// The easy target: the wire pushed up the descending aorta enters it
/// without a turn, and the catheter tracks over it.
#[test]
fn the_wire_leads_and_the_catheter_tracks_into_the_left_subclavian() {
    cannulates("cannulate_left_subclavian.toml", "left_subclavian");
}

/// The wire, its tip turned half a turn, leads over the arch into the
/// trunk; the catheter, turned the same way, tracks over it.
#[test]
fn the_wire_turned_to_the_right_leads_and_the_catheter_tracks_into_the_brachiocephalic_trunk() {
    cannulates("cannulate_brachiocephalic.toml", "brachiocephalic");
}

/// The wire, turned away from the left subclavian, leads past its ostium;
/// the catheter follows to below the carotid's ostium; the wire's tip is
/// turned back toward the carotid and advanced out of the catheter, the
/// hand watching its tip: a try that finds the carotid ends the wire's
/// advance, a miss is pulled back and tried again turned a little
/// further; the catheter tracks over the wire until its tip is in.
#[test]
fn the_catheter_holds_the_wire_below_the_ostium_and_the_watched_wire_leads_into_the_left_common_carotid() {
    let report = cannulates("cannulate_left_common_carotid.toml", "left_common_carotid");
    let w = &report.hand_watches;
    // Five tries of the wire (rows 7, 10, 13, 16, 19), then the catheter (row 21).
    assert_eq!(
        w.iter().map(|h| h.row).collect::<Vec<_>>(),
        [7, 10, 13, 16, 19, 21],
        "{w:?}"
    );
    assert!(
        w[..5].iter().any(|h| h.met),
        "no try of the wire found the carotid: {w:?}"
    );
    let last = w[5].clone();
    assert!(last.reached && last.met, "the catheter's watched advance: {last:?}");
}
