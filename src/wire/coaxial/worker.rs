//! The catheter's half of a lagged coupled step on a second thread:
//! [`CatheterWorker`].
//!
//! One persistent thread, started with the pair's and set up as the
//! pair's (pinned to its own CPU, SCHED_FIFO, its stack prefaulted, drawing
//! from the RT pool), steps the catheter while the pair's thread steps the
//! wire. The two exchange nothing but a raw pointer to the catheter and one
//! to the lumen, through a slot guarded by one atomic state word:
//!
//! ```text
//!  pair's thread                         worker (other CPU)
//!  exchange (forces, sheath, core)       sleeps until the period's start,
//!  slot ← (catheter, lumen); GO ──────▶  then spins on the state (bounded)
//!  wire.step(lumen)                      catheter.step(lumen)
//!  spins until DONE ◀──────────────────  slot ← result; DONE
//!  report; the catheter is its own again
//! ```
//!
//! Why these waits, for SCHED_FIFO threads pinned to the two CPUs of a
//! small machine:
//!
//! - The worker never spins unbounded. A SCHED_FIFO thread that spins on a
//!   CPU keeps every normal thread off it, and the kernel's RT throttling
//!   (95 % of each second by default) would then stall every RT thread of
//!   that CPU for the rest of the second. So it sleeps until just before
//!   the next period's start ([`CatheterWorker::wake_at`] less
//!   [`WAKE_LEAD_NS`], an absolute `clock_nanosleep`, as the pair's thread
//!   sleeps), spins from there for at most [`SPIN_NS`] while the pair's thread reads its hubs and hands
//!   the forces over, and parks if the work has not come by then (a
//!   futex; the pair's thread unparks it, one atomic swap and, only when
//!   it is parked, one system call). Woken by the clock, it is already
//!   running when the work comes, so the wake-up's latency (tens of µs
//!   for a futex wake across CPUs) stays off the tick's critical path.
//! - A step the worker has not begun when the pair's thread is done
//!   with the wire (the worker woken late) is taken back by the pair's
//!   thread and run there: one atomic exchange from GO decides who runs
//!   it, and such a tick costs the two steps one after the other instead
//!   of the worker's lateness (the result is the same to the bit).
//! - The pair's thread waits for the result spinning: the wait is the
//!   difference between the two rods' steps (tens of µs) on its own CPU,
//!   and a futex wait would add the wake-up's latency to every tick. Past
//!   about a millisecond of spinning it yields its CPU each round, so a
//!   worker misplaced on the same CPU still gets to finish.
//! - No lock, no allocation, no channel in the period: one atomic word's
//!   release/acquire orders the slot's contents and the catheter's state
//!   between the threads.
//!
//! The catheter stays a field of [`super::Coaxial`]: the worker holds its
//! pointer only between the start and the end of one step, which
//! [`Pending`] enforces (its drop waits for the worker, so not even an
//! unwinding pair's thread lets the catheter or the lumen go while the
//! worker uses them).

use crate::rt::clock::{self, Nanos};
use crate::rt::thread::{setup_current, RtGrant, RtRequest};
use crate::wire::lumen::Lumen;
use crate::wire::rod::{StepReport, Wire, WireFault};
use std::cell::UnsafeCell;
use std::sync::atomic::{AtomicI64, AtomicU64, AtomicU8, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

/// How long the worker spins for its work past the period's start (or past
/// its last result when no wake time is set) before it parks (ns).
pub const SPIN_NS: Nanos = 300_000;

/// How early the worker wakes before the period's start (ns): a timer's
/// wake-up on a virtual CPU can be late by tens of µs, and the worker
/// should be spinning when the work comes.
pub const WAKE_LEAD_NS: Nanos = 50_000;

/// Spins of the pair's thread waiting for the result before it starts to
/// yield its CPU each round (about a millisecond).
const SPINS_BEFORE_YIELD: u32 = 1 << 15;

const IDLE: u8 = 0;
const GO: u8 = 1;
const DONE: u8 = 2;
const STOP: u8 = 3;
/// The worker has claimed the step (from GO): the pair's thread waits.
const RUNNING: u8 = 4;

/// One step's work: the catheter, the lumen (type-erased) and how to step
/// the one in the other; then its result (None: the step panicked).
#[derive(Clone, Copy)]
struct Job {
    run: unsafe fn(*mut Wire, *const ()) -> Result<StepReport, WireFault>,
    rod: *mut Wire,
    lumen: *const (),
    result: Option<Result<StepReport, WireFault>>,
}

/// Steps the rod at `rod` in the lumen of type `L` at `lumen`.
///
/// # Safety
/// `rod` and `lumen` point to a live `Wire` and `L` that no other thread
/// uses (the lumen: only reads) until the step returns.
unsafe fn run<L: Lumen + Sync>(rod: *mut Wire, lumen: *const ()) -> Result<StepReport, WireFault> {
    // SAFETY: the caller's contract.
    unsafe { (*rod).step(&*(lumen as *const L)) }
}

unsafe fn no_job(_: *mut Wire, _: *const ()) -> Result<StepReport, WireFault> {
    Ok(StepReport::default())
}

struct Slot {
    state: AtomicU8,
    /// The next period's start (ns, absolute); 0: none.
    wake_at: AtomicI64,
    /// Steps the pair's thread took back and ran itself.
    taken_back: AtomicU64,
    job: UnsafeCell<Job>,
}

// SAFETY: `job` is written by the pair's thread only while `state` is IDLE
// or DONE (the worker does not touch it then) and read by the worker only
// after it has seen GO (acquire), which the pair's thread stores (release)
// after writing it; the worker writes the result before storing DONE
// (release), which the pair's thread sees (acquire) before reading it. The
// pointers in it are used by the worker only between GO and DONE, while
// the pair's thread leaves what they point to alone ([`Pending`]).
unsafe impl Sync for Slot {}
// SAFETY: as for Sync; the pointed-to `Wire` is Send and the lumen Sync
// (`start`'s bounds).
unsafe impl Send for Slot {}

/// A thread that steps a catheter's half of a lagged coupled step
/// ([`super::Coaxial::step_on`]); module docs for how it waits. Dropping
/// it stops and joins the thread.
pub struct CatheterWorker {
    slot: Arc<Slot>,
    thread: std::thread::Thread,
    handle: Option<JoinHandle<u64>>,
    grant: RtGrant,
}

impl std::fmt::Debug for CatheterWorker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CatheterWorker").field("grant", &self.grant).finish()
    }
}

