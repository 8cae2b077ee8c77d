//! The OpenHaptics HD backend (cargo feature `openhaptics`): a hand-written
//! FFI to the vendor's HD library (`libHD.so`), driving the device from its
//! own servo callback.
//!
//! - `start`: `hdInitDevice(HD_DEFAULT_DEVICE)`, reads the nominal force
//!   limits, `hdEnable(HD_FORCE_OUTPUT)`, schedules the servo callback with
//!   `hdScheduleAsynchronous(.., HD_MAX_SCHEDULER_PRIORITY)` and
//!   `hdStartScheduler()`.
//! - The servo callback (the vendor's 1 kHz scheduler thread):
//!   `hdBeginFrame`, `hdGetDoublev(HD_CURRENT_POSITION)`,
//!   `hdGetDoublev(HD_CURRENT_VELOCITY)`,
//!   `hdGetDoublev(HD_CURRENT_GIMBAL_ANGLES)` (rad), `hdGetIntegerv(HD_CURRENT_BUTTONS)`,
//!   `hdSetDoublev(HD_CURRENT_FORCE)` with the force last written, or zero
//!   if that force is older than the command timeout (a stalled service must
//!   not leave a force playing), `hdEndFrame`, then `hdGetError`. It publishes the pose through a
//!   seqlock of atomics and reads the force from another; no locks, no
//!   allocation. A device error zeroes the commanded force and is reported by
//!   the next `read`; a device-class error (HD_DEVICE_FAULT, HD_COMM_ERROR, ...)
//!   also ends the callback (`HD_CALLBACK_DONE`), as the vendor examples do.
//! - `stop`: zero force, `hdStopScheduler`, `hdUnschedule`,
//!   `hdDisableDevice`.
//!
//! Units: the HD API works in mm, mm/s, rad and N; the conversion to SI
//! happens here and nowhere else ([`crate::haptics::frame::HD_LENGTH_M`]).
//! A sample with a gimbal angle beyond ±[`crate::haptics::device::GIMBAL_LIMIT_RAD`] is refused as
//! [`DeviceError::BadData`], like a non-finite one.
//!
//! Constants are those of OpenHaptics 3.0 `HD/hdDefines.h`, `HD/hdDevice.h`
//! and `HD/hdScheduler.h` as found in public copies of the SDK headers
//! (github.com/danepowell/openhaptics `usr/include/HD/`, identical values in
//! github.com/hhmai/PhantomAPI `include/HD/hdDefines.h`).
//!
//! Building on a box with the SDK: install OpenHaptics (and the device
//! driver) so that `libHD.so` is on the linker path (default `/usr/lib`; else
//! `RUSTFLAGS="-L /path/to/lib"`), then `cargo build --release --features
//! openhaptics`. Here, without the SDK, only `cargo check --features
//! openhaptics` works (nothing is linked).

use crate::haptics::device::{live_command, DeviceError, DeviceSample, HapticDevice};
use crate::haptics::frame::HD_LENGTH_M;
use crate::math::Vec3;
use std::ffi::{c_char, c_int, c_uint, c_ulong, c_ushort, c_void};
use std::sync::atomic::{fence, AtomicBool, AtomicU32, AtomicU64, Ordering};

/// HD device handle (`HHD`, unsigned int).
type Hhd = c_uint;
/// `HDenum`.
type HdEnum = c_uint;
/// `HDCallbackCode`.
type HdCallbackCode = c_uint;
/// `HDSchedulerHandle` (unsigned long).
type HdSchedulerHandle = c_ulong;

/// `HDErrorInfo` (hdDefines.h).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
struct HdErrorInfo {
    error_code: c_uint,
    internal_error_code: c_int,
    h_hd: Hhd,
}

// hdDefines.h (OpenHaptics 3.0).
const HD_SUCCESS: c_uint = 0x0000;
const HD_CURRENT_BUTTONS: HdEnum = 0x2000;
const HD_CURRENT_POSITION: HdEnum = 0x2050;
const HD_CURRENT_VELOCITY: HdEnum = 0x2051;
const HD_CURRENT_GIMBAL_ANGLES: HdEnum = 0x2150;
const HD_NOMINAL_MAX_FORCE: HdEnum = 0x2603;
const HD_NOMINAL_MAX_CONTINUOUS_FORCE: HdEnum = 0x2604;
const HD_CURRENT_FORCE: HdEnum = 0x2700;
const HD_FORCE_OUTPUT: HdEnum = 0x4000;
/// `USHRT_MAX`.
const HD_MAX_SCHEDULER_PRIORITY: c_ushort = c_ushort::MAX;
const HD_INVALID_HANDLE: Hhd = 0xFFFF_FFFF;
/// Force errors are 0x02xx (HD_WARM_MOTORS .. HD_FORCE_ERROR).
const HD_FORCE_ERRORS: std::ops::Range<c_uint> = 0x0200..0x0300;
/// Device errors are 0x03xx (HD_DEVICE_FAULT, HD_COMM_ERROR, ...).
const HD_DEVICE_ERRORS: std::ops::Range<c_uint> = 0x0300..0x0400;
const HD_COMM_ERROR: c_uint = 0x0302;
const HD_COMM_CONFIG_ERROR: c_uint = 0x0303;
// hdScheduler.h.
const HD_CALLBACK_DONE: HdCallbackCode = 0;
const HD_CALLBACK_CONTINUE: HdCallbackCode = 1;

