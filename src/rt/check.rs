//! `nvtmm check-rt`: an audit of the box for the 1 kHz loop. Each check
//! reads what Linux exposes (files under /sys and /proc, resource limits) and
//! says pass, warn or fail with the fix. Nothing is changed.

use serde::Serialize;
use std::path::Path;

/// Outcome of one check.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Level {
    /// Set up as recommended.
    Pass,
    /// Works, but latency will suffer.
    Warn,
    /// The loop cannot get what it needs.
    Fail,
}

/// One line of the audit.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Check {
    /// Short name (stable, for scripts).
    pub name: &'static str,
    /// Outcome.
    pub level: Level,
    /// What was found and, if not pass, what to do.
    pub detail: String,
}

fn read(path: &str) -> Option<String> {
    std::fs::read_to_string(path).ok().map(|s| s.trim().to_string())
}

fn rlimit(resource: libc::__rlimit_resource_t) -> Option<(u64, u64)> {
    let mut r = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: `r` is a valid, writable rlimit.
    let rc = unsafe { libc::getrlimit(resource, &mut r) };
    (rc == 0).then_some((r.rlim_cur, r.rlim_max))
}

fn is_root() -> bool {
    // SAFETY: geteuid has no preconditions.
    unsafe { libc::geteuid() == 0 }
}

fn fmt_limit(v: u64) -> String {
    if v == libc::RLIM_INFINITY {
        "unlimited".into()
    } else {
        v.to_string()
    }
}

/// Runs every check. `rt_cpu` is the CPU the loop is configured to use.
pub fn audit(rt_cpu: Option<usize>) -> Vec<Check> {
    let mut out = Vec::new();
    let mut add = |name, level, detail: String| out.push(Check { name, level, detail });

    let uname_v = read("/proc/sys/kernel/version").unwrap_or_default();
    let realtime = read("/sys/kernel/realtime").as_deref() == Some("1");
    if realtime || uname_v.contains("PREEMPT_RT") {
        add("preempt_rt", Level::Pass, format!("PREEMPT_RT kernel ({uname_v})"));
    } else {
        add(
            "preempt_rt",
            Level::Warn,
            format!("not a PREEMPT_RT kernel ({uname_v}); install linux-image-rt (Debian) for bounded latency"),
        );
    }

    let root = is_root();
    match rlimit(libc::RLIMIT_RTPRIO) {
        Some((cur, _)) if cur >= 80 || root => add(
            "rtprio",
            Level::Pass,
            format!("RLIMIT_RTPRIO {}{}", fmt_limit(cur), if root { " (root)" } else { "" }),
        ),
        Some((cur, _)) => add(
            "rtprio",
            Level::Fail,
            format!(
                "RLIMIT_RTPRIO {} < 80: SCHED_FIFO will be refused; set LimitRTPRIO=99 (systemd) or rtprio in limits.conf",
                fmt_limit(cur)
            ),
        ),
        None => add("rtprio", Level::Warn, "RLIMIT_RTPRIO unreadable".into()),
    }
    match rlimit(libc::RLIMIT_MEMLOCK) {
        Some((cur, _)) if cur == libc::RLIM_INFINITY || root => add(
            "memlock",
            Level::Pass,
            format!("RLIMIT_MEMLOCK {}{}", fmt_limit(cur), if root { " (root)" } else { "" }),
        ),
        Some((cur, _)) => add(
            "memlock",
            Level::Warn,
            format!(
                "RLIMIT_MEMLOCK {} bytes: mlockall of the whole process will be refused; set LimitMEMLOCK=infinity",
                fmt_limit(cur)
            ),
        ),
        None => add("memlock", Level::Warn, "RLIMIT_MEMLOCK unreadable".into()),
    }

    let ncpu = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    let mut governors = Vec::new();
    for c in 0..ncpu {
        if let Some(g) = read(&format!("/sys/devices/system/cpu/cpu{c}/cpufreq/scaling_governor")) {
            governors.push(format!("cpu{c}={g}"));
        }
    }
    if governors.is_empty() {
        add(
            "governor",
            Level::Warn,
            "no cpufreq interface (a VM, or frequency scaling off); check BIOS power settings".into(),
        );
    } else if governors.iter().all(|g| g.ends_with("=performance")) {
        add("governor", Level::Pass, governors.join(" "));
    } else {
        add(
            "governor",
            Level::Warn,
            format!(
                "{}: use the performance governor (cpupower frequency-set -g performance)",
                governors.join(" ")
            ),
        );
    }

    let isolated = read("/sys/devices/system/cpu/isolated").unwrap_or_default();
    let cmdline = read("/proc/cmdline").unwrap_or_default();
    match rt_cpu {
        Some(cpu) if cpu_in_list(&isolated, cpu) => {
            add("isolcpus", Level::Pass, format!("loop CPU {cpu} is isolated ({isolated})"))
        }
        Some(cpu) => add(
            "isolcpus",
            Level::Warn,
            format!(
                "loop CPU {cpu} is not isolated (isolated: '{isolated}'); add isolcpus={cpu} nohz_full={cpu} rcu_nocbs={cpu} to the kernel command line"
            ),
        ),
        None => add("isolcpus", Level::Warn, "the loop is not pinned to a CPU (loop.cpu)".into()),
    }
    for key in ["nohz_full", "rcu_nocbs"] {
        if cmdline.split_whitespace().any(|w| w.starts_with(&format!("{key}="))) {
            add(
                key_name(key),
                Level::Pass,
                format!("{key} set on the kernel command line"),
            );
        } else {
            add(
                key_name(key),
                Level::Warn,
                format!("{key}= not on the kernel command line"),
            );
        }
    }

    if Path::new("/dev/cpu_dma_latency").exists() {
        match std::fs::OpenOptions::new().write(true).open("/dev/cpu_dma_latency") {
            Ok(_) => add(
                "cpu_dma_latency",
                Level::Pass,
                "/dev/cpu_dma_latency writable: the service can hold C-states at 0 while it runs".into(),
            ),
            Err(e) => add(
                "cpu_dma_latency",
                Level::Warn,
                format!("/dev/cpu_dma_latency not writable ({e}); deep C-states add wake-up latency"),
            ),
        }
    } else {
        add(
            "cpu_dma_latency",
            Level::Warn,
            "/dev/cpu_dma_latency missing; disable deep C-states (processor.max_cstate=0 intel_idle.max_cstate=0)"
                .into(),
        );
    }
    let throttle = read("/proc/sys/kernel/sched_rt_runtime_us").unwrap_or_default();
    add(
        "rt_throttling",
        Level::Pass,
        format!("sched_rt_runtime_us = {throttle} (RT throttling keeps a runaway FIFO thread from hanging a CPU)"),
    );
    out
}

