//! Training tasks and procedure metrics (`[task]` in the service
//! configuration, docs/DRIVING.md "Metrics").
//!
//! A task names a target vessel segment (any segment label of the mesh, so
//! a patient mesh's labels work as well as the built-in arch's); it is done
//! when the wire's last `inside_m` (20 mm by default), measured back from
//! the tip along the wire, all lie in that segment. [`Metrics`] is fed one
//! [`MetricsSample`] per state frame, outside the haptic loop (the stream
//! publisher does it), and keeps what a cath-lab trainer scores: time to
//! target, the tip's path length, pull-backs, the hub force's peak, the
//! wire's wall contact force (peak, time above 0.5 N and above 1.5 N),
//! fluoroscopy-on time and contrast injections (from the device buttons).
//! Every figure is a plain function of the samples, so a script can
//! recompute them from a recording (`tests/task_metrics_match_the_recording.rs`).

use crate::config::{Checker, ConfigError};
use crate::math::Vec3;
use crate::mesh::TetMesh;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Device button bit: switch the active instrument (momentary).
pub const BUTTON_SWITCH: u32 = 1 << 0;
/// Device button bit: inject contrast (a press, 0 → 1, is one injection).
pub const BUTTON_CONTRAST: u32 = 1 << 1;
/// Device button bit: fluoroscopy on (held while the pedal is down).
pub const BUTTON_FLUORO: u32 = 1 << 2;

/// A pull-back: the inserted length fell this far (m) below its largest
/// value since the wire last advanced; it ends when the wire advances this
/// far above its smallest value since (a hysteresis: one retraction, however
/// long, is one pull-back).
pub const PULLBACK_M: f64 = 5e-3;
/// Wall contact force thresholds (N) whose time above is counted: 0.5 N
/// (light contact) and 1.5 N (proposed as a perforation risk).
pub const WALL_THRESHOLDS_N: [f64; 2] = [0.5, 1.5];
/// An interval between samples longer than this (s) is not counted in the
/// time-above and fluoroscopy figures (a stalled publisher, a paused run).
pub const MAX_GAP_S: f64 = 0.5;

/// `[task]`: the target and where the summary goes.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct TaskConfig {
    /// The target segment's label (e.g. `left_subclavian`); a mesh's labels
    /// are its `segment_*` node sets without the prefix.
    pub target_segment: String,
    /// How far (m) the wire must be inside the target, from the tip back.
    pub inside_m: f64,
    /// UDP `IP:PORT` the summary goes to as JSON a few times a second (for
    /// `nvtmm view`'s HUD); "" sends nothing.
    pub hud_target: String,
    /// Directory (relative to the configuration) where each run writes its
    /// session file `session-<unix seconds>.json`; "" writes none.
    pub session_dir: String,
}

impl Default for TaskConfig {
    fn default() -> Self {
        TaskConfig {
            target_segment: String::new(),
            inside_m: 0.02,
            hud_target: String::new(),
            session_dir: String::new(),
        }
    }
}

impl TaskConfig {
    /// Range checks; keys are named `task.…`.
    pub fn validate(&self, c: &Checker) -> Result<(), ConfigError> {
        if self.target_segment.trim().is_empty() {
            return Err(c.err(
                "task.target_segment",
                "must name a segment label of the mesh (e.g. \"left_subclavian\")",
            ));
        }
        c.f64_in("task.inside_m", self.inside_m, 0.0, 0.5, "m")?;
        if !self.hud_target.is_empty() && self.hud_target.parse::<std::net::SocketAddr>().is_err() {
            return Err(c.err(
                "task.hud_target",
                format!("{:?}: expected IP:PORT or \"\"", self.hud_target),
            ));
        }
        Ok(())
    }
}

/// Which segment a point is in: the label of the nearest labelled wall
/// vertex (rest positions).
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentMap {
    points: Vec<Vec3>,
    labels: Vec<u8>,
    names: Vec<String>,
}

impl SegmentMap {
    /// The vertices of node set `set` of `mesh` with their segment labels;
    /// an error names the set or says the mesh has no labels.
    pub fn from_mesh(mesh: &TetMesh, set: &str) -> Result<SegmentMap, String> {
        let (names, label) = mesh
            .segment_labels()
            .ok_or("the mesh has no segment labels (segment_* node sets)")?;
        let nodes = mesh
            .node_set(set)
            .ok_or_else(|| format!("the mesh has no node set {set:?}"))?;
        let mut points = Vec::new();
        let mut labels = Vec::new();
        for &i in nodes {
            let l = label[i as usize];
            if (l as usize) < names.len() {
                points.push(mesh.rest()[i as usize]);
                labels.push(l);
            }
        }
        if points.is_empty() {
            return Err(format!("no vertex of node set {set:?} carries a segment label"));
        }
        Ok(SegmentMap { points, labels, names })
    }

