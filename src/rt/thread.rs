//! Scheduling set-up of a real-time thread: SCHED_FIFO at a configured
//! priority (`thread-priority`), pinning to one CPU (`core_affinity`; the
//! former has no affinity on Linux), locked memory (`mlockall`) and a
//! prefaulted stack. Where the OS refuses (no CAP_SYS_NICE, RLIMIT_RTPRIO 0,
//! RLIMIT_MEMLOCK too small) the call records the refusal and the thread
//! runs on at normal priority: the service says so once and the report shows
//! it.

use serde::Serialize;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

/// What a thread asks for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RtRequest {
    /// SCHED_FIFO priority 1..=99, or None for the normal policy.
    pub fifo_priority: Option<u8>,
    /// CPU to pin to, or None.
    pub cpu: Option<usize>,
    /// Bytes of stack to touch so the loop never page-faults on it.
    pub prefault_stack_bytes: usize,
}

/// What the OS granted to one thread.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct RtGrant {
    /// SCHED_FIFO was granted.
    pub fifo: bool,
    /// The priority asked for (0: none asked).
    pub priority: u8,
    /// The CPU the thread is pinned to, if pinning worked.
    pub cpu: Option<usize>,
    /// Stack bytes prefaulted.
    pub stack_prefaulted_bytes: usize,
    /// Why something asked for was refused (one line each).
    pub refusals: Vec<String>,
}

/// Locks the process's pages in RAM (`mlockall`). Call once from the main
/// thread, after setup and before starting RT threads. Returns the OS error
/// text when refused.
///
/// Pages are locked as they are touched (`MCL_CURRENT | MCL_FUTURE |
/// MCL_ONFAULT`, Linux ≥ 4.4): everything resident now stays resident, and
/// every page touched later stays once touched. The file-backed mappings
/// (the program's and its libraries' code and read-only data) are then
/// populated and locked whole (`mlock`), so code the loop runs for the
/// first time after start does not fault either. The RT threads' stacks are
/// prefaulted and the RT allocator's pool is populated and locked
/// explicitly.
///
/// Why not plain `MCL_CURRENT | MCL_FUTURE`: it makes every *reserved* page
/// resident, touched or not. faer's matrix-product backend reserves two
/// L3-sized buffers per thread that uses it (2 × 480 MiB on a VM that
/// reports a 480 MiB L3) and touches a small part of them: the 5832-node
/// service held 5.1 GB resident for about 1.2 GB used. On a kernel without
/// `MCL_ONFAULT` this falls back to `MCL_CURRENT | MCL_FUTURE`.
pub fn lock_memory() -> Result<(), String> {
    // SAFETY: mlockall takes flags only and has no memory-safety preconditions.
    if unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE | libc::MCL_ONFAULT) } == 0 {
        lock_file_mappings();
        return Ok(());
    }
    // SAFETY: as above.
    if unsafe { libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) } == 0 {
        Ok(())
    } else {
        Err(format!(
            "mlockall refused: {} (raise RLIMIT_MEMLOCK, e.g. LimitMEMLOCK=infinity in the systemd unit)",
            std::io::Error::last_os_error()
        ))
    }
}

/// Page faults (minor, major) the calling thread has taken so far
/// (`getrusage(RUSAGE_THREAD)`; one system call, no allocation). A minor
/// fault maps a page already in memory (a first touch), a major one reads
/// it from disk; (0, 0) where the count is not available.
pub fn thread_page_faults() -> (u64, u64) {
    // SAFETY: rusage is plain data; getrusage fills it or fails.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: a valid pointer to a rusage the call may write.
    if unsafe { libc::getrusage(libc::RUSAGE_THREAD, &mut ru) } == 0 {
        (ru.ru_minflt as u64, ru.ru_majflt as u64)
    } else {
        (0, 0)
    }
}

/// Blocks of at least this many bytes are served by their own `mmap` and
/// unmapped when freed (see [`return_large_blocks`]).
pub const MMAP_THRESHOLD_BYTES: usize = 128 * 1024;

/// Makes the C allocator (glibc) return large blocks to the system when
/// they are freed: blocks of [`MMAP_THRESHOLD_BYTES`] or more get their own
/// mapping, unmapped on free. By default glibc raises that threshold as
/// large blocks are freed (up to 32 MiB) and then serves them from its
/// arenas, whose free pages it gives back with `madvise(MADV_DONTNEED)`;
/// under `mlockall` that is refused, so every transient working set of a
/// helper thread (a basis recomputation's matrices) would stay resident
/// for good. A fixed threshold turns that off. Costs a `mmap`/`munmap` per
/// large block in the helper threads; the RT loop does not use the system
/// allocator. Returns whether the allocator took the setting (always false
/// off glibc).
pub fn return_large_blocks() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: mallopt takes two integers; M_MMAP_THRESHOLD accepts any
        // value up to 32 MiB.
        unsafe { libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES as libc::c_int) == 1 }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

