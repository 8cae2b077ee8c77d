//! Fault injection into a running service, for the soak (`nvtmm soak`) and
//! the recovery tests: switches the threads read with one relaxed atomic
//! load where the fault would happen, and counters of the faults each thread
//! actually met. [`crate::service::Handle::faults`] gives the switches of a
//! running service. Device faults (silence, bad samples, garbage datagrams)
//! are injected by the device itself (`crate::haptics::touchx::TouchXSim`
//! and the soak's device), and a clock leap by
//! [`crate::rt::clock::inject_jump`].
//!
//! Every switch is off unless set; a service nobody injects into pays one
//! atomic load per tick (the model hold) and per background step.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// The switches and what became of them. All fields are atomics; share it
/// with `Arc`.
#[derive(Debug, Default)]
pub struct FaultSwitches {
    /// The background thread sleeps this long (ms) before its next step, once.
    pub stall_background_ms: AtomicU64,
    /// The background thread's next full step fails (one of its loads is
    /// non-finite, so the solver rejects the step and the state stays as it
    /// was).
    pub fail_next_step: AtomicBool,
    /// The basis thread's next recomputation fails (it is allowed no
    /// subspace iteration, so it does not converge).
    pub fail_next_basis: AtomicBool,
    /// While set, the haptic loop takes no new model from the model ring
    /// (so the ring fills and the background keeps only the latest).
    pub hold_models: AtomicBool,
    /// The background thread panics at its next step.
    pub panic_background: AtomicBool,
    /// The basis thread panics at its next job.
    pub panic_basis: AtomicBool,
    /// The stream publisher panics at its next frame.
    pub panic_publisher: AtomicBool,
    /// The guidewire's next step goes non-finite (its tip made NaN).
    pub poison_wire: AtomicBool,
    /// The wire thread sleeps this long (ms) before its next step, once.
    pub stall_wire_ms: AtomicU64,
    /// Stalls the background thread served.
    pub stalls_served: AtomicU64,
    /// Injected full-step failures the solver reported as failed.
    pub step_failures_served: AtomicU64,
    /// Injected basis failures the basis thread met.
    pub basis_failures_served: AtomicU64,
}

impl FaultSwitches {
    /// Takes a pending stall (ms), 0 if none.
    pub fn take_stall_ms(&self) -> u64 {
        self.stall_background_ms.swap(0, Ordering::Relaxed)
    }

    /// Takes a one-shot switch: whether it was set (and clears it).
    pub fn take(flag: &AtomicBool) -> bool {
        flag.swap(false, Ordering::Relaxed)
    }

    /// Whether the loop should hold the models back now.
    pub fn holding_models(&self) -> bool {
        self.hold_models.load(Ordering::Relaxed)
    }

    /// Adds one to a served counter.
    pub fn served(counter: &AtomicU64) {
        counter.fetch_add(1, Ordering::Relaxed);
    }
}
