//! A global allocator that counts the allocations made on the calling thread
//! while counting is on: the "allocates nothing" tests install it with
//! `#[global_allocator]` and wrap the code under test in [`count_allocations`].
//! Counting per thread keeps the test harness's own threads (and other tests
//! running in parallel) out of the count.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

/// The counting allocator (forwards everything to the system allocator).
pub struct Counting;

thread_local! {
    static ON: Cell<bool> = const { Cell::new(false) };
    static COUNT: Cell<usize> = const { Cell::new(0) };
}

fn note() {
    if ON.try_with(|c| c.get()).unwrap_or(false) {
        let _ = COUNT.try_with(|c| c.set(c.get() + 1));
    }
}

// SAFETY: forwards to the system allocator unchanged; only counts, using
// const-initialised thread-locals that never allocate.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        note();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        note();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc_zeroed(l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        note();
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(p, l, n) }
    }
}

/// Runs `f` and returns its result with the number of allocations (alloc,
/// alloc_zeroed, realloc) it made on this thread.
pub fn count_allocations<R>(f: impl FnOnce() -> R) -> (R, usize) {
    COUNT.with(|c| c.set(0));
    ON.with(|c| c.set(true));
    let r = f();
    ON.with(|c| c.set(false));
    (r, COUNT.with(|c| c.get()))
}

/// A global allocator that counts every thread's allocations while
/// counting is on, for a test of code that runs on several threads (a test
/// file with one test, so that no other test's thread allocates then).
pub struct EveryThread;

static EVERY_ON: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
static EVERY_COUNT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

fn note_every() {
    use std::sync::atomic::Ordering;
    if EVERY_ON.load(Ordering::Relaxed) {
        EVERY_COUNT.fetch_add(1, Ordering::Relaxed);
    }
}

// SAFETY: forwards to the system allocator unchanged; only counts, with
// atomics that never allocate.
unsafe impl GlobalAlloc for EveryThread {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        note_every();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        note_every();
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc_zeroed(l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        note_every();
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(p, l, n) }
    }
}

/// Runs `f` and returns its result with the number of allocations (alloc,
/// alloc_zeroed, realloc) every thread made meanwhile ([`EveryThread`]).
pub fn count_every_thread_allocations<R>(f: impl FnOnce() -> R) -> (R, usize) {
    use std::sync::atomic::Ordering;
    EVERY_COUNT.store(0, Ordering::SeqCst);
    EVERY_ON.store(true, Ordering::SeqCst);
    let r = f();
    EVERY_ON.store(false, Ordering::SeqCst);
    (r, EVERY_COUNT.load(Ordering::SeqCst))
}
