//! Real-time plumbing: the monotonic clock and absolute-deadline sleep, the
//! scheduling set-up of the haptic thread (SCHED_FIFO, CPU pinning, locked
//! memory, prefaulted stack), fixed histograms for timing statistics, the
//! RT-safe allocator, and the audit of the box (`nvtmm check-rt`).
//!
//! Not here: what the loop computes ([`crate::haptics`]) or which threads the
//! service starts (`service`).

pub mod alloc;
pub mod check;
pub mod clock;
pub mod reserved;
pub mod stats;
pub mod thread;