    /// A map from explicit points, labels (indices into `names`) and names.
    pub fn new(points: Vec<Vec3>, labels: Vec<u8>, names: Vec<String>) -> SegmentMap {
        SegmentMap { points, labels, names }
    }

    /// The segment names, in label order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// The labelled wall vertices (m, at rest).
    pub fn points(&self) -> &[Vec3] {
        &self.points
    }

    /// Each vertex's label (an index into [`SegmentMap::names`]).
    pub fn labels(&self) -> &[u8] {
        &self.labels
    }

    /// The label index of `name`.
    pub fn label_of(&self, name: &str) -> Option<u8> {
        self.names.iter().position(|n| n == name).map(|i| i as u8)
    }

    /// The label of the vertex nearest `p` (brute force: a few thousand
    /// vertices, a few points a frame).
    pub fn label_at(&self, p: Vec3) -> Option<u8> {
        let (k, _) = self
            .points
            .iter()
            .enumerate()
            .map(|(k, x)| (k, (x - p).norm_squared()))
            .min_by(|a, b| a.1.total_cmp(&b.1))?;
        self.labels.get(k).copied()
    }

    /// The name of the segment nearest `p`.
    pub fn segment_at(&self, p: Vec3) -> Option<&str> {
        self.label_at(p)
            .and_then(|l| self.names.get(l as usize))
            .map(String::as_str)
    }

    /// How far (m) the wire `polyline` (hub to tip) lies in segment
    /// `label`, measured back from the tip: the arc length from the tip to
    /// the farthest point before it such that every point in between is in
    /// the segment. 0 when the tip is not in it.
    pub fn depth_in(&self, polyline: &[[f32; 3]], label: u8, enough_m: f64) -> f64 {
        let mut depth = 0.0;
        let mut prev: Option<Vec3> = None;
        for p in polyline.iter().rev() {
            let x = Vec3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            if self.label_at(x) != Some(label) {
                break;
            }
            if let Some(q) = prev {
                depth += (x - q).norm();
            }
            prev = Some(x);
            if depth >= enough_m {
                break;
            }
        }
        depth
    }
}

/// One state frame's worth of what the metrics need.
#[derive(Debug, Clone, Copy)]
pub struct MetricsSample<'a> {
    /// Simulation time (s).
    pub time_s: f64,
    /// The wire, hub to tip (m, scene frame); empty without a wire.
    pub polyline: &'a [[f32; 3]],
    /// Magnitude of the force rendered to the hand (N): with the wire, its
    /// hub force through the drive.
    pub hub_force_n: f64,
    /// Largest force (N) of one wire–wall contact since the previous sample.
    pub wall_force_n: f64,
    /// Device buttons ([`BUTTON_SWITCH`], [`BUTTON_CONTRAST`], [`BUTTON_FLUORO`]).
    pub buttons: u32,
}

/// The procedure's figures so far (also the session file's `summary`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TaskSummary {
    /// The target segment.
    pub target_segment: String,
    /// Required depth in the target (m).
    pub inside_m: f64,
    /// Whether the wire has reached the target (stays true once reached).
    pub success: bool,
    /// Time (s) from the first sample to the first sample at the target.
    pub time_to_target_s: Option<f64>,
    /// Time (s) from the first sample to the latest.
    pub elapsed_s: f64,
    /// The tip's path length (m): the sum of its moves between samples.
    pub tip_path_m: f64,
    /// The segment of the tip now ("" without a wire).
    pub tip_segment: String,
    /// How far (m) the wire is inside the target now (capped at `inside_m`).
    pub depth_m: f64,
    /// Pull-backs: the inserted length fell 5 mm below its largest value
    /// since the wire last advanced (by 5 mm: one retraction is one).
    pub pullbacks: u64,
    /// Inserted length now (m): the polyline's arc length.
    pub inserted_m: f64,
    /// Largest hub force (N).
    pub hub_force_peak_n: f64,
    /// Largest wall contact force (N).
    pub wall_force_peak_n: f64,
    /// Time (s) with the wall contact force above 0.5 N.
    pub wall_above_0_5_n_s: f64,
    /// Time (s) with the wall contact force above 1.5 N.
    pub wall_above_1_5_n_s: f64,
    /// Time (s) with fluoroscopy on.
    pub fluoroscopy_s: f64,
    /// Contrast injections (presses of the contrast button).
    pub contrast_injections: u64,
    /// Presses of the instrument switch.
    pub instrument_switches: u64,
    /// Samples taken.
    pub samples: u64,
}