fn key_name(key: &str) -> &'static str {
    match key {
        "nohz_full" => "nohz_full",
        _ => "rcu_nocbs",
    }
}

/// Whether `cpu` is in a Linux CPU list such as "1,3-5".
pub fn cpu_in_list(list: &str, cpu: usize) -> bool {
    list.split(',').filter(|s| !s.trim().is_empty()).any(|part| {
        let mut it = part.trim().splitn(2, '-');
        let lo = it.next().and_then(|s| s.parse::<usize>().ok());
        let hi = it.next().and_then(|s| s.parse::<usize>().ok()).or(lo);
        matches!((lo, hi), (Some(lo), Some(hi)) if (lo..=hi).contains(&cpu))
    })
}

/// The audit as text lines ("PASS name: detail").
pub fn render(checks: &[Check]) -> String {
    checks
        .iter()
        .map(|c| {
            let tag = match c.level {
                Level::Pass => "PASS",
                Level::Warn => "WARN",
                Level::Fail => "FAIL",
            };
            format!("{tag} {:<16} {}\n", c.name, c.detail)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_lists_parse_like_the_kernel_writes_them() {
        assert!(cpu_in_list("1,3-5", 4));
        assert!(cpu_in_list("1,3-5", 1));
        assert!(!cpu_in_list("1,3-5", 2));
        assert!(!cpu_in_list("", 0));
        assert!(!cpu_in_list("x-y", 0));
    }

    #[test]
    fn the_audit_covers_every_topic_once() {
        let checks = audit(Some(1));
        for name in [
            "preempt_rt",
            "rtprio",
            "memlock",
            "governor",
            "isolcpus",
            "cpu_dma_latency",
        ] {
            assert_eq!(checks.iter().filter(|c| c.name == name).count(), 1, "{name}");
        }
        assert!(render(&checks).lines().count() == checks.len());
    }
}
