//! An RT-safe global allocator: ordinary threads use the system allocator; a
//! thread that calls [`enter_rt`] (once, before its loop) is served from a
//! fixed pool reserved and prefaulted by that call, managed by a TLSF
//! allocator (`rlsf`, constant-time allocate and free). The haptic loop then
//! never calls into the system allocator even when a library it uses
//! allocates (clarabel's `solve()` allocates one small block per call).
//!
//! Install it in a binary with
//! `#[global_allocator] static ALLOC: RtAllocator = RtAllocator;` (the `nvtmm`
//! binary does).
//!
//! # Design and soundness
//!
//! - **Which thread is RT**: a `thread_local!` `Cell<bool>` with const
//!   initialisation and no destructor, so reading it never allocates, never
//!   registers a destructor and works during thread teardown: the allocator
//!   never recurses into itself.
//! - **The pool**: one per process, `mmap`ed (anonymous, `MAP_POPULATE`),
//!   every page written once (prefaulted) and `mlock`ed (best effort: the
//!   service's `mlockall` covers it anyway), never unmapped, so the TLSF
//!   structure can hold it as `'static`. Further RT threads share it.
//! - **Free from any thread**: a pointer inside the pool's address range goes
//!   back to the pool whatever thread frees it; anything else goes to the
//!   system allocator. Pool memory and system memory never mix because the
//!   range test is exact and the pool range never changes after set-up
//!   (published with release/acquire before any pool pointer exists).
//! - **The lock**: the TLSF state is guarded by an atomic flag taken with a
//!   bounded try-spin (`SPIN_TRIES` attempts), never a system lock. It is
//!   uncontended in practice: only RT threads allocate from the pool, and
//!   frees of pool memory by other threads are rare (an object the loop
//!   allocated and handed away); each critical section is a constant-time
//!   TLSF operation of ~100 ns. Because the spin is bounded, a holder that was
//!   preempted (possibly by the RT thread itself, on the same core) can never
//!   deadlock the RT thread: an RT allocation that cannot take the flag falls
//!   back to the system allocator (counted), and a free that cannot take it is
//!   pushed onto a lock-free intrusive stack (the freed block itself stores the
//!   link) that the next holder drains. The stack has many pushers and one
//!   taker that takes the whole list with a swap, so it has no ABA problem.
//!   Pool blocks are at least 16 bytes, 8-aligned, to hold that link.
//! - **Exhaustion** falls back to the system allocator and is counted, never
//!   UB. A non-RT thread that reallocates a pool block moves it to the system
//!   allocator (it does not grow inside the RT pool).
//!
//! Counters ([`stats`], [`thread_system_calls`]): system-allocator calls made
//! by RT threads after [`enter_rt`] (allocations, frees and reallocations;
//! must stay 0), pool allocations and frees, deferred frees, bytes in use and
//! the high-water mark, exhaustion and contention fallbacks.

use rlsf::Tlsf;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::{Cell, UnsafeCell};
use std::ptr::{self, NonNull};
use std::sync::atomic::{AtomicBool, AtomicPtr, AtomicU64, AtomicU8, AtomicUsize, Ordering};

/// TLSF with 28 first-level classes (blocks up to 8 GiB on 64-bit) and 16
/// second-level classes.
type PoolTlsf = Tlsf<'static, u32, u16, 28, 16>;

/// Attempts on the pool's flag before giving up.
const SPIN_TRIES: u32 = 256;
/// Pool blocks are at least this large and this aligned (they hold a
/// [`FreeNode`] when their free is deferred).
const MIN_SIZE: usize = 16;
const MIN_ALIGN: usize = 8;
/// Allowed pool sizes.
const POOL_MIN: usize = 64 << 10;
const POOL_MAX: usize = 4 << 30;

const EMPTY: u8 = 0;
const INIT: u8 = 1;
const READY: u8 = 2;

thread_local! {
    static IS_RT: Cell<bool> = const { Cell::new(false) };
    static THREAD_SYS: Cell<u64> = const { Cell::new(0) };
}

fn is_rt() -> bool {
    IS_RT.try_with(|c| c.get()).unwrap_or(false)
}

