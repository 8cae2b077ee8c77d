//! One monotonic clock for the whole service: `CLOCK_MONOTONIC`, read as
//! seconds since a process-wide epoch, and an absolute-deadline sleep on the
//! same clock (`clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME)`). Mixing
//! clocks produces bogus overruns; every thread and every sample timestamp
//! uses this one.

use std::sync::OnceLock;

/// A point on `CLOCK_MONOTONIC` in nanoseconds.
pub type Nanos = i64;

fn raw_now() -> Nanos {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec * 1_000_000_000 + ts.tv_nsec
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