/// Populates and locks every readable file-backed mapping listed in
/// `/proc/self/maps` (best effort: a mapping that cannot be locked is left
/// as it is). Returns the bytes locked.
fn lock_file_mappings() -> usize {
    let Ok(maps) = std::fs::read_to_string("/proc/self/maps") else {
        return 0;
    };
    let mut locked = 0;
    for line in maps.lines() {
        let mut fields = line.split_whitespace();
        let (Some(range), Some(perms)) = (fields.next(), fields.next()) else {
            continue;
        };
        let path = fields.nth(3).unwrap_or("");
        if !path.starts_with('/') || !perms.starts_with('r') {
            continue;
        }
        let Some((a, b)) = range.split_once('-') else {
            continue;
        };
        let (Ok(a), Ok(b)) = (usize::from_str_radix(a, 16), usize::from_str_radix(b, 16)) else {
            continue;
        };
        // SAFETY: mlock only pins pages of an existing mapping of this
        // process; an invalid range is refused with an error code.
        if b > a && unsafe { libc::mlock(a as *const libc::c_void, b - a) } == 0 {
            locked += b - a;
        }
    }
    locked
}

/// Undoes [`lock_memory`].
pub fn unlock_memory() {
    // SAFETY: munlockall has no preconditions.
    unsafe { libc::munlockall() };
}

#[inline(never)]
fn prefault(bytes: usize) {
    // Touch the stack in 4 KiB pages below this frame through a recursion of
    // fixed-size frames, so no variable-length array is needed.
    const CHUNK: usize = 16 * 1024;
    let mut page = [0u8; CHUNK];
    for i in (0..CHUNK).step_by(4096) {
        page[i] = 1;
    }
    std::hint::black_box(&mut page);
    if bytes > CHUNK {
        prefault(bytes - CHUNK);
    }
}

/// Applies `req` to the calling thread and reports what was granted. Call it
/// at the start of the thread, before its loop (it may allocate for the
/// refusal messages).
pub fn setup_current(req: &RtRequest) -> RtGrant {
    let mut grant = RtGrant::default();
    if let Some(cpu) = req.cpu {
        let ids = core_affinity::get_core_ids().unwrap_or_default();
        match ids.iter().find(|c| c.id == cpu) {
            Some(&id) if core_affinity::set_for_current(id) => grant.cpu = Some(cpu),
            Some(_) => grant.refusals.push(format!("pinning to CPU {cpu} refused by the OS")),
            None => grant.refusals.push(format!(
                "CPU {cpu} is not available to this process (available: {:?})",
                ids.iter().map(|c| c.id).collect::<Vec<_>>()
            )),
        }
    }
    if let Some(p) = req.fifo_priority {
        grant.priority = p;
        match set_fifo(p) {
            Ok(()) => grant.fifo = true,
            Err(e) => grant.refusals.push(format!(
                "SCHED_FIFO priority {p} refused ({e}); running at normal priority. Grant CAP_SYS_NICE \
                 (setcap cap_sys_nice+ep) or RLIMIT_RTPRIO (LimitRTPRIO=99)"
            )),
        }
    }
    if req.prefault_stack_bytes > 0 {
        prefault(req.prefault_stack_bytes);
        grant.stack_prefaulted_bytes = req.prefault_stack_bytes;
    }
    grant
}

fn set_fifo(priority: u8) -> Result<(), String> {
    use thread_priority::unix::{
        set_thread_priority_and_policy, thread_native_id, RealtimeThreadSchedulePolicy, ThreadSchedulePolicy,
    };
    use thread_priority::{ThreadPriority, ThreadPriorityValue};
    let value = ThreadPriorityValue::try_from(priority.clamp(1, 99)).map_err(|e| e.to_string())?;
    set_thread_priority_and_policy(
        thread_native_id(),
        ThreadPriority::Crossplatform(value),
        ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
    )
    .map_err(|e| format!("{e:?}"))
}

/// Sets the calling thread's nice value (Linux: per thread). A thread at
/// nice 19 gets only the CPU time that threads at nice 0 leave (CFS weights
/// 15 against 1024). Returns the OS error text when refused.
pub fn set_current_nice(nice: i32) -> Result<(), String> {
    // SAFETY: gettid and setpriority take integers only; on Linux
    // PRIO_PROCESS with a thread id applies to that thread alone.
    let r = unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        libc::setpriority(libc::PRIO_PROCESS, tid, nice)
    };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error().to_string())
    }
}

