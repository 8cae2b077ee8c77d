//! Where a haptic tick's time goes: the tick split into its phases (the
//! rings drained, the model swap, the instruments, contact with its
//! residual-compliance solve, the reduced step, the cross-fade's old model,
//! the passivity filter, the gain and the pushes), each phase timed on the
//! loop thread into a fixed histogram ([`Histogram`]), plus the split of the
//! slowest tick and the mean split of the ticks over a threshold (the tail).
//!
//! Every phase is timed where it runs, with one clock read at each end, into
//! a [`TickSplit`] that lives for one tick; [`TickPhases::record`] adds the
//! split to the histograms at the end of the tick. Nothing here allocates
//! after [`TickPhases::new`], locks or does I/O.

use crate::rt::clock::{self, Nanos};
use crate::rt::stats::{Histogram, Percentiles};
use serde::Serialize;
use std::collections::BTreeMap;

/// A phase of the haptic tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Draining the pose ring and looking into the model ring.
    Drain,
    /// Swapping a refreshed model in: the state transfer, the contact
    /// match, the new model's contact and its static Newton step (only on
    /// ticks that swap).
    Swap,
    /// The instruments' contributions in the loop (each instrument's
    /// `LoopSide::contribute`: the probe's sphere, the guidewire's hub
    /// drive, wall loads and hand force; docs/INSTRUMENTS.md).
    Instruments,
    /// Contact of the tool spheres with the deformed surface: the triangle
    /// search or the kept triangles, the pressure quadrature and the
    /// residual-compliance series solve.
    Contact,
    /// The searches for the surface triangles near the tool spheres alone
    /// (part of [`Phase::Contact`], and of [`Phase::Fade`] for the old
    /// model's; only on ticks where a sphere left the slack of its kept
    /// triangles, or had none).
    Search,
    /// The residual-compliance series solve alone (part of [`Phase::Contact`];
    /// only on ticks with a patch and a compliance table).
    Series,
    /// The reduced implicit step with the contact stiffness.
    Step,
    /// During a cross-fade after a swap, the old model's contact and step
    /// (only on ticks that blend).
    Fade,
    /// The passivity filter: the shortcut, the QP or its fallback, and the
    /// energy observer's bookkeeping.
    Filter,
    /// The passivity filter on the ticks its QP solver ran (part of
    /// [`Phase::Filter`], which also holds the shortcut ticks).
    QpSolve,
    /// The watchdog gain, the force push and the pushes to the other
    /// threads (contact forces, retired models).
    Output,
    /// After the force push, taking a refreshed model from the ring and
    /// reading its memory, to swap it in on the next tick (only on ticks
    /// that take one).
    Warm,
}

/// The tick compute time above which a tick counts in the tail
/// ([`TickPhases::new`]; µs): the default run's p99.9 goal.
pub const TAIL_US: f64 = 100.0;

/// Number of phases.
pub const PHASES: usize = 12;

impl Phase {
    /// Every phase, in the order of the tick.
    pub const ALL: [Phase; PHASES] = [
        Phase::Drain,
        Phase::Swap,
        Phase::Instruments,
        Phase::Contact,
        Phase::Search,
        Phase::Series,
        Phase::Step,
        Phase::Fade,
        Phase::Filter,
        Phase::QpSolve,
        Phase::Output,
        Phase::Warm,
    ];

    /// The report key.
    pub fn key(self) -> &'static str {
        match self {
            Phase::Drain => "drain",
            Phase::Swap => "swap",
            Phase::Instruments => "instruments",
            Phase::Contact => "contact",
            Phase::Search => "search",
            Phase::Series => "series",
            Phase::Step => "step",
            Phase::Fade => "fade",
            Phase::Filter => "filter",
            Phase::QpSolve => "qp_solve",
            Phase::Output => "output",
            Phase::Warm => "warm",
        }
    }

    /// Whether the phase is part of another one (not counted twice in the
    /// tick's sum).
    pub fn nested(self) -> bool {
        matches!(self, Phase::Search | Phase::Series | Phase::QpSolve)
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// One tick's time per phase (ns; phases that did not run are absent).
/// Fixed size, copied freely.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TickSplit {
    ns: [Nanos; PHASES],
    ran: u16,
    mark: Nanos,
}

impl TickSplit {
    /// An empty split whose next [`TickSplit::lap`] counts from `t`.
    pub fn starting_at(t: Nanos) -> TickSplit {
        TickSplit {
            mark: t,
            ..TickSplit::default()
        }
    }

    /// Empties the split (keeps nothing of the last tick).
    pub fn clear(&mut self) {
        *self = TickSplit::default();
    }

    /// Adds `ns` to `phase`.
    pub fn add(&mut self, phase: Phase, ns: Nanos) {
        self.ns[phase.index()] += ns.max(0);
        self.ran |= 1 << phase.index();
    }

    /// Adds the time since `t0` to `phase`; returns now (the next phase's
    /// start).
    pub fn add_since(&mut self, phase: Phase, t0: Nanos) -> Nanos {
        let now = clock::now_ns();
        self.add(phase, now - t0);
        now
    }