/// One row of the session's time series.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct SeriesRow {
    /// Simulation time (s).
    pub t: f64,
    /// Hub force (N).
    pub hub_n: f64,
    /// Wall contact force (N).
    pub wall_n: f64,
    /// Inserted length (m).
    pub inserted_m: f64,
    /// Buttons.
    pub buttons: u32,
}

/// A session file: the summary and the time series.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Session {
    /// The figures at the end.
    pub summary: TaskSummary,
    /// One row per sample.
    pub series: Vec<SeriesRow>,
}

/// The metrics accumulator (see the module documentation).
#[derive(Debug, Clone)]
pub struct Metrics {
    map: SegmentMap,
    target: Option<u8>,
    s: TaskSummary,
    t0: Option<f64>,
    last_t: f64,
    last_tip: Option<Vec3>,
    peak_inserted: f64,
    /// While retracting: the smallest inserted length since it began.
    trough_inserted: Option<f64>,
    last_buttons: u32,
    series: Vec<SeriesRow>,
}

fn arc_length(polyline: &[[f32; 3]]) -> f64 {
    polyline
        .windows(2)
        .map(|w| {
            let d = [0, 1, 2].map(|k| (w[1][k] - w[0][k]) as f64);
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
        })
        .sum()
}

impl Metrics {
    /// A task on `map`; an error when the map has no segment of the target's name.
    pub fn new(cfg: &TaskConfig, map: SegmentMap) -> Result<Metrics, String> {
        let target = map.label_of(&cfg.target_segment).ok_or_else(|| {
            format!(
                "task.target_segment = {:?} is not a segment of the mesh (it has: {})",
                cfg.target_segment,
                map.names().join(", ")
            )
        })?;
        Ok(Metrics {
            map,
            target: Some(target),
            s: TaskSummary {
                target_segment: cfg.target_segment.clone(),
                inside_m: cfg.inside_m,
                ..TaskSummary::default()
            },
            t0: None,
            last_t: 0.0,
            last_tip: None,
            peak_inserted: 0.0,
            trough_inserted: None,
            last_buttons: 0,
            series: Vec::new(),
        })
    }

    /// Takes one sample (non-finite numbers are skipped field by field).
    pub fn push(&mut self, x: &MetricsSample<'_>) {
        if !x.time_s.is_finite() {
            return;
        }
        let t0 = *self.t0.get_or_insert(x.time_s);
        let dt = match self.s.samples {
            0 => 0.0,
            _ => x.time_s - self.last_t,
        };
        let dt = if (0.0..=MAX_GAP_S).contains(&dt) { dt } else { 0.0 };
        self.last_t = x.time_s;
        self.s.samples += 1;
        self.s.elapsed_s = x.time_s - t0;
        let hub = if x.hub_force_n.is_finite() { x.hub_force_n } else { 0.0 };
        let wall = if x.wall_force_n.is_finite() {
            x.wall_force_n
        } else {
            0.0
        };
        self.s.hub_force_peak_n = self.s.hub_force_peak_n.max(hub);
        self.s.wall_force_peak_n = self.s.wall_force_peak_n.max(wall);
        if wall > WALL_THRESHOLDS_N[0] {
            self.s.wall_above_0_5_n_s += dt;
        }
        if wall > WALL_THRESHOLDS_N[1] {
            self.s.wall_above_1_5_n_s += dt;
        }
        if x.buttons & BUTTON_FLUORO != 0 {
            self.s.fluoroscopy_s += dt;
        }
        let pressed = x.buttons & !self.last_buttons;
        if pressed & BUTTON_CONTRAST != 0 {
            self.s.contrast_injections += 1;
        }
        if pressed & BUTTON_SWITCH != 0 {
            self.s.instrument_switches += 1;
        }
        self.last_buttons = x.buttons;
        if let Some(tip) = x.polyline.last() {
            let tip = Vec3::new(tip[0] as f64, tip[1] as f64, tip[2] as f64);
            if let Some(p) = self.last_tip {
                self.s.tip_path_m += (tip - p).norm();
            }
            self.last_tip = Some(tip);
            let inserted = arc_length(x.polyline);
            self.s.inserted_m = inserted;
            match self.trough_inserted {
                None => {
                    self.peak_inserted = self.peak_inserted.max(inserted);
                    if inserted <= self.peak_inserted - PULLBACK_M {
                        self.s.pullbacks += 1;
                        self.trough_inserted = Some(inserted);
                    }
                }
                Some(trough) => {
                    let trough = trough.min(inserted);
                    self.trough_inserted = Some(trough);
                    if inserted >= trough + PULLBACK_M {
                        self.trough_inserted = None;
                        self.peak_inserted = inserted;
                    }
                }
            }
            self.s.tip_segment = self.map.segment_at(tip).unwrap_or("").to_string();
            if let Some(target) = self.target {
                self.s.depth_m = self.map.depth_in(x.polyline, target, self.s.inside_m);
                if self.s.depth_m >= self.s.inside_m && !self.s.success {
                    self.s.success = true;
                    self.s.time_to_target_s = Some(x.time_s - t0);
                }
            }
        }
        self.series.push(SeriesRow {
            t: x.time_s,
            hub_n: hub,
            wall_n: wall,
            inserted_m: self.s.inserted_m,
            buttons: x.buttons,
        });
    }