/// A deferred free: written into the freed block itself.
#[repr(C)]
struct FreeNode {
    next: *mut FreeNode,
    align: usize,
}

/// Why the pool did not serve an allocation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Miss {
    NotReady,
    Exhausted,
    Contended,
}

/// The pool: TLSF state behind an atomic flag, its address range, counters.
struct Pool {
    state: AtomicU8,
    lock: AtomicBool,
    tlsf: UnsafeCell<PoolTlsf>,
    start: AtomicUsize,
    end: AtomicUsize,
    locked_in_ram: AtomicBool,
    deferred: AtomicPtr<FreeNode>,
    allocs: AtomicU64,
    frees: AtomicU64,
    deferred_frees: AtomicU64,
    exhausted: AtomicU64,
    contended: AtomicU64,
    sys_on_rt: AtomicU64,
    in_use: AtomicUsize,
    high_water: AtomicUsize,
}

// SAFETY: the only non-Sync field, the TLSF state, is accessed solely while
// `lock` is held (acquire on take, release on give), which serializes it.
unsafe impl Sync for Pool {}

/// `layout` as the pool stores it (at least MIN_SIZE bytes, MIN_ALIGN-aligned).
fn pool_layout(l: Layout) -> Option<Layout> {
    Layout::from_size_align(l.size().max(MIN_SIZE), l.align().max(MIN_ALIGN)).ok()
}

impl Pool {
    const fn new() -> Pool {
        Pool {
            state: AtomicU8::new(EMPTY),
            lock: AtomicBool::new(false),
            tlsf: UnsafeCell::new(PoolTlsf::new()),
            start: AtomicUsize::new(0),
            end: AtomicUsize::new(0),
            locked_in_ram: AtomicBool::new(false),
            deferred: AtomicPtr::new(ptr::null_mut()),
            allocs: AtomicU64::new(0),
            frees: AtomicU64::new(0),
            deferred_frees: AtomicU64::new(0),
            exhausted: AtomicU64::new(0),
            contended: AtomicU64::new(0),
            sys_on_rt: AtomicU64::new(0),
            in_use: AtomicUsize::new(0),
            high_water: AtomicUsize::new(0),
        }
    }

    fn bytes(&self) -> usize {
        self.end.load(Ordering::Acquire) - self.start.load(Ordering::Acquire)
    }

    /// Reserves, prefaults and locks `bytes` (first call only; later calls
    /// return the existing size). Not for the RT path: it may sleep.
    fn init(&self, bytes: usize) -> Result<usize, RtAllocError> {
        if !(POOL_MIN..=POOL_MAX).contains(&bytes) {
            return Err(RtAllocError::Size(bytes));
        }
        if self
            .state
            .compare_exchange(EMPTY, INIT, Ordering::Acquire, Ordering::Acquire)
            .is_err()
        {
            while self.state.load(Ordering::Acquire) == INIT {
                std::thread::yield_now();
            }
            return match self.state.load(Ordering::Acquire) {
                READY => Ok(self.bytes()),
                _ => self.init(bytes),
            };
        }
        // SAFETY: sysconf has no preconditions.
        let page = usize::try_from(unsafe { libc::sysconf(libc::_SC_PAGESIZE) })
            .ok()
            .filter(|&p| p > 0)
            .unwrap_or(4096);
        let len = bytes.div_ceil(page) * page;
        // SAFETY: an anonymous private mapping at an address of the kernel's
        // choosing touches no existing memory.
        let base = unsafe {
            libc::mmap(
                ptr::null_mut(),
                len,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_PRIVATE | libc::MAP_ANONYMOUS | libc::MAP_POPULATE,
                -1,
                0,
            )
        };
        if base == libc::MAP_FAILED {
            self.state.store(EMPTY, Ordering::Release);
            return Err(RtAllocError::Map(
                std::io::Error::last_os_error().raw_os_error().unwrap_or(0),
            ));
        }
        let base = base.cast::<u8>();
        for off in (0..len).step_by(page) {
            // SAFETY: `off < len`, inside the fresh writable mapping.
            unsafe { ptr::write_volatile(base.add(off), 0) };
        }
        // SAFETY: locking pages of our own mapping; failure only means they may be paged out.
        let locked = unsafe { libc::mlock(base.cast(), len) } == 0;
        self.locked_in_ram.store(locked, Ordering::Relaxed);
        let Some(block) = NonNull::new(ptr::slice_from_raw_parts_mut(base, len)) else {
            self.state.store(EMPTY, Ordering::Release);
            return Err(RtAllocError::Map(0));
        };
        // No other thread touches the TLSF before `state` is READY (the
        // allocation paths check `start`/`end`, still 0), but take the flag
        // anyway for a uniform rule.
        while !self.try_lock() {}
        // SAFETY: the mapping is never unmapped while the pool is in use (the
        // process-wide pool never; test pools only in Drop), so it outlives
        // the TLSF that owns it; we hold the flag.
        let used = unsafe { (*self.tlsf.get()).insert_free_block_ptr(block) };
        self.unlock();
        if used.is_none() {
            // SAFETY: unmapping the mapping made above, which nothing references.
            unsafe { libc::munmap(base.cast(), len) };
            self.state.store(EMPTY, Ordering::Release);
            return Err(RtAllocError::Size(bytes));
        }
        self.start.store(base as usize, Ordering::Release);
        self.end.store(base as usize + len, Ordering::Release);
        self.state.store(READY, Ordering::Release);
        Ok(len)
    }