impl CatheterWorker {
    /// Starts the thread (named `nvtmm-catheter`), set up as `request`
    /// asks ([`setup_current`]) and, with `pool_bytes`, drawing from the
    /// process's RT pool ([`crate::rt::alloc::enter_rt`]). Returns once the
    /// thread is set up. Errors: the OS refused the thread.
    pub fn spawn(request: &RtRequest, pool_bytes: Option<usize>) -> std::io::Result<CatheterWorker> {
        let slot = Arc::new(Slot {
            state: AtomicU8::new(IDLE),
            wake_at: AtomicI64::new(0),
            taken_back: AtomicU64::new(0),
            job: UnsafeCell::new(Job {
                run: no_job,
                rod: std::ptr::null_mut(),
                lumen: std::ptr::null(),
                result: None,
            }),
        });
        let (tx, rx) = std::sync::mpsc::sync_channel(1);
        let request = *request;
        let s = slot.clone();
        let handle = std::thread::Builder::new()
            .name("nvtmm-catheter".into())
            .stack_size(1 << 20)
            .spawn(move || {
                let grant = setup_current(&request);
                let pooled = pool_bytes.is_some_and(|b| crate::rt::alloc::enter_rt(b).is_ok());
                let _ = tx.send(grant);
                let sys0 = crate::rt::alloc::thread_system_calls();
                serve(&s);
                let sys = crate::rt::alloc::thread_system_calls() - sys0;
                if pooled {
                    crate::rt::alloc::leave_rt();
                }
                sys
            })?;
        let grant = rx
            .recv()
            .map_err(|_| std::io::Error::other("the catheter's worker ended before it was set up"))?;
        Ok(CatheterWorker {
            thread: handle.thread().clone(),
            slot,
            handle: Some(handle),
            grant,
        })
    }

    /// What the OS granted the worker's thread.
    pub fn grant(&self) -> &RtGrant {
        &self.grant
    }

    /// Steps the pair's thread took back because the worker had not begun
    /// them when the wire's step was done (`Coaxial::step_on` runs it then).
    pub fn taken_back(&self) -> u64 {
        self.slot.taken_back.load(Ordering::Relaxed)
    }

    /// The next period's start (ns on [`clock::now_ns`]'s clock): the
    /// worker, once done with a step, sleeps until then and spins from
    /// there for the next one. Set it before the step whose end it
    /// follows. Unset (0), the worker spins at once after each step.
    pub fn wake_at(&self, t: Nanos) {
        self.slot.wake_at.store(t, Ordering::Relaxed);
    }

    /// Stops and joins the thread; returns its system-allocator calls
    /// after its set-up ([`crate::rt::alloc::thread_system_calls`]: 0 is
    /// the requirement; always 0 without the RT allocator installed).
    pub fn stop(mut self) -> u64 {
        self.halt()
    }

    fn halt(&mut self) -> u64 {
        let Some(h) = self.handle.take() else {
            return 0;
        };
        self.slot.state.store(STOP, Ordering::Release);
        self.thread.unpark();
        h.join().unwrap_or(0)
    }