    /// The figures so far.
    pub fn summary(&self) -> &TaskSummary {
        &self.s
    }

    /// The session so far (summary and time series).
    pub fn session(&self) -> Session {
        Session {
            summary: self.s.clone(),
            series: self.series.clone(),
        }
    }
}

impl Session {
    /// Reads a session file; errors name the file.
    pub fn load(path: &Path) -> Result<Session, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        serde_json::from_str(&text).map_err(|e| format!("{}: not a session file: {e}", path.display()))
    }

    /// Writes the session as JSON.
    pub fn save(&self, path: &Path) -> Result<(), String> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        }
        let text = serde_json::to_string(self).map_err(|e| e.to_string())?;
        std::fs::write(path, text).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// A human-readable summary.
    pub fn render(&self) -> String {
        let s = &self.summary;
        let ttt = s
            .time_to_target_s
            .map_or("not reached".to_string(), |t| format!("{t:.2} s"));
        format!(
            "task: wire {} mm into {}\n\
             result           {}\n\
             time to target   {ttt}\n\
             elapsed          {:.2} s\n\
             tip path         {:.1} mm   (tip now in {}, {:.1} mm deep)\n\
             pull-backs       {}\n\
             hub force peak   {:.3} N\n\
             wall force peak  {:.3} N   above 0.5 N {:.2} s, above 1.5 N {:.2} s\n\
             fluoroscopy      {:.1} s   contrast injections {}\n\
             samples          {}\n",
            s.inside_m * 1e3,
            s.target_segment,
            if s.success { "success" } else { "not reached" },
            s.elapsed_s,
            s.tip_path_m * 1e3,
            if s.tip_segment.is_empty() { "-" } else { &s.tip_segment },
            s.depth_m * 1e3,
            s.pullbacks,
            s.hub_force_peak_n,
            s.wall_force_peak_n,
            s.wall_above_0_5_n_s,
            s.wall_above_1_5_n_s,
            s.fluoroscopy_s,
            s.contrast_injections,
            s.samples,
        )
    }

    /// A PNG of the hub and wall forces over time, with the 0.5 N and 1.5 N
    /// lines (with the default feature `tools`, which brings the plotting).
    #[cfg(feature = "tools")]
    pub fn plot(&self, path: &Path) -> Result<(), String> {
        use crate::experiment::plot::{line_plot, Series};
        use plotters::style::RGBColor;
        let t0 = self.series.first().map_or(0.0, |r| r.t);
        let pts = |f: fn(&SeriesRow) -> f64| self.series.iter().map(|r| (r.t - t0, f(r))).collect::<Vec<_>>();
        let t1 = self.series.last().map_or(1.0, |r| r.t - t0).max(1e-3);
        let line = |v: f64| vec![(0.0, v), (t1, v)];
        let series = [
            Series {
                name: "hub force (N)".into(),
                color: RGBColor(30, 90, 200),
                points: pts(|r| r.hub_n),
                markers: false,
            },
            Series {
                name: "wall contact force (N)".into(),
                color: RGBColor(200, 40, 40),
                points: pts(|r| r.wall_n),
                markers: false,
            },
            Series {
                name: "0.5 N".into(),
                color: RGBColor(230, 160, 30),
                points: line(0.5),
                markers: false,
            },
            Series {
                name: "1.5 N (perforation risk)".into(),
                color: RGBColor(120, 0, 0),
                points: line(1.5),
                markers: false,
            },
        ];
        let title = format!(
            "{} to {}: {}",
            "session",
            self.summary.target_segment,
            if self.summary.success { "success" } else { "not reached" }
        );
        line_plot(path, &title, "time (s)", "force (N)", &series, false, false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map() -> SegmentMap {
        // Segment 0 along x < 0, segment 1 along x ≥ 0 (points every 1 mm).
        let mut pts = Vec::new();
        let mut labels = Vec::new();
        for i in -100..=100 {
            pts.push(Vec3::new(i as f64 * 1e-3, 0.01, 0.0));
            labels.push(u8::from(i >= 0));
        }
        SegmentMap::new(pts, labels, vec!["aorta".into(), "branch".into()])
    }

    fn cfg() -> TaskConfig {
        TaskConfig {
            target_segment: "branch".into(),
            ..TaskConfig::default()
        }
    }

    fn wire(tip_x: f64) -> Vec<[f32; 3]> {
        (0..=40)
            .map(|k| [(tip_x - 0.04 + k as f64 * 1e-3) as f32, 0.0, 0.0])
            .collect()
    }

    #[test]
    fn success_needs_the_depth_and_the_figures_add_up() {
        let mut m = Metrics::new(&cfg(), map()).unwrap();
        let mut t = 0.0;
        for (tip, hub, wall, buttons) in [
            (-0.010, 0.1, 0.0, 0),
            (0.010, 0.2, 0.6, BUTTON_FLUORO),
            (0.019, 0.3, 1.6, BUTTON_FLUORO | BUTTON_CONTRAST),
            (0.012, 0.1, 0.2, BUTTON_FLUORO),
            (0.025, 0.4, 0.0, BUTTON_CONTRAST),
        ] {
            let line = wire(tip);
            m.push(&MetricsSample {
                time_s: t,
                polyline: &line,
                hub_force_n: hub,
                wall_force_n: wall,
                buttons,
            });
            t += 0.1;
        }
        let s = m.summary();
        assert!(s.success);
        assert!((s.time_to_target_s.unwrap() - 0.4).abs() < 1e-9);
        assert!(
            (s.tip_path_m - (0.020 + 0.009 + 0.007 + 0.013)).abs() < 1e-6,
            "{}",
            s.tip_path_m
        );
        assert_eq!(s.contrast_injections, 2);
        assert!((s.fluoroscopy_s - 0.3).abs() < 1e-9);
        assert!((s.wall_above_0_5_n_s - 0.2).abs() < 1e-9);
        assert!((s.wall_above_1_5_n_s - 0.1).abs() < 1e-9);
        assert_eq!(s.hub_force_peak_n, 0.4);
        assert_eq!(s.wall_force_peak_n, 1.6);
        assert_eq!(s.tip_segment, "branch");
        // The wire keeps its length (40 mm): no pull-back.
        assert_eq!(s.pullbacks, 0);
    }

    #[test]
    fn a_pull_back_is_counted_once_per_retraction() {
        let mut m = Metrics::new(&cfg(), map()).unwrap();
        // 40 → 33: one; back up to 40, down to 34: two; a long retraction
        // 34 → 10 in steps: still two... then up to 20 and down to 10: three.
        for (k, len) in [30, 40, 37, 34, 33, 40, 34, 28, 22, 16, 10, 20, 10].iter().enumerate() {
            let line: Vec<[f32; 3]> = (0..=*len)
                .map(|i| [(-0.05 + i as f64 * 1e-3) as f32, 0.0, 0.0])
                .collect();
            m.push(&MetricsSample {
                time_s: k as f64,
                polyline: &line,
                hub_force_n: 0.0,
                wall_force_n: 0.0,
                buttons: 0,
            });
        }
        assert_eq!(m.summary().pullbacks, 3);
    }

    #[test]
    fn an_unknown_target_and_bad_keys_are_refused() {
        let e = Metrics::new(
            &TaskConfig {
                target_segment: "renal".into(),
                ..TaskConfig::default()
            },
            map(),
        )
        .unwrap_err();
        assert!(e.contains("renal") && e.contains("branch"), "{e}");
        let c = Checker::new(Path::new("x.toml"));
        assert_eq!(
            TaskConfig::default().validate(&c).unwrap_err().key,
            "task.target_segment"
        );
        let bad = TaskConfig {
            inside_m: -1.0,
            ..cfg()
        };
        assert_eq!(bad.validate(&c).unwrap_err().key, "task.inside_m");
        let bad = TaskConfig {
            hud_target: "nowhere".into(),
            ..cfg()
        };
        assert_eq!(bad.validate(&c).unwrap_err().key, "task.hud_target");
    }
}