    fn contains(&self, p: *mut u8) -> bool {
        let a = p as usize;
        a >= self.start.load(Ordering::Acquire) && a < self.end.load(Ordering::Acquire)
    }

    fn try_lock(&self) -> bool {
        for _ in 0..SPIN_TRIES {
            if !self.lock.load(Ordering::Relaxed)
                && self
                    .lock
                    .compare_exchange_weak(false, true, Ordering::Acquire, Ordering::Relaxed)
                    .is_ok()
            {
                return true;
            }
            std::hint::spin_loop();
        }
        false
    }

    fn unlock(&self) {
        self.lock.store(false, Ordering::Release);
    }

    /// Frees the deferred blocks. Caller holds the flag.
    ///
    /// # Safety
    /// The flag is held.
    unsafe fn drain(&self, tlsf: &mut PoolTlsf) {
        let mut node = self.deferred.swap(ptr::null_mut(), Ordering::Acquire);
        while let Some(n) = NonNull::new(node) {
            // SAFETY: every node on the stack is a pool block pushed by
            // `free`, which wrote it fully before publishing it (release CAS).
            let FreeNode { next, align } = unsafe { n.as_ptr().read() };
            // SAFETY: the block was allocated by this TLSF with this alignment.
            unsafe { tlsf.deallocate(n.cast(), align) };
            self.frees.fetch_add(1, Ordering::Relaxed);
            node = next;
        }
    }

    fn alloc(&self, layout: Layout) -> Result<NonNull<u8>, Miss> {
        if self.state.load(Ordering::Acquire) != READY {
            return Err(Miss::NotReady);
        }
        let l = pool_layout(layout).ok_or(Miss::Exhausted)?;
        if !self.try_lock() {
            return Err(Miss::Contended);
        }
        // SAFETY: we hold the flag, so we have the TLSF to ourselves.
        let p = unsafe {
            let tlsf = &mut *self.tlsf.get();
            self.drain(tlsf);
            tlsf.allocate(l)
        };
        self.unlock();
        let p = p.ok_or(Miss::Exhausted)?;
        self.allocs.fetch_add(1, Ordering::Relaxed);
        let used = self.in_use.fetch_add(l.size(), Ordering::Relaxed) + l.size();
        self.high_water.fetch_max(used, Ordering::Relaxed);
        Ok(p)
    }