/// `HDSchedulerCallback`; `HDCALLBACK` is empty (cdecl) on Linux.
type HdSchedulerCallback = unsafe extern "C" fn(user: *mut c_void) -> HdCallbackCode;

#[link(name = "HD")]
extern "C" {
    fn hdInitDevice(config_name: *const c_char) -> Hhd;
    fn hdDisableDevice(h: Hhd);
    fn hdMakeCurrentDevice(h: Hhd);
    fn hdBeginFrame(h: Hhd);
    fn hdEndFrame(h: Hhd);
    fn hdGetError() -> HdErrorInfo;
    fn hdEnable(cap: HdEnum);
    fn hdGetDoublev(pname: HdEnum, params: *mut f64);
    fn hdGetIntegerv(pname: HdEnum, params: *mut c_int);
    fn hdSetDoublev(pname: HdEnum, params: *const f64);
    fn hdStartScheduler();
    fn hdStopScheduler();
    fn hdScheduleAsynchronous(cb: HdSchedulerCallback, user: *mut c_void, priority: c_ushort) -> HdSchedulerHandle;
    fn hdUnschedule(h: HdSchedulerHandle);
}

/// Single-writer seqlock over `N` f64 values (stored as bits in atomics):
/// the writer never waits, readers retry while a write is in progress.
struct SeqLock<const N: usize> {
    seq: AtomicU64,
    vals: [AtomicU64; N],
}

impl<const N: usize> SeqLock<N> {
    fn new() -> Self {
        SeqLock {
            seq: AtomicU64::new(0),
            vals: std::array::from_fn(|_| AtomicU64::new(0)),
        }
    }

