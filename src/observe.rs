//! How the library tells its caller what it is doing: progress and
//! messages go to an [`Observer`] the caller passes, never to the terminal.
//! The default ([`Observe::none`]) drops them; the `nvtmm` command line
//! renders them as progress bars and lines on stderr; an application
//! embedding the service can log them, show them in its own UI, or ignore
//! them.
//!
//! Only preparation and batch work report here (meshing, the basis, a
//! scene's steps, a service run's elapsed time); nothing on the haptic loop
//! or the wire thread calls an observer.

use std::sync::Arc;

/// One thing worth telling the caller.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event<'a> {
    /// A line of text (e.g. "8 nodes, 12 tets; basis r = 32…").
    Message(&'a str),
    /// Progress of a long task: `done` of `total` (in the task's unit:
    /// steps for `"simulate"`, seconds for `"run"`), with a short detail
    /// (the simulated time, the tick count).
    Progress {
        /// Which task (`"simulate"`, `"run"`).
        task: &'a str,
        /// How far it is.
        done: f64,
        /// How far it goes.
        total: f64,
        /// A short status to show next to it.
        detail: &'a str,
    },
    /// The task has ended (its progress display can go).
    Finished {
        /// Which task.
        task: &'a str,
        /// Whether it succeeded.
        ok: bool,
    },
}

/// Receives [`Event`]s. Called from the thread doing the work (not an RT
/// thread); keep it quick.
pub trait Observer: Send + Sync {
    /// One event.
    fn event(&self, event: Event<'_>);
}

/// An observer handle to pass around: cheap to clone, silent by default,
/// compared by identity.
#[derive(Clone, Default)]
pub struct Observe(Option<Arc<dyn Observer>>);

impl Observe {
    /// The silent observer: every event is dropped.
    pub fn none() -> Observe {
        Observe(None)
    }

    /// Events go to `observer`.
    pub fn new(observer: Arc<dyn Observer>) -> Observe {
        Observe(Some(observer))
    }

    /// Whether anyone listens (to skip building a message nobody reads).
    pub fn is_active(&self) -> bool {
        self.0.is_some()
    }

    /// Reports `event`.
    pub fn event(&self, event: Event<'_>) {
        if let Some(o) = &self.0 {
            o.event(event);
        }
    }

    /// Reports a line of text.
    pub fn message(&self, text: &str) {
        self.event(Event::Message(text));
    }

    /// Reports progress of `task`.
    pub fn progress(&self, task: &str, done: f64, total: f64, detail: &str) {
        self.event(Event::Progress {
            task,
            done,
            total,
            detail,
        });
    }

    /// Reports that `task` has ended.
    pub fn finished(&self, task: &str, ok: bool) {
        self.event(Event::Finished { task, ok });
    }
}

impl std::fmt::Debug for Observe {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() {
            "Observe(active)"
        } else {
            "Observe(none)"
        })
    }
}

impl PartialEq for Observe {
    fn eq(&self, other: &Self) -> bool {
        match (&self.0, &other.0) {
            (Some(a), Some(b)) => Arc::ptr_eq(a, b),
            (None, None) => true,
            _ => false,
        }
    }
}