    /// # Safety
    /// `p` was returned by `self.alloc(layout)` (or `realloc` with this
    /// layout) and is not used afterwards.
    unsafe fn free(&self, p: NonNull<u8>, layout: Layout) {
        let Some(l) = pool_layout(layout) else { return };
        self.in_use.fetch_sub(l.size(), Ordering::Relaxed);
        if self.try_lock() {
            // SAFETY: we hold the flag; `p` is a live block of this TLSF with
            // alignment `l.align()` (the caller's contract).
            unsafe {
                let tlsf = &mut *self.tlsf.get();
                self.drain(tlsf);
                tlsf.deallocate(p, l.align());
            }
            self.unlock();
            self.frees.fetch_add(1, Ordering::Relaxed);
        } else {
            let node = p.cast::<FreeNode>().as_ptr();
            let mut head = self.deferred.load(Ordering::Relaxed);
            loop {
                // SAFETY: the block is ours (being freed), ≥ 16 bytes and
                // 8-aligned (pool_layout), so it holds a FreeNode.
                unsafe {
                    node.write(FreeNode {
                        next: head,
                        align: l.align(),
                    })
                };
                match self
                    .deferred
                    .compare_exchange_weak(head, node, Ordering::Release, Ordering::Relaxed)
                {
                    Ok(_) => break,
                    Err(h) => head = h,
                }
            }
            self.deferred_frees.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Grows or shrinks a pool block inside the pool; `None` leaves it intact.
    ///
    /// # Safety
    /// `p` is a live pool block allocated with `layout`; `new_size` is a
    /// valid size for `layout.align()`.
    unsafe fn realloc(&self, p: NonNull<u8>, layout: Layout, new_size: usize) -> Option<NonNull<u8>> {
        let l = pool_layout(layout)?;
        let nl = pool_layout(Layout::from_size_align(new_size, layout.align()).ok()?)?;
        if !self.try_lock() {
            self.contended.fetch_add(1, Ordering::Relaxed);
            return None;
        }
        // SAFETY: we hold the flag; `p` is a live block of this TLSF with the
        // same (adjusted) alignment as `nl`.
        let r = unsafe {
            let tlsf = &mut *self.tlsf.get();
            self.drain(tlsf);
            tlsf.reallocate(p, nl)
        };
        self.unlock();
        if r.is_some() {
            self.allocs.fetch_add(1, Ordering::Relaxed);
            self.frees.fetch_add(1, Ordering::Relaxed);
            self.in_use.fetch_sub(l.size(), Ordering::Relaxed);
            let used = self.in_use.fetch_add(nl.size(), Ordering::Relaxed) + nl.size();
            self.high_water.fetch_max(used, Ordering::Relaxed);
        } else {
            self.exhausted.fetch_add(1, Ordering::Relaxed);
        }
        r
    }

    fn note_sys_on_rt(&self) {
        self.sys_on_rt.fetch_add(1, Ordering::Relaxed);
        let _ = THREAD_SYS.try_with(|c| c.set(c.get() + 1));
    }

    fn note_miss(&self, m: Miss) {
        match m {
            Miss::Exhausted => self.exhausted.fetch_add(1, Ordering::Relaxed),
            Miss::Contended => self.contended.fetch_add(1, Ordering::Relaxed),
            Miss::NotReady => 0,
        };
        self.note_sys_on_rt();
    }

    fn stats(&self) -> AllocStats {
        let r = |a: &AtomicU64| a.load(Ordering::Relaxed);
        AllocStats {
            system_calls_on_rt: r(&self.sys_on_rt),
            pool_allocs: r(&self.allocs),
            pool_frees: r(&self.frees),
            deferred_frees: r(&self.deferred_frees),
            exhausted_fallbacks: r(&self.exhausted),
            contended_fallbacks: r(&self.contended),
            pool_bytes: self.bytes(),
            pool_in_use_bytes: self.in_use.load(Ordering::Relaxed),
            pool_high_water_bytes: self.high_water.load(Ordering::Relaxed),
            pool_locked_in_ram: self.locked_in_ram.load(Ordering::Relaxed),
        }
    }

    // ---- the GlobalAlloc logic, over any pool (the tests use their own) ----

    /// # Safety
    /// `GlobalAlloc::alloc`'s contract.
    unsafe fn g_alloc(&self, l: Layout, zeroed: bool) -> *mut u8 {
        if is_rt() {
            match self.alloc(l) {
                Ok(p) => {
                    if zeroed {
                        // SAFETY: a fresh block of at least `l.size()` bytes.
                        unsafe { p.as_ptr().write_bytes(0, l.size()) };
                    }
                    return p.as_ptr();
                }
                Err(m) => self.note_miss(m),
            }
        }
        // SAFETY: the caller's contract.
        unsafe {
            if zeroed {
                System.alloc_zeroed(l)
            } else {
                System.alloc(l)
            }
        }
    }

    /// # Safety
    /// `GlobalAlloc::dealloc`'s contract.
    unsafe fn g_dealloc(&self, p: *mut u8, l: Layout) {
        match NonNull::new(p) {
            // SAFETY: inside the pool range, so a pool block allocated with `l`.
            Some(nn) if self.contains(p) => unsafe { self.free(nn, l) },
            _ => {
                if is_rt() {
                    self.note_sys_on_rt();
                }
                // SAFETY: outside the pool: a system block (caller's contract).
                unsafe { System.dealloc(p, l) }
            }
        }
    }

    /// # Safety
    /// `GlobalAlloc::realloc`'s contract.
    unsafe fn g_realloc(&self, p: *mut u8, l: Layout, new_size: usize) -> *mut u8 {
        let rt = is_rt();
        let Ok(nl) = Layout::from_size_align(new_size, l.align()) else {
            return ptr::null_mut();
        };
        match NonNull::new(p) {
            Some(nn) if self.contains(p) => {
                if rt {
                    // SAFETY: a live pool block allocated with `l`.
                    if let Some(q) = unsafe { self.realloc(nn, l, new_size) } {
                        return q.as_ptr();
                    }
                    self.note_sys_on_rt();
                }
                // Move it out to the system allocator.
                // SAFETY: `nl` has a non-zero size (GlobalAlloc contract).
                let q = unsafe { System.alloc(nl) };
                if !q.is_null() {
                    // SAFETY: both blocks are valid for the smaller size and distinct.
                    unsafe {
                        ptr::copy_nonoverlapping(p, q, l.size().min(new_size));
                        self.free(nn, l);
                    }
                }
                q
            }
            _ if rt => {
                // A system block on an RT thread: move it into the pool (the
                // system free is still a system call, and is counted).
                // SAFETY: the caller's contract.
                let q = unsafe { self.g_alloc(nl, false) };
                if !q.is_null() {
                    self.note_sys_on_rt();
                    // SAFETY: both valid for the smaller size, distinct; `p` is a system block.
                    unsafe {
                        ptr::copy_nonoverlapping(p, q, l.size().min(new_size));
                        System.dealloc(p, l);
                    }
                }
                q
            }
            // SAFETY: the caller's contract; `p` is a system block.
            _ => unsafe { System.realloc(p, l, new_size) },
        }
    }
}

impl Drop for Pool {
    fn drop(&mut self) {
        let (s, e) = (*self.start.get_mut(), *self.end.get_mut());
        if e > s {
            // SAFETY: our own mapping; with `&mut self` no pool block can be
            // freed into it any more (the process-wide pool is never dropped).
            unsafe { libc::munmap(s as *mut libc::c_void, e - s) };
        }
    }
}

static POOL: Pool = Pool::new();

/// The global allocator: system allocator for ordinary threads, the RT pool
/// for threads marked with [`enter_rt`].
#[derive(Debug, Clone, Copy, Default)]
pub struct RtAllocator;

// SAFETY: every block is served either by `System` or by the TLSF pool, and
// returned to the one that served it (exact address-range test); the pool's
// state is serialized by its flag; nothing here allocates or panics.
unsafe impl GlobalAlloc for RtAllocator {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        // SAFETY: forwarded contract.
        unsafe { POOL.g_alloc(l, false) }
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        // SAFETY: forwarded contract.
        unsafe { POOL.g_alloc(l, true) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: forwarded contract.
        unsafe { POOL.g_dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: forwarded contract.
        unsafe { POOL.g_realloc(p, l, new_size) }
    }
}

/// Why [`enter_rt`] failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum RtAllocError {
    /// The requested pool size is outside 64 KiB ..= 4 GiB.
    #[error("RT pool size {0} bytes: must be in 65536..=4294967296")]
    Size(usize),
    /// `mmap` failed (errno).
    #[error("RT pool: mmap failed (errno {0})")]
    Map(i32),
}

/// What [`enter_rt`] set up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PoolInfo {
    /// Pool size (bytes, rounded up to pages; the first caller's size).
    pub bytes: usize,
    /// Whether `mlock` succeeded on the pool.
    pub locked_in_ram: bool,
    /// Whether [`RtAllocator`] is this process's global allocator, i.e.
    /// whether this thread's allocations now really come from the pool
    /// (false in binaries that install another allocator, e.g. tests).
    pub installed: bool,
}

/// Counters of the allocator (process-wide).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AllocStats {
    /// System-allocator calls (alloc, free, realloc) made by RT threads after
    /// [`enter_rt`]. Must stay 0.
    pub system_calls_on_rt: u64,
    /// Pool allocations (a reallocation counts as one allocation and one free).
    pub pool_allocs: u64,
    /// Pool frees.
    pub pool_frees: u64,
    /// Frees that found the pool busy and were deferred.
    pub deferred_frees: u64,
    /// RT allocations the pool could not hold (served by the system allocator).
    pub exhausted_fallbacks: u64,
    /// RT allocations that found the pool busy (served by the system allocator).
    pub contended_fallbacks: u64,
    /// Pool size (bytes; 0 before [`enter_rt`]).
    pub pool_bytes: usize,
    /// Bytes in pool blocks now.
    pub pool_in_use_bytes: usize,
    /// Most bytes ever in pool blocks.
    pub pool_high_water_bytes: usize,
    /// Whether the pool is locked in RAM.
    pub pool_locked_in_ram: bool,
}