    /// Adds the time since the last lap (or the start) to `phase`.
    pub fn lap(&mut self, phase: Phase) {
        self.mark = self.add_since(phase, self.mark);
    }

    /// Adds every phase of `inner` (timed elsewhere, e.g. inside the tick)
    /// and moves the lap mark to now: what ran between the last lap and now
    /// outside `inner`'s phases stays unattributed ([`TickPhases`] reports
    /// it as `other`).
    pub fn absorb(&mut self, inner: &TickSplit) {
        for p in Phase::ALL {
            if let Some(ns) = inner.get(p) {
                self.add(p, ns);
            }
        }
        self.mark = clock::now_ns();
    }

    /// The time of `phase` (ns), None if it did not run.
    pub fn get(&self, phase: Phase) -> Option<Nanos> {
        (self.ran & (1 << phase.index()) != 0).then_some(self.ns[phase.index()])
    }

    /// Sum of the phases that are not part of another (ns).
    pub fn total(&self) -> Nanos {
        Phase::ALL
            .iter()
            .filter(|p| !p.nested())
            .filter_map(|&p| self.get(p))
            .sum()
    }
}

/// The loop's phase histograms and its tail's split (fixed memory).
#[derive(Debug, Clone)]
pub struct TickPhases {
    hist: Vec<Histogram>,
    other: Histogram,
    ticks: u64,
    compute_sum_us: f64,
    tail_threshold_us: f64,
    tail_ticks: u64,
    tail_sum_us: [f64; PHASES + 2],
    slowest_us: [f64; PHASES + 2],
    slowest_ran: u16,
}

impl TickPhases {
    /// Empty histograms (allocated here, once); ticks whose compute time
    /// exceeds `tail_threshold_us` are the tail whose mean split is kept.
    pub fn new(tail_threshold_us: f64) -> TickPhases {
        TickPhases {
            hist: (0..PHASES).map(|_| Histogram::new()).collect(),
            other: Histogram::new(),
            ticks: 0,
            compute_sum_us: 0.0,
            tail_threshold_us,
            tail_ticks: 0,
            tail_sum_us: [0.0; PHASES + 2],
            slowest_us: [0.0; PHASES + 2],
            slowest_ran: 0,
        }
    }

    /// Records one tick's split and its whole compute time (ns). Allocates
    /// nothing.
    pub fn record(&mut self, split: &TickSplit, compute_ns: Nanos) {
        let us = |ns: Nanos| ns as f64 * 1e-3;
        let compute = us(compute_ns);
        let other = us((compute_ns - split.total()).max(0));
        self.ticks += 1;
        self.compute_sum_us += compute;
        for p in Phase::ALL {
            if let Some(ns) = split.get(p) {
                self.hist[p.index()].record(us(ns));
            }
        }
        self.other.record(other);
        let row = |i: usize| -> f64 {
            match i {
                i if i < PHASES => split.get(Phase::ALL[i]).map_or(0.0, us),
                i if i == PHASES => other,
                _ => compute,
            }
        };
        if compute > self.tail_threshold_us {
            self.tail_ticks += 1;
            for (i, s) in self.tail_sum_us.iter_mut().enumerate() {
                *s += row(i);
            }
        }
        if compute > self.slowest_us[PHASES + 1] {
            for (i, s) in self.slowest_us.iter_mut().enumerate() {
                *s = row(i);
            }
            self.slowest_ran = split.ran;
        }
    }

    /// The report's figures.
    pub fn report(&self) -> PhasesReport {
        let mut phases = BTreeMap::new();
        let share = |sum: f64| {
            if self.compute_sum_us > 0.0 {
                sum / self.compute_sum_us
            } else {
                0.0
            }
        };
        let stats = |h: &Histogram| {
            let sum = h.mean() * h.count() as f64;
            PhaseStats {
                ticks: h.count(),
                us: h.percentiles(),
                mean_us: h.mean(),
                per_tick_us: if self.ticks > 0 { sum / self.ticks as f64 } else { 0.0 },
                share: share(sum),
            }
        };
        for p in Phase::ALL {
            phases.insert(p.key(), stats(&self.hist[p.index()]));
        }
        phases.insert("other", stats(&self.other));
        let split_of = |v: &[f64; PHASES + 2], ran: Option<u16>, n: f64| {
            let mut m = BTreeMap::new();
            for p in Phase::ALL {
                if ran.is_none_or(|r| r & (1 << p.index()) != 0) {
                    m.insert(p.key(), v[p.index()] / n);
                }
            }
            m.insert("other", v[PHASES] / n);
            m.insert("compute", v[PHASES + 1] / n);
            m
        };
        PhasesReport {
            phases,
            slowest_tick_us: if self.ticks > 0 {
                split_of(&self.slowest_us, Some(self.slowest_ran), 1.0)
            } else {
                BTreeMap::new()
            },
            tail_threshold_us: self.tail_threshold_us,
            tail_ticks: self.tail_ticks,
            tail_mean_us: if self.tail_ticks > 0 {
                split_of(&self.tail_sum_us, None, self.tail_ticks as f64)
            } else {
                BTreeMap::new()
            },
        }
    }
}

