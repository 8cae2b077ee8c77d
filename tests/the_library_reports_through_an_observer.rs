//! The library does not print: a scene's run reports its progress and end
//! to the observer the caller passes (the `nvtmm` binary renders them as a
//! progress bar), and the trade plot's log axes are labelled at 1, 2 and 5
//! times a power of ten only, with the legend in the emptiest corner.

use nvtmm::experiment::plot::{legend_corner, log_tick_label, Series};
use nvtmm::observe::{Event, Observe, Observer};
use nvtmm::scene::Scene;
use plotters::prelude::{SeriesLabelPosition, BLACK};
use std::path::Path;
use std::sync::{Arc, Mutex};

#[derive(Default)]
struct Log(Mutex<Vec<String>>);

impl Observer for Log {
    fn event(&self, e: Event<'_>) {
        self.0.lock().unwrap().push(format!("{e:?}"));
    }
}

#[test]
fn a_scene_run_reports_its_progress_to_the_observer() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("rt-config/scenes/block_creep.toml"))
        .unwrap()
        .replace("duration = 1.0", "duration = 0.02");
    let scene = Scene::parse(&text, Path::new("block_creep.toml"), &root.join("rt-config/scenes")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let log = Arc::new(Log::default());
    let summary = nvtmm::simulate::run(&scene, dir.path(), &Observe::new(log.clone())).unwrap();
    let events = log.0.lock().unwrap().clone();
    let progress = events
        .iter()
        .filter(|e| e.starts_with("Progress { task: \"simulate\""))
        .count();
    assert_eq!(progress, summary.steps, "one progress event a step: {events:?}");
    assert!(
        events
            .last()
            .unwrap()
            .contains("Finished { task: \"simulate\", ok: true }"),
        "{events:?}"
    );
    // The silent default runs the same.
    nvtmm::simulate::run(&scene, dir.path(), &Observe::none()).unwrap();
    let o = Observe::new(log.clone());
    assert_eq!(o.clone(), o);
    assert_ne!(o, Observe::none());
}

#[test]
fn log_ticks_are_labelled_at_one_two_and_five_only() {
    let labels: Vec<String> = [
        1.0, 2.0, 3.0, 5.0, 7.0, 8.0, 9.0, 10.0, 20.0, 0.01, 0.05, 0.06, 50.0, 60.0,
    ]
    .iter()
    .map(|&v| log_tick_label(v))
    .collect();
    assert_eq!(
        labels,
        ["1", "2", "", "5", "", "", "", "10", "20", "0.01", "0.05", "", "50", ""]
    );
}

#[test]
fn the_legend_goes_to_the_emptiest_corner() {
    let s = |pts: &[(f64, f64)]| Series {
        name: String::new(),
        color: BLACK,
        points: pts.to_vec(),
        markers: true,
    };
    // Data along the top and down the right edge: the lower left is empty.
    let series = [s(&[(0.0, 1.0), (1.0, 1.0), (1.0, 0.0)])];
    let c = legend_corner(&series, (0.0, 1.0), (0.0, 1.0), (false, false), 0.3, 0.3);
    assert_eq!(c, SeriesLabelPosition::LowerLeft);
    // A diagonal from lower left to upper right leaves the other two.
    let series = [s(&[(0.0, 0.0), (1.0, 1.0)])];
    let c = legend_corner(&series, (0.0, 1.0), (0.0, 1.0), (false, false), 0.3, 0.3);
    assert!(
        matches!(c, SeriesLabelPosition::UpperLeft | SeriesLabelPosition::LowerRight),
        "{c:?}"
    );
    // On log axes too: points at the low end of a decade range.
    let series = [s(&[(1.0, 0.001), (2.0, 0.002)])];
    let c = legend_corner(&series, (1.0, 100.0), (0.001, 1.0), (true, true), 0.3, 0.3);
    assert_ne!(c, SeriesLabelPosition::LowerLeft);
}