/// Marks the calling thread RT: from now on its allocations come from the
/// process's RT pool, which the first call reserves (`pool_bytes`, 64 KiB ..=
/// 4 GiB), prefaults and locks. Call once at the RT thread's start, before
/// its loop (this call itself may sleep and allocate). Resets this thread's
/// [`thread_system_calls`] counter.
pub fn enter_rt(pool_bytes: usize) -> Result<PoolInfo, RtAllocError> {
    let bytes = POOL.init(pool_bytes)?;
    let _ = THREAD_SYS.try_with(|c| c.set(0));
    let _ = IS_RT.try_with(|c| c.set(true));
    // Probe: does an allocation from this thread land in the pool?
    let probe = Box::new(0u64);
    let installed = POOL.contains((&*probe as *const u64).cast_mut().cast());
    drop(probe);
    Ok(PoolInfo {
        bytes,
        locked_in_ram: POOL.locked_in_ram.load(Ordering::Relaxed),
        installed,
    })
}

/// Unmarks the calling thread (its later allocations use the system
/// allocator; its pool blocks still return to the pool when freed).
pub fn leave_rt() {
    let _ = IS_RT.try_with(|c| c.set(false));
}

/// Whether the calling thread is marked RT.
pub fn is_rt_thread() -> bool {
    is_rt()
}