/// Starts a thread that keeps CPU `cpu` from going idle until `stop` is
/// set: pinned there, under `SCHED_IDLE` (it runs only when nothing else
/// on that CPU wants to, and any other thread preempts it at once), it
/// spins. On a virtual machine a halted virtual CPU is woken through the
/// host when a timer fires, which can make an RT thread sleeping to a
/// deadline there wake milliseconds late; a CPU that never halts takes the
/// timer at once (the user-space counterpart of booting with
/// `idle=poll`). It costs that CPU's idle time, and takes some from plain
/// threads there (a `SCHED_IDLE` thread still gets a small share).
/// Returns the thread and why something asked for was refused (the thread
/// spins anyway: unpinned or under the normal policy it is only less
/// useful).
pub fn spawn_keep_awake(cpu: usize, stop: Arc<AtomicBool>) -> std::io::Result<(JoinHandle<()>, Vec<String>)> {
    let (tx, rx) = std::sync::mpsc::channel();
    let h = std::thread::Builder::new().name("nvtmm-awake".into()).spawn(move || {
        let mut refusals = setup_current(&RtRequest {
            fifo_priority: None,
            cpu: Some(cpu),
            prefault_stack_bytes: 0,
        })
        .refusals;
        // SAFETY: sched_param is plain data; sched_setscheduler(0, ..)
        // applies to the calling thread and reads the struct only.
        let param: libc::sched_param = unsafe { std::mem::zeroed() };
        // SAFETY: as above.
        if unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) } != 0 {
            refusals.push(format!(
                "keep-awake thread: SCHED_IDLE refused ({})",
                std::io::Error::last_os_error()
            ));
        }
        let _ = tx.send(refusals);
        while !stop.load(Ordering::Relaxed) {
            std::hint::spin_loop();
        }
    })?;
    let refusals = rx.recv().unwrap_or_default();
    Ok((h, refusals))
}

/// [`spawn_keep_awake`], with what was refused, or why the thread did not
/// start, added to `refusals` (the service and `bench wire --tick --rt`
/// both report them so).
pub fn spawn_keep_awake_noting(
    cpu: usize,
    stop: Arc<AtomicBool>,
    refusals: &mut Vec<String>,
) -> Option<JoinHandle<()>> {
    match spawn_keep_awake(cpu, stop) {
        Ok((h, why)) => {
            refusals.extend(why);
            Some(h)
        }
        Err(e) => {
            refusals.push(format!("keep-awake thread not started: {e}"));
            None
        }
    }
}

/// Whether the calling thread runs under SCHED_FIFO now.
pub fn current_is_fifo() -> bool {
    // SAFETY: sched_getscheduler(0) queries the calling thread; no pointers.
    unsafe { libc::sched_getscheduler(0) == libc::SCHED_FIFO }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The keep-awake thread runs pinned under SCHED_IDLE (which any user
    /// may take), spins, and ends once told to.
    #[test]
    fn the_keep_awake_thread_spins_idle_and_stops() {
        let stop = Arc::new(AtomicBool::new(false));
        let (h, refusals) = spawn_keep_awake(0, stop.clone()).unwrap();
        assert!(
            !refusals.iter().any(|r| r.contains("SCHED_IDLE")),
            "SCHED_IDLE is never refused on Linux: {refusals:?}"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
        assert!(!h.is_finished(), "it spins until told to stop");
        stop.store(true, Ordering::Relaxed);
        let t0 = std::time::Instant::now();
        while !h.is_finished() && t0.elapsed().as_secs() < 10 {
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        assert!(h.is_finished(), "it stops once told to");
        h.join().unwrap();
    }

    #[test]
    fn setup_reports_what_it_got_and_never_fails() {
        let g = std::thread::spawn(|| {
            setup_current(&RtRequest {
                fifo_priority: Some(10),
                cpu: Some(0),
                prefault_stack_bytes: 64 * 1024,
            })
        })
        .join()
        .unwrap();
        assert_eq!(g.priority, 10);
        assert_eq!(g.stack_prefaulted_bytes, 64 * 1024);
        // Either granted or refused with a reason, never silently.
        assert!(g.fifo || g.refusals.iter().any(|r| r.contains("SCHED_FIFO")));
        assert!(g.cpu == Some(0) || g.refusals.iter().any(|r| r.contains("CPU 0")));
        let g = std::thread::spawn(|| {
            setup_current(&RtRequest {
                fifo_priority: None,
                cpu: Some(100_000),
                prefault_stack_bytes: 0,
            })
        })
        .join()
        .unwrap();
        assert!(!g.fifo && g.cpu.is_none() && g.refusals.len() == 1);
    }
}
