//! The task metrics on the stream publisher's side (never in the haptic
//! loop): one sample per state frame into [`crate::task::Metrics`], the
//! summary to `[task] hud_target` five times a second, the session file at
//! the end.

use super::config::ServiceConfig;
use super::ServiceError;
use crate::mesh::TetMesh;
use crate::task::{Metrics, MetricsSample, SegmentMap, TaskConfig, TaskSummary};
use std::net::{SocketAddr, UdpSocket};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;

/// How often the summary goes to the HUD (s of simulation time).
const HUD_PERIOD_S: f64 = 0.2;

/// The publisher's task part.
pub(crate) struct TaskFeed {
    metrics: Metrics,
    buttons: Arc<AtomicU32>,
    hud: Option<(UdpSocket, SocketAddr)>,
    last_hud_s: f64,
    session: Option<PathBuf>,
}

impl TaskFeed {
    /// The task of `cfg` on `mesh`'s labelled inner wall; `buttons` holds
    /// the device's newest buttons.
    pub(crate) fn new(
        cfg: &ServiceConfig,
        task: &TaskConfig,
        mesh: &TetMesh,
        buttons: Arc<AtomicU32>,
    ) -> Result<TaskFeed, ServiceError> {
        let c = crate::config::Checker::new(&cfg.path);
        let set = cfg
            .guidewire
            .as_ref()
            .map_or("inner_wall".to_string(), |g| g.wall_set.clone());
        let map = SegmentMap::from_mesh(mesh, &set).map_err(|e| c.err("task.target_segment", e))?;
        let metrics = Metrics::new(task, map).map_err(|e| c.err("task.target_segment", e))?;
        let hud = match task.hud_target.parse::<SocketAddr>() {
            Ok(to) => {
                let local = if to.is_ipv4() { "0.0.0.0:0" } else { "[::]:0" };
                let sock = UdpSocket::bind(local).map_err(|e| c.err("task.hud_target", e.to_string()))?;
                let _ = sock.set_nonblocking(true);
                Some((sock, to))
            }
            Err(_) => None,
        };
        let session = (!task.session_dir.is_empty()).then(|| {
            let secs = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs());
            cfg.resolve(std::path::Path::new(&task.session_dir))
                .join(format!("session-{secs}.json"))
        });
        Ok(TaskFeed {
            metrics,
            buttons,
            hud,
            last_hud_s: f64::NEG_INFINITY,
            session,
        })
    }

    /// One state frame: time (s), the wire's polyline, the hand force's
    /// magnitude (N), the largest wall contact force since the last frame (N).
    pub(crate) fn push(&mut self, time_s: f64, polyline: &[[f32; 3]], hub_force_n: f64, wall_force_n: f64) {
        self.metrics.push(&MetricsSample {
            time_s,
            polyline,
            hub_force_n,
            wall_force_n,
            buttons: self.buttons.load(Ordering::Relaxed),
        });
        if let Some((sock, to)) = &self.hud {
            if time_s - self.last_hud_s >= HUD_PERIOD_S || self.last_hud_s.is_infinite() {
                self.last_hud_s = time_s;
                if let Ok(text) = serde_json::to_string(self.metrics.summary()) {
                    // A HUD that is not listening loses nothing that matters.
                    let _ = sock.send_to(text.as_bytes(), to);
                }
            }
        }
    }

    /// The figures at the end, and an error if the session file could not
    /// be written.
    pub(crate) fn finish(self) -> (TaskSummary, Option<String>) {
        if let Some((sock, to)) = &self.hud {
            if let Ok(text) = serde_json::to_string(self.metrics.summary()) {
                let _ = sock.send_to(text.as_bytes(), to);
            }
        }
        let error = self
            .session
            .as_ref()
            .and_then(|p| self.metrics.session().save(p).err())
            .map(|e| format!("task session file: {e}"));
        (self.metrics.summary().clone(), error)
    }
}