    /// Hands the worker `rod`'s step in `lumen`; the returned [`Pending`]
    /// holds both borrows until the step is done.
    pub(super) fn start<'a, L: Lumen + Sync>(&'a mut self, rod: &'a mut Wire, lumen: &'a L) -> Pending<'a> {
        // SAFETY: the worker is IDLE (every Pending waited for DONE and set
        // IDLE), so it does not touch the slot; `&mut self` excludes
        // another start.
        unsafe {
            *self.slot.job.get() = Job {
                run: run::<L>,
                rod: rod as *mut Wire,
                lumen: lumen as *const L as *const (),
                result: None,
            };
        }
        self.slot.state.store(GO, Ordering::Release);
        self.thread.unpark();
        Pending {
            slot: &self.slot,
            _rod: std::marker::PhantomData,
        }
    }
}

impl Drop for CatheterWorker {
    fn drop(&mut self) {
        self.halt();
    }
}

/// A step handed to the worker: holds the catheter and the lumen borrowed
/// until [`Pending::finish`], or its drop, has seen the worker done.
pub(super) struct Pending<'a> {
    slot: &'a Slot,
    _rod: std::marker::PhantomData<&'a mut Wire>,
}

impl Pending<'_> {
    /// Waits for the worker (module docs) and returns its step's result
    /// (None: the step panicked). A step the worker has not begun by now
    /// (its wake-up late: a parked worker's futex wake, a virtual CPU's
    /// timer) is taken back and run in this thread: the tick then costs
    /// the two steps' sum, not the worker's lateness.
    pub(super) fn finish(self) -> Option<Result<StepReport, WireFault>> {
        if self
            .slot
            .state
            .compare_exchange(GO, IDLE, Ordering::Acquire, Ordering::Relaxed)
            .is_ok()
        {
            // SAFETY: the exchange from GO excludes the worker's (it claims
            // the step by the same exchange to RUNNING); the job and what it
            // points to are this thread's until the next start.
            let job = unsafe { *self.slot.job.get() };
            self.slot.taken_back.fetch_add(1, Ordering::Relaxed);
            std::mem::forget(self);
            // SAFETY: as in `serve`: the rod and the lumen are borrowed for
            // this Pending's lifetime, which the caller holds.
            return std::panic::catch_unwind(|| unsafe { (job.run)(job.rod, job.lumen) }).ok();
        }
        self.wait();
        // SAFETY: DONE was seen with acquire: the worker wrote the result
        // before it and no longer touches the slot.
        let r = unsafe { (*self.slot.job.get()).result };
        self.slot.state.store(IDLE, Ordering::Relaxed);
        std::mem::forget(self);
        r
    }

    fn wait(&self) {
        let mut spins = 0u32;
        while self.slot.state.load(Ordering::Acquire) != DONE {
            if spins < SPINS_BEFORE_YIELD {
                spins += 1;
                std::hint::spin_loop();
            } else {
                std::thread::yield_now();
            }
        }
    }
}

impl Drop for Pending<'_> {
    fn drop(&mut self) {
        // Reached only when unwinding past a step: the worker must be done
        // with the catheter and the lumen before they can go (a step it has
        // not begun is withdrawn).
        if self
            .slot
            .state
            .compare_exchange(GO, IDLE, Ordering::Acquire, Ordering::Relaxed)
            .is_ok()
        {
            return;
        }
        self.wait();
        self.slot.state.store(IDLE, Ordering::Relaxed);
    }
}

/// The worker's loop: wait for GO (module docs), step, DONE; until STOP.
fn serve(slot: &Slot) {
    loop {
        let wake = slot.wake_at.load(Ordering::Relaxed);
        if wake - WAKE_LEAD_NS > clock::now_ns() {
            clock::sleep_until(wake - WAKE_LEAD_NS);
        }
        let until = clock::now_ns() + SPIN_NS;
        let state = loop {
            let s = slot.state.load(Ordering::Acquire);
            // Claim the step, unless the pair's thread took it back first
            // (`Pending::finish`).
            if s == GO
                && slot
                    .state
                    .compare_exchange(GO, RUNNING, Ordering::Acquire, Ordering::Relaxed)
                    .is_ok()
            {
                break GO;
            }
            if s == STOP {
                break s;
            }
            if clock::now_ns() < until {
                std::hint::spin_loop();
            } else {
                std::thread::park();
            }
        };
        if state == STOP {
            return;
        }
        // SAFETY: GO seen with acquire: the job is written and the pair's
        // thread leaves the slot, the rod and the lumen alone until DONE;
        // `run` was instantiated for the lumen's type (`start`).
        let job = unsafe { *slot.job.get() };
        let r = std::panic::catch_unwind(|| {
            // SAFETY: as above; the rod and the lumen outlive the step
            // (`Pending` waits for DONE).
            unsafe { (job.run)(job.rod, job.lumen) }
        });
        // SAFETY: the pair's thread reads the slot only after DONE.
        unsafe {
            (*slot.job.get()).result = r.ok();
        }
        slot.state.store(DONE, Ordering::Release);
    }
}