    /// Only one thread may write.
    fn write(&self, v: &[f64; N]) {
        let s = self.seq.load(Ordering::Relaxed);
        self.seq.store(s.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        for (a, x) in self.vals.iter().zip(v) {
            a.store(x.to_bits(), Ordering::Relaxed);
        }
        self.seq.store(s.wrapping_add(2), Ordering::Release);
    }

    /// A consistent snapshot and the number of writes so far; `None` if the
    /// writer kept interfering for `tries` attempts.
    fn read(&self, tries: usize) -> Option<([f64; N], u64)> {
        for _ in 0..tries {
            let s1 = self.seq.load(Ordering::Acquire);
            if s1 & 1 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let mut out = [0.0; N];
            for (o, a) in out.iter_mut().zip(&self.vals) {
                *o = f64::from_bits(a.load(Ordering::Relaxed));
            }
            fence(Ordering::Acquire);
            if self.seq.load(Ordering::Relaxed) == s1 {
                return Some((out, s1 / 2));
            }
        }
        None
    }
}

/// What the servo callback and the device I/O thread share (heap-pinned).
struct Shared {
    handle: AtomicU32,
    /// Pose: position (m) ×3, velocity (m/s) ×3, buttons, time (s), gimbal
    /// angles (rad) ×3.
    pose: SeqLock<11>,
    /// Force (N) ×3, then the time it was written (s, [`crate::rt::clock`]).
    force: SeqLock<4>,
    /// Last HD error code seen by the callback (0 = none).
    error: AtomicU32,
    running: AtomicBool,
    /// A force older than this (s) is no longer applied.
    command_timeout_s: f64,
}

/// The servo callback.
///
/// # Safety
/// `user` must point to a live [`Shared`] (guaranteed by [`OpenHapticsDevice`],
/// which unschedules the callback before dropping it).
unsafe extern "C" fn servo(user: *mut c_void) -> HdCallbackCode {
    // SAFETY: `user` is the `Shared` boxed by the device, alive until after
    // hdStopScheduler/hdUnschedule return.
    let sh = unsafe { &*(user as *const Shared) };
    let h = sh.handle.load(Ordering::Relaxed);
    let mut pos = [0.0f64; 3];
    let mut vel = [0.0f64; 3];
    let mut gimbal = [0.0f64; 3];
    let mut buttons: c_int = 0;
    // One clock read a frame: the commands' age and the pose's time (the
    // frame's state is sampled at hdBeginFrame, just after).
    let now = crate::rt::clock::now_s();
    let f = if sh.running.load(Ordering::Acquire) && sh.error.load(Ordering::Relaxed) == HD_SUCCESS {
        sh.force
            .read(4)
            .map_or([0.0; 3], |(f, _)| live_command(f, now, sh.command_timeout_s))
    } else {
        [0.0; 3]
    };
    // SAFETY: called on the HD scheduler thread with a device initialised by
    // `start`; the pointers are to live stack arrays of the sizes the HD API
    // writes/reads (3 doubles for position, velocity, gimbal angles and
    // force, 1 int for buttons).
    unsafe {
        hdBeginFrame(h);
        hdGetDoublev(HD_CURRENT_POSITION, pos.as_mut_ptr());
        hdGetDoublev(HD_CURRENT_VELOCITY, vel.as_mut_ptr());
        hdGetDoublev(HD_CURRENT_GIMBAL_ANGLES, gimbal.as_mut_ptr());
        hdGetIntegerv(HD_CURRENT_BUTTONS, &mut buttons);
        hdSetDoublev(HD_CURRENT_FORCE, f.as_ptr());
        hdEndFrame(h);
    }
    // SAFETY: plain call, no pointers.
    let err = unsafe { hdGetError() };
    let t = now;
    // mm -> m, mm/s -> m/s: the only unit conversion in the service (the
    // gimbal angles are already in rad).
    let mm = HD_LENGTH_M;
    sh.pose.write(&[
        pos[0] * mm,
        pos[1] * mm,
        pos[2] * mm,
        vel[0] * mm,
        vel[1] * mm,
        vel[2] * mm,
        buttons as u32 as f64,
        t,
        gimbal[0],
        gimbal[1],
        gimbal[2],
    ]);
    if err.error_code != HD_SUCCESS {
        sh.error.store(err.error_code, Ordering::Release);
        if HD_DEVICE_ERRORS.contains(&err.error_code) {
            return HD_CALLBACK_DONE;
        }
    }
    if sh.running.load(Ordering::Acquire) {
        HD_CALLBACK_CONTINUE
    } else {
        HD_CALLBACK_DONE
    }
}

fn to_device_error(code: c_uint) -> DeviceError {
    let c = code as i32;
    match code {
        HD_COMM_ERROR | HD_COMM_CONFIG_ERROR => DeviceError::Comm(c),
        _ if HD_FORCE_ERRORS.contains(&code) || HD_DEVICE_ERRORS.contains(&code) => DeviceError::Fault(c),
        _ => DeviceError::Comm(c),
    }
}

/// A Touch X (or any HD-API device) through OpenHaptics.
pub struct OpenHapticsDevice {
    shared: Box<Shared>,
    handle: Option<Hhd>,
    sched: Option<HdSchedulerHandle>,
    max_force_n: f64,
    max_continuous_force_n: f64,
    /// Reads that find no new servo frame before this age (s) are stale.
    max_age_s: f64,
}

impl OpenHapticsDevice {
    /// A device not yet opened; reads older than `max_age_s` are stale, and
    /// the servo callback stops applying a force written more than
    /// `command_timeout_s` ago.
    pub fn new(max_age_s: f64, command_timeout_s: f64) -> OpenHapticsDevice {
        OpenHapticsDevice {
            shared: Box::new(Shared {
                handle: AtomicU32::new(HD_INVALID_HANDLE),
                pose: SeqLock::new(),
                force: SeqLock::new(),
                error: AtomicU32::new(HD_SUCCESS),
                running: AtomicBool::new(false),
                command_timeout_s,
            }),
            handle: None,
            sched: None,
            max_force_n: 0.0,
            max_continuous_force_n: 0.0,
            max_age_s,
        }
    }

    /// The device's nominal peak and continuous force (N), read at start.
    pub fn nominal_forces(&self) -> (f64, f64) {
        (self.max_force_n, self.max_continuous_force_n)
    }
}

impl HapticDevice for OpenHapticsDevice {
    fn name(&self) -> &'static str {
        "openhaptics"
    }