/// System-allocator calls the calling thread made since its [`enter_rt`].
pub fn thread_system_calls() -> u64 {
    THREAD_SYS.try_with(|c| c.get()).unwrap_or(0)
}

/// The process-wide counters.
pub fn stats() -> AllocStats {
    POOL.stats()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs `f` on a fresh thread marked RT (flag only: these tests drive
    /// their own pools directly, the lib's test binary keeps the system
    /// allocator).
    fn on_rt_thread<R: Send>(f: impl FnOnce() -> R + Send) -> R {
        std::thread::scope(|s| {
            s.spawn(|| {
                IS_RT.with(|c| c.set(true));
                let r = f();
                IS_RT.with(|c| c.set(false));
                r
            })
            .join()
            .unwrap()
        })
    }

    #[test]
    fn cross_thread_free_returns_to_the_pool() {
        let pool = Pool::new();
        pool.init(POOL_MIN).unwrap();
        let l = Layout::from_size_align(1000, 8).unwrap();
        // Fill the pool from an RT thread.
        let ptrs: Vec<usize> = on_rt_thread(|| {
            let mut v = vec![];
            loop {
                // SAFETY: valid layout.
                let p = unsafe { pool.g_alloc(l, true) };
                if !pool.contains(p) {
                    // SAFETY: a system block from the fallback.
                    unsafe { pool.g_dealloc(p, l) };
                    break;
                }
                v.push(p as usize);
            }
            v
        });
        assert!(ptrs.len() > 30, "{}", ptrs.len());
        let s = pool.stats();
        assert_eq!(s.exhausted_fallbacks, 1);
        assert_eq!(s.system_calls_on_rt, 2, "the fallback alloc and its free");
        // Free everything from this (non-RT) thread and from a second one at
        // once, contending for the flag.
        let (a, b) = ptrs.split_at(ptrs.len() / 2);
        std::thread::scope(|sc| {
            sc.spawn(|| {
                for &p in a {
                    // SAFETY: pool blocks allocated with `l`, freed once.
                    unsafe { pool.g_dealloc(p as *mut u8, l) };
                }
            });
            for &p in b {
                // SAFETY: as above.
                unsafe { pool.g_dealloc(p as *mut u8, l) };
            }
        });
        let s = pool.stats();
        assert_eq!(s.pool_in_use_bytes, 0);
        // Deferred frees are drained by the next holder; after it the whole
        // pool is usable again.
        let again: Vec<usize> = on_rt_thread(|| {
            (0..ptrs.len())
                // SAFETY: valid layout.
                .map(|_| unsafe { pool.g_alloc(l, false) } as usize)
                .collect()
        });
        assert!(again.iter().all(|&p| pool.contains(p as *mut u8)));
        let s = pool.stats();
        assert_eq!(s.exhausted_fallbacks, 1, "{s:?}");
        assert_eq!(s.pool_frees, ptrs.len() as u64 + 0, "{s:?}");
        assert_eq!(s.pool_high_water_bytes, ptrs.len() * 1000);
        for p in again {
            // SAFETY: pool blocks allocated with `l`.
            unsafe { pool.g_dealloc(p as *mut u8, l) };
        }
    }

    #[test]
    fn exhaustion_falls_back_and_is_counted() {
        let pool = Pool::new();
        pool.init(POOL_MIN).unwrap();
        let big = Layout::from_size_align(1 << 20, 16).unwrap();
        let small = Layout::from_size_align(24, 8).unwrap();
        on_rt_thread(|| {
            // SAFETY: valid layouts; every block freed once with its layout.
            unsafe {
                let p = pool.g_alloc(big, false);
                assert!(!p.is_null() && !pool.contains(p));
                p.write_bytes(7, big.size());
                pool.g_dealloc(p, big);
                let q = pool.g_alloc(small, false);
                assert!(pool.contains(q));
                // Growing past the pool moves the block to the system allocator.
                q.write_bytes(3, 24);
                let r = pool.g_realloc(q, small, big.size());
                assert!(!r.is_null() && !pool.contains(r));
                assert_eq!(*r.add(23), 3);
                pool.g_dealloc(r, big);
            }
        });
        let s = pool.stats();
        assert_eq!(s.exhausted_fallbacks, 2, "{s:?}");
        assert_eq!(s.system_calls_on_rt, 4, "{s:?}");
        assert_eq!(s.pool_in_use_bytes, 0);
    }

    #[test]
    fn ordinary_threads_use_the_system_allocator() {
        let pool = Pool::new();
        pool.init(POOL_MIN).unwrap();
        let l = Layout::from_size_align(64, 8).unwrap();
        // SAFETY: valid layout, freed once.
        unsafe {
            let p = pool.g_alloc(l, false);
            assert!(!pool.contains(p));
            pool.g_dealloc(p, l);
        }
        assert_eq!(
            pool.stats(),
            AllocStats {
                pool_bytes: POOL_MIN,
                pool_locked_in_ram: pool.stats().pool_locked_in_ram,
                ..AllocStats::default()
            }
        );
        assert_eq!(Pool::new().init(10), Err(RtAllocError::Size(10)));
    }
}