/// One phase's figures over the run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct PhaseStats {
    /// Ticks the phase ran in.
    pub ticks: u64,
    /// Its time on those ticks (µs): p50, p99, p99.9, max.
    pub us: Percentiles,
    /// Its mean time on those ticks (µs).
    pub mean_us: f64,
    /// Its time summed over the run per tick run (µs): what it adds to the
    /// mean tick.
    pub per_tick_us: f64,
    /// Its share of the summed tick compute time (0..1).
    pub share: f64,
}

/// The `tick_phases` keys of the report.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct PhasesReport {
    /// Per phase ([`Phase::key`], and `other`: the tick's compute time not
    /// in any phase).
    pub phases: BTreeMap<&'static str, PhaseStats>,
    /// The slowest tick's split (µs; its phases, `other` and `compute`).
    pub slowest_tick_us: BTreeMap<&'static str, f64>,
    /// Ticks whose compute time exceeded this are the tail (µs).
    pub tail_threshold_us: f64,
    /// Ticks in the tail.
    pub tail_ticks: u64,
    /// The tail's mean split (µs per tail tick; every phase, `other` and
    /// `compute`).
    pub tail_mean_us: BTreeMap<&'static str, f64>,
}

impl PhasesReport {
    /// The report's text lines (one per phase that ran, then the tail).
    pub fn render(&self) -> String {
        let mut s = String::new();
        let keys = Phase::ALL.iter().map(|p| p.key()).chain(["other"]);
        s += "  tick phases (µs over the ticks each ran; per tick: its time summed over the run / ticks):\n";
        for k in keys.clone() {
            let Some(st) = self.phases.get(k).filter(|st| st.ticks > 0) else {
                continue;
            };
            let nested = Phase::ALL.iter().any(|p| p.key() == k && p.nested());
            s += &format!(
                "    {:<9} {:>7} ticks  p50 {:>6.1}  p99 {:>6.1}  p99.9 {:>6.1}  max {:>6.1}  per tick {:>5.1} ({:>4.1} %){}\n",
                k,
                st.ticks,
                st.us.p50,
                st.us.p99,
                st.us.p999,
                st.us.max,
                st.per_tick_us,
                st.share * 100.0,
                if nested { " (part of the one above)" } else { "" }
            );
        }
        let line = |m: &BTreeMap<&'static str, f64>| -> String {
            keys.clone()
                .filter_map(|k| m.get(k).filter(|v| **v > 0.0).map(|v| format!("{k} {v:.1}")))
                .collect::<Vec<_>>()
                .join(", ")
        };
        if let Some(c) = self.slowest_tick_us.get("compute") {
            s += &format!("    slowest tick {c:.1}: {}\n", line(&self.slowest_tick_us));
        }
        match self.tail_mean_us.get("compute") {
            Some(c) => {
                s += &format!(
                    "    {} ticks over {:.0} µs, mean {c:.1}: {}\n",
                    self.tail_ticks,
                    self.tail_threshold_us,
                    line(&self.tail_mean_us)
                )
            }
            None => s += &format!("    no tick over {:.0} µs\n", self.tail_threshold_us),
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_split_sums_its_outer_phases_and_the_rest_is_other() {
        let mut s = TickSplit::default();
        s.add(Phase::Contact, 30_000);
        s.add(Phase::Series, 10_000);
        s.add(Phase::Step, 15_000);
        s.add(Phase::Filter, 5_000);
        assert_eq!(s.total(), 50_000, "the series solve is inside contact");
        assert_eq!(s.get(Phase::Swap), None);
        let mut outer = TickSplit::default();
        outer.add(Phase::Drain, 1_000);
        outer.absorb(&s);
        assert_eq!(outer.total(), 51_000);
        assert_eq!(outer.get(Phase::Series), Some(10_000));

        let mut p = TickPhases::new(100.0);
        p.record(&outer, 60_000);
        let mut slow = TickSplit::default();
        slow.add(Phase::Swap, 150_000);
        slow.add(Phase::Contact, 20_000);
        p.record(&slow, 200_000);
        let r = p.report();
        assert_eq!(r.phases["contact"].ticks, 2);
        assert_eq!(r.phases["swap"].ticks, 1);
        assert_eq!(r.phases["swap"].us.max, 150.0);
        assert_eq!(r.phases["other"].us.max, 30.0);
        assert!((r.phases["contact"].per_tick_us - 25.0).abs() < 1e-9);
        assert!((r.phases["swap"].share - 150.0 / 260.0).abs() < 1e-9);
        assert_eq!(r.tail_ticks, 1);
        assert_eq!(r.tail_mean_us["swap"], 150.0);
        assert_eq!(r.tail_mean_us["compute"], 200.0);
        assert_eq!(r.slowest_tick_us["compute"], 200.0);
        assert!(!r.slowest_tick_us.contains_key("step"), "only the phases that ran");
        let text = r.render();
        assert!(text.contains("1 ticks over 100 µs"), "{text}");
        assert!(
            text.contains("slowest tick 200.0: swap 150.0, contact 20.0, other 30.0"),
            "{text}"
        );
    }
}