    fn start(&mut self) -> Result<(), DeviceError> {
        if self.handle.is_some() {
            return Ok(());
        }
        crate::rt::clock::epoch();
        // SAFETY: HD_DEFAULT_DEVICE is NULL, which hdInitDevice accepts.
        let h = unsafe { hdInitDevice(std::ptr::null()) };
        // SAFETY: plain call.
        let e = unsafe { hdGetError() };
        if h == HD_INVALID_HANDLE || e.error_code != HD_SUCCESS {
            return Err(DeviceError::Start(e.error_code as i32));
        }
        let mut fmax = 0.0f64;
        let mut fcont = 0.0f64;
        // SAFETY: the device is initialised and current; each query writes
        // one double into a live local.
        unsafe {
            hdMakeCurrentDevice(h);
            hdGetDoublev(HD_NOMINAL_MAX_FORCE, &mut fmax);
            hdGetDoublev(HD_NOMINAL_MAX_CONTINUOUS_FORCE, &mut fcont);
        }
        self.max_force_n = if fmax.is_finite() && fmax > 0.0 { fmax } else { 0.0 };
        self.max_continuous_force_n = if fcont.is_finite() && fcont > 0.0 { fcont } else { 0.0 };
        self.shared.handle.store(h, Ordering::Relaxed);
        self.shared.force.write(&[0.0; 4]);
        self.shared.error.store(HD_SUCCESS, Ordering::Relaxed);
        self.shared.running.store(true, Ordering::Release);
        let user = &*self.shared as *const Shared as *mut c_void;
        // SAFETY: `user` points into `self.shared`, a Box that lives until
        // `stop` has stopped the scheduler and unscheduled the callback
        // (`Drop` calls `stop`). `servo` matches HDSchedulerCallback.
        let sched = unsafe {
            hdEnable(HD_FORCE_OUTPUT);
            let s = hdScheduleAsynchronous(servo, user, HD_MAX_SCHEDULER_PRIORITY);
            hdStartScheduler();
            s
        };
        self.handle = Some(h);
        self.sched = Some(sched);
        // SAFETY: plain call.
        let e = unsafe { hdGetError() };
        if e.error_code != HD_SUCCESS {
            self.stop();
            return Err(DeviceError::Start(e.error_code as i32));
        }
        Ok(())
    }

    fn read(&mut self, now_s: f64) -> Result<DeviceSample, DeviceError> {
        if self.handle.is_none() {
            return Err(DeviceError::Start(0));
        }
        let e = self.shared.error.load(Ordering::Acquire);
        if e != HD_SUCCESS {
            return Err(to_device_error(e));
        }
        let Some((v, frames)) = self.shared.pose.read(64) else {
            return Err(DeviceError::Stale);
        };
        if frames == 0 || now_s - v[7] > self.max_age_s {
            return Err(DeviceError::Stale);
        }
        let s = DeviceSample {
            position: Vec3::new(v[0], v[1], v[2]),
            velocity: Vec3::new(v[3], v[4], v[5]),
            buttons: v[6] as u32,
            time_s: v[7],
            seq: frames,
            gimbal_rad: [v[8], v[9], v[10]],
        };
        if !s.is_valid() {
            return Err(DeviceError::BadData);
        }
        Ok(s)
    }

    fn write_force(&mut self, force: Vec3) -> Result<Vec3, DeviceError> {
        if self.handle.is_none() {
            return Err(DeviceError::Start(0));
        }
        if !force.iter().all(|c| c.is_finite()) {
            self.shared.force.write(&[0.0; 4]);
            return Err(DeviceError::BadData);
        }
        let n = force.norm();
        let f = if self.max_force_n > 0.0 && n > self.max_force_n {
            force * (self.max_force_n / n)
        } else {
            force
        };
        self.shared.force.write(&[f.x, f.y, f.z, crate::rt::clock::now_s()]);
        Ok(f)
    }

    fn stop(&mut self) {
        self.shared.force.write(&[0.0; 4]);
        self.shared.running.store(false, Ordering::Release);
        if let Some(s) = self.sched.take() {
            // SAFETY: stops the scheduler thread (no more callbacks after it
            // returns) and removes our callback, so `shared` is no longer
            // referenced by the HD library.
            unsafe {
                hdStopScheduler();
                hdUnschedule(s);
            }
        }
        if let Some(h) = self.handle.take() {
            // SAFETY: `h` came from hdInitDevice and is disabled once.
            unsafe { hdDisableDevice(h) };
        }
    }
}

impl Drop for OpenHapticsDevice {
    fn drop(&mut self) {
        self.stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seqlock_returns_what_was_written() {
        let s = SeqLock::<3>::new();
        assert_eq!(s.read(1), Some(([0.0; 3], 0)));
        s.write(&[1.0, 2.0, 3.0]);
        assert_eq!(s.read(1), Some(([1.0, 2.0, 3.0], 1)));
        assert_eq!(to_device_error(HD_COMM_ERROR), DeviceError::Comm(0x302));
        assert_eq!(to_device_error(0x0201), DeviceError::Fault(0x201));
    }
}
