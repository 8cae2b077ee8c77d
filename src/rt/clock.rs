//! One monotonic clock for the whole service: `CLOCK_MONOTONIC`, read as
//! seconds since a process-wide epoch, and an absolute-deadline sleep on the
//! same clock (`clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)`). Mixing
//! clocks produces bogus overruns; every thread and every sample timestamp
//! uses this one.

use std::sync::atomic::{AtomicI64, AtomicU64, Ordering};
use std::sync::OnceLock;

/// A point on `CLOCK_MONOTONIC` in nanoseconds.
pub type Nanos = i64;

fn kernel_now() -> Nanos {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec * 1_000_000_000 + ts.tv_nsec
}

/// Injected forward jumps so far (ns), added to every reading.
static JUMP_NS: AtomicI64 = AtomicI64::new(0);
/// Number of injected jumps.
static JUMPS: AtomicU64 = AtomicU64::new(0);

fn raw_now() -> Nanos {
    kernel_now() + JUMP_NS.load(Ordering::Relaxed)
}

/// Fault injection: the service clock leaps forward by `by_ns` (> 0) for
/// every thread at once, as after a suspended process or a virtual machine
/// paused by its host. `CLOCK_MONOTONIC` itself never jumps (wall-clock
/// changes such as NTP steps do not reach it, and it never goes back), so
/// a forward leap is the one clock fault the service can meet; the soak
/// (`nvtmm soak`) injects it to test that every thread re-phases instead
/// of bursting. Process-wide: do not use in tests that share a process
/// with timing-sensitive ones. Non-positive values are ignored.
pub fn inject_jump(by_ns: Nanos) {
    if by_ns > 0 {
        JUMP_NS.fetch_add(by_ns, Ordering::Relaxed);
        JUMPS.fetch_add(1, Ordering::Relaxed);
    }
}

/// Injected clock jumps so far ([`inject_jump`]).
pub fn injected_jumps() -> u64 {
    JUMPS.load(Ordering::Relaxed)
}

static EPOCH: OnceLock<Nanos> = OnceLock::new();

/// The process epoch (first call wins); call once at start so that the RT
/// path never initializes it.
pub fn epoch() -> Nanos {
    *EPOCH.get_or_init(raw_now)
}

/// Now on `CLOCK_MONOTONIC` (ns, absolute).
pub fn now_ns() -> Nanos {
    raw_now()
}

/// Seconds since [`epoch`].
pub fn now_s() -> f64 {
    (raw_now() - epoch()) as f64 * 1e-9
}

/// Converts an absolute time (ns) to seconds since [`epoch`].
pub fn to_s(t: Nanos) -> f64 {
    (t - epoch()) as f64 * 1e-9
}

/// Sleeps until the absolute time `deadline` (ns on `CLOCK_MONOTONIC`),
/// resuming after signal interruptions. Returns at once if it has passed.
pub fn sleep_until(deadline: Nanos) {
    // Deadlines are on the service clock; the kernel sleeps on its own.
    let deadline = deadline - JUMP_NS.load(Ordering::Relaxed);
    let ts = libc::timespec {
        tv_sec: deadline.div_euclid(1_000_000_000),
        tv_nsec: deadline.rem_euclid(1_000_000_000),
    };
    loop {
        // SAFETY: `ts` is a valid timespec; the remaining-time pointer may be null with TIMER_ABSTIME.
        let rc =
            unsafe { libc::clock_nanosleep(libc::CLOCK_MONOTONIC, libc::TIMER_ABSTIME, &ts, std::ptr::null_mut()) };
        if rc != libc::EINTR {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sleep_until_does_not_return_early_and_the_clock_is_monotonic() {
        let t0 = now_ns();
        let deadline = t0 + 2_000_000;
        sleep_until(deadline);
        let t1 = now_ns();
        assert!(t1 >= deadline);
        assert!(now_s() >= to_s(t0));
        // A deadline in the past returns at once (no panic, no wait).
        sleep_until(t0 - 1_000_000_000);
    }
}
