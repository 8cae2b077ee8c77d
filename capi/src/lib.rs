//! The C ABI of the nvtmm haptic service: `nvtmm_start`, `nvtmm_snapshot`,
//! `nvtmm_frame_positions`, `nvtmm_instrument_count`,
//! `nvtmm_instrument_polyline`, `nvtmm_stop` (see `include/nvtmm.h`, which is
//! the contract). For engines that are not Rust (Unity, Unreal, Godot, C and
//! C++ hosts): the service runs on its own threads inside the host process;
//! the host polls snapshots at its frame rate and stops it when done.
//!
//! Every function catches panics (none crosses the boundary), checks its
//! pointers, and reports failures by a return value plus
//! `nvtmm_last_error()` (a message for the calling thread).
#![warn(missing_docs)]
#![warn(clippy::undocumented_unsafe_blocks)]

use nvtmm::service::{Handle, Service, StartOptions};
use std::cell::RefCell;
use std::ffi::{c_char, c_int, CStr, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;

/// The RT allocator, as in the `nvtmm` binary: a fixed pool for the RT
/// threads that also counts any system-allocator call they make.
#[global_allocator]
static ALLOCATOR: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_error(msg: impl Into<String>) {
    let s = msg.into().replace('\0', " ");
    LAST_ERROR.with(|e| *e.borrow_mut() = CString::new(s).unwrap_or_default());
}

/// An opaque running service.
pub struct NvtmmService {
    handle: Handle,
    /// The host's device port (`nvtmm_start_host`), None otherwise.
    host: Option<std::sync::Arc<nvtmm::haptics::host::HostPort>>,
}

/// Live figures (mirrors `nvtmm_snapshot` in `include/nvtmm.h`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct NvtmmSnapshot {
    /// Wall time since start (s).
    pub elapsed_s: f64,
    /// Loop ticks so far.
    pub ticks: u64,
    /// Deadline misses so far.
    pub deadline_misses: u64,
    /// Status bits of the last tick.
    pub flags: u32,
    /// Vertices of the latest state frame (0 before the first).
    pub frame_vertices: u32,
    /// Force commanded on the last tick (N).
    pub force_n: [f64; 3],
    /// Tool centre on the last tick (m).
    pub tool_m: [f64; 3],
    /// Largest force so far (N).
    pub max_force_n: f64,
    /// Full steps of the background solve so far.
    pub background_steps: u64,
    /// Simulated / wall time of the background solve.
    pub background_real_time_factor: f64,
    /// Loop time of the latest state frame (s).
    pub frame_time_s: f64,
}

/// # Safety
/// `p` is null or a valid NUL-terminated string.
unsafe fn opt_str(p: *const c_char) -> Result<Option<String>, String> {
    if p.is_null() {
        return Ok(None);
    }
    // SAFETY: the caller guarantees `p` points to a NUL-terminated string.
    let s = unsafe { CStr::from_ptr(p) };
    s.to_str()
        .map(|s| Some(s.to_string()))
        .map_err(|_| "string argument is not UTF-8".to_string())
}

/// Starts the service. `config_path`: a configuration file (NULL: the
/// default `rt-config/nvtmm.toml`); `config_toml`: configuration text
/// instead of a file (NULL: use `config_path`; relative paths in it resolve
/// against the directory of `config_path`, or the working directory);
/// `seconds` > 0 sets the simulated hand's script length. Returns NULL on
/// error (see `nvtmm_last_error`).
///
/// # Safety
/// The string arguments are NULL or valid NUL-terminated strings.
#[no_mangle]
pub unsafe extern "C" fn nvtmm_start(
    config_path: *const c_char,
    config_toml: *const c_char,
    seconds: f64,
) -> *mut NvtmmService {
    // SAFETY: forwarded from this function's contract.
    unsafe { start(config_path, config_toml, seconds, false) }
}

/// As `nvtmm_start`, with the host as the device: the configured backend is
/// replaced by poses the host pushes with `nvtmm_push_pose`; the force comes
/// back through `nvtmm_force`.
///
/// # Safety
/// As `nvtmm_start`.
#[no_mangle]
pub unsafe extern "C" fn nvtmm_start_host(
    config_path: *const c_char,
    config_toml: *const c_char,
    seconds: f64,
) -> *mut NvtmmService {
    // SAFETY: forwarded from this function's contract.
    unsafe { start(config_path, config_toml, seconds, true) }
}

/// # Safety
/// As `nvtmm_start`.
unsafe fn start(
    config_path: *const c_char,
    config_toml: *const c_char,
    seconds: f64,
    with_host: bool,
) -> *mut NvtmmService {
    // SAFETY: forwarded from this function's contract.
    let path = match unsafe { opt_str(config_path) } {
        Ok(p) => p.map(PathBuf::from),
        Err(e) => {
            set_error(format!("config_path: {e}"));
            return std::ptr::null_mut();
        }
    };
    // SAFETY: forwarded from this function's contract.
    let text = match unsafe { opt_str(config_toml) } {
        Ok(t) => t,
        Err(e) => {
            set_error(format!("config_toml: {e}"));
            return std::ptr::null_mut();
        }
    };
    let mut opts = match text {
        Some(t) => StartOptions::text(t, path.unwrap_or_else(|| PathBuf::from("inline.toml"))),
        None => StartOptions::file(path.unwrap_or_else(nvtmm::service::default_config)),
    };
    if seconds.is_finite() && seconds > 0.0 {
        opts.seconds = Some(seconds);
    }
    let host = if with_host {
        let (factory, port) = nvtmm::haptics::host::host_device();
        opts.device = Some(factory);
        Some(port)
    } else {
        None
    };
    match catch_unwind(AssertUnwindSafe(|| Service::start(opts))) {
        Ok(Ok(handle)) => Box::into_raw(Box::new(NvtmmService { handle, host })),
        Ok(Err(e)) => {
            set_error(e.to_string());
            std::ptr::null_mut()
        }
        Err(_) => {
            set_error("nvtmm_start panicked");
            std::ptr::null_mut()
        }
    }
}

/// Fills `out` with the live figures. Returns 0, or -1 on a null argument.
///
/// # Safety
/// `service` is NULL or a pointer `nvtmm_start` returned and `nvtmm_stop`
/// has not consumed; `out` is NULL or valid for writes.
#[no_mangle]
pub unsafe extern "C" fn nvtmm_snapshot(service: *const NvtmmService, out: *mut NvtmmSnapshot) -> c_int {
    if service.is_null() || out.is_null() {
        set_error("nvtmm_snapshot: null argument");
        return -1;
    }
    // SAFETY: non-null and, by the contract, a live service.
    let s = unsafe { &*service };
    let r = catch_unwind(AssertUnwindSafe(|| {
        let l = s.handle.snapshot();
        let (n, t) = l
            .frame
            .as_ref()
            .map(|f| (f.positions.len() as u32, f.time_s))
            .unwrap_or((0, 0.0));
        NvtmmSnapshot {
            elapsed_s: l.elapsed_s,
            ticks: l.ticks,
            deadline_misses: l.deadline_misses,
            flags: l.flags,
            frame_vertices: n,
            force_n: l.force_n,
            tool_m: l.tool_m,
            max_force_n: l.max_force_n,
            background_steps: l.background_steps,
            background_real_time_factor: l.background_real_time_factor,
            frame_time_s: t,
        }
    }));
    match r {
        Ok(snap) => {
            // SAFETY: non-null and valid for writes by the contract.
            unsafe { out.write(snap) };
            0
        }
        Err(_) => {
            set_error("nvtmm_snapshot panicked");
            -1
        }
    }
}

/// Copies the latest frame's vertex positions (m, x y z per vertex) into
/// `xyz` (room for `max_vertices` vertices). Returns the number of vertices
/// copied (0 before the first frame), or -1 on a null argument.
///
/// # Safety
/// `service` as for `nvtmm_snapshot`; `xyz` is valid for `3 * max_vertices`
/// floats.
#[no_mangle]
pub unsafe extern "C" fn nvtmm_frame_positions(
    service: *const NvtmmService,
    xyz: *mut f32,
    max_vertices: usize,
) -> i64 {
    if service.is_null() || (xyz.is_null() && max_vertices > 0) {
        set_error("nvtmm_frame_positions: null argument");
        return -1;
    }
    // SAFETY: non-null and, by the contract, a live service.
    let s = unsafe { &*service };
    let Ok(frame) = catch_unwind(AssertUnwindSafe(|| s.handle.snapshot().frame)) else {
        set_error("nvtmm_frame_positions panicked");
        return -1;
    };
    let Some(frame) = frame else { return 0 };
    // SAFETY: forwarded from this function's contract.
    unsafe { copy_points(&frame.positions, xyz, max_vertices) }
}

/// Copies at most `max` points into `xyz`; returns how many.
///
/// # Safety
/// `xyz` is valid for `3 * max` floats (or `max` is 0).
unsafe fn copy_points(points: &[[f32; 3]], xyz: *mut f32, max: usize) -> i64 {
    let n = points.len().min(max);
    if n > 0 {
        // SAFETY: `xyz` is valid for 3 * max floats and n <= max.
        let dst = unsafe { std::slice::from_raw_parts_mut(xyz, 3 * n) };
        for (k, p) in points.iter().take(n).enumerate() {
            dst[3 * k..3 * k + 3].copy_from_slice(p);
        }
    }
    n as i64
}

/// Copies the latest frame's surface triangles (3 vertex indices each,
/// into the positions of `nvtmm_frame_positions`, counter-clockwise seen
/// from outside the tissue) into `tri` (room for `max_triangles`). Returns
/// the number copied; with `tri` NULL and `max_triangles` 0, the number
/// there are. 0 before the first frame; -1 on a null service.
///
/// # Safety
/// `service` as for `nvtmm_snapshot`; `tri` is valid for
/// `3 * max_triangles` integers.
#[no_mangle]
pub unsafe extern "C" fn nvtmm_frame_triangles(
    service: *const NvtmmService,
    tri: *mut u32,
    max_triangles: usize,
) -> i64 {
    if service.is_null() || (tri.is_null() && max_triangles > 0) {
        set_error("nvtmm_frame_triangles: null argument");
        return -1;
    }
    // SAFETY: non-null and, by the contract, a live service.
    let s = unsafe { &*service };
    let Ok(frame) = catch_unwind(AssertUnwindSafe(|| s.handle.snapshot().frame)) else {
        set_error("nvtmm_frame_triangles panicked");
        return -1;
    };
    let Some(frame) = frame else { return 0 };
    if tri.is_null() {
        return frame.triangles.len() as i64;
    }
    let n = frame.triangles.len().min(max_triangles);
    // SAFETY: `tri` is valid for 3 * max_triangles integers and n <= max_triangles.
    let dst = unsafe { std::slice::from_raw_parts_mut(tri, 3 * n) };
    for (k, t) in frame.triangles.iter().take(n).enumerate() {
        dst[3 * k..3 * k + 3].copy_from_slice(t);
    }
    n as i64
}

/// Pushes the host's device pose (a service from `nvtmm_start_host`):
/// `position` (m, device frame, 3 doubles), `gimbal` (rad, 3 doubles, the
/// stylus roll last; NULL: zeros), `buttons` (bit 0 instrument switch, bit 1
/// contrast, bit 2 fluoroscopy). Call it each tick of the host's device
/// loop; the service takes the newest at its device rate, and a pose older
/// than `watchdog.device_timeout_ms` ramps the force to zero. Returns 0; -1
/// on a null argument or a service without a host device; -2 for a
/// non-finite number or a gimbal angle beyond ±2π; -3 when the pose ring
/// was full (the pose is dropped). Never blocks.
///
/// # Safety
/// `service` as for `nvtmm_snapshot`; `position` valid for 3 doubles;
/// `gimbal` NULL or valid for 3 doubles.
#[no_mangle]
pub unsafe extern "C" fn nvtmm_push_pose(
    service: *const NvtmmService,
    position: *const f64,
    gimbal: *const f64,
    buttons: u32,
) -> c_int {
    if service.is_null() || position.is_null() {
        set_error("nvtmm_push_pose: null argument");
        return -1;
    }
    // SAFETY: non-null and, by the contract, a live service.
    let s = unsafe { &*service };
    let Some(port) = s.host.as_ref() else {
        set_error("nvtmm_push_pose: the service was not started with nvtmm_start_host");
        return -1;
    };
    // SAFETY: valid for 3 doubles by the contract.
    let p = unsafe { std::slice::from_raw_parts(position, 3) };
    let g = if gimbal.is_null() {
        [0.0; 3]
    } else {
        // SAFETY: valid for 3 doubles by the contract.
        let g = unsafe { std::slice::from_raw_parts(gimbal, 3) };
        [g[0], g[1], g[2]]
    };
    let pose = nvtmm::haptics::host::HostPose {
        position: [p[0], p[1], p[2]],
        gimbal_rad: g,
        buttons,
    };
    match port.push_pose(&pose) {
        Ok(()) => 0,
        Err(e) => {
            set_error(format!("nvtmm_push_pose: {e}"));
            match e {
                nvtmm::haptics::host::PushError::Invalid => -2,
                nvtmm::haptics::host::PushError::Full => -3,
            }
        }
    }
}

/// The newest force the service commanded on the host's device (N, device
/// frame, into 3 doubles of `out`); zero before the first and once stopped.
/// Returns 0, or -1 on a null argument or a service without a host device.
///
/// # Safety
/// `service` as for `nvtmm_snapshot`; `out` valid for 3 doubles.
#[no_mangle]
pub unsafe extern "C" fn nvtmm_force(service: *const NvtmmService, out: *mut f64) -> c_int {
    if service.is_null() || out.is_null() {
        set_error("nvtmm_force: null argument");
        return -1;
    }
    // SAFETY: non-null and, by the contract, a live service.
    let s = unsafe { &*service };
    let Some(port) = s.host.as_ref() else {
        set_error("nvtmm_force: the service was not started with nvtmm_start_host");
        return -1;
    };
    let f = port.force();
    // SAFETY: valid for 3 doubles by the contract.
    unsafe { std::slice::from_raw_parts_mut(out, 3) }.copy_from_slice(&f);
    0
}

/// Stops the service and frees it. Returns the report as JSON (free it with
/// `nvtmm_string_free`), or NULL on error (the service is freed either way).
///
/// # Safety
/// `service` is NULL or a pointer `nvtmm_start` returned, not yet stopped;
/// it must not be used afterwards.
#[no_mangle]
pub unsafe extern "C" fn nvtmm_stop(service: *mut NvtmmService) -> *mut c_char {
    if service.is_null() {
        set_error("nvtmm_stop: null service");
        return std::ptr::null_mut();
    }
    // SAFETY: by the contract, a pointer from Box::into_raw in nvtmm_start,
    // consumed exactly once here.
    let s = unsafe { Box::from_raw(service) };
    let r = catch_unwind(AssertUnwindSafe(move || {
        s.handle
            .stop()
            .map_err(|e| e.to_string())
            .and_then(|rep| serde_json::to_string(&rep).map_err(|e| e.to_string()))
    }));
    match r {
        Ok(Ok(json)) => CString::new(json)
            .map(CString::into_raw)
            .unwrap_or(std::ptr::null_mut()),
        Ok(Err(e)) => {
            set_error(e);
            std::ptr::null_mut()
        }
        Err(_) => {
            set_error("nvtmm_stop panicked");
            std::ptr::null_mut()
        }
    }
}

/// Frees a string returned by `nvtmm_stop`.
///
/// # Safety
/// `s` is NULL or a string `nvtmm_stop` returned, freed once.
#[no_mangle]
pub unsafe extern "C" fn nvtmm_string_free(s: *mut c_char) {
    if !s.is_null() {
        // SAFETY: by the contract, from CString::into_raw in nvtmm_stop.
        drop(unsafe { CString::from_raw(s) });
    }
}

/// The last error message on the calling thread ("" if none). Valid until
/// the next nvtmm call on this thread.
#[no_mangle]
pub extern "C" fn nvtmm_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// The number of instruments in the latest frame (0 before the first), or
/// -1 on a null argument.
///
/// # Safety
/// `service` as for `nvtmm_snapshot`.
#[no_mangle]
pub unsafe extern "C" fn nvtmm_instrument_count(service: *const NvtmmService) -> i64 {
    if service.is_null() {
        set_error("nvtmm_instrument_count: null argument");
        return -1;
    }
    // SAFETY: non-null and, by the contract, a live service.
    let s = unsafe { &*service };
    match catch_unwind(AssertUnwindSafe(|| s.handle.snapshot().frame)) {
        Ok(frame) => frame.map_or(0, |f| f.instruments.len() as i64),
        Err(_) => {
            set_error("nvtmm_instrument_count panicked");
            -1
        }
    }
}

/// Copies instrument `index`'s polyline from the latest frame (m, x y z per
/// point, hub to tip) into `xyz` (room for `max_points` points) and its
/// kind code into `kind` (if not null). Returns the number of points
/// copied (with `xyz` null and `max_points` 0: the number there are), or
/// -1 on a null service or an index past the count.
///
/// # Safety
/// `service` as for `nvtmm_snapshot`; `xyz` is valid for `3 * max_points`
/// floats; `kind` is null or valid for a write.
#[no_mangle]
pub unsafe extern "C" fn nvtmm_instrument_polyline(
    service: *const NvtmmService,
    index: usize,
    kind: *mut u8,
    xyz: *mut f32,
    max_points: usize,
) -> i64 {
    if service.is_null() || (xyz.is_null() && max_points > 0) {
        set_error("nvtmm_instrument_polyline: null argument");
        return -1;
    }
    // SAFETY: non-null and, by the contract, a live service.
    let s = unsafe { &*service };
    let Ok(frame) = catch_unwind(AssertUnwindSafe(|| s.handle.snapshot().frame)) else {
        set_error("nvtmm_instrument_polyline panicked");
        return -1;
    };
    let Some(line) = frame.and_then(|f| f.instruments.into_iter().nth(index)) else {
        set_error(format!(
            "nvtmm_instrument_polyline: no instrument {index} in the latest frame"
        ));
        return -1;
    };
    if !kind.is_null() {
        // SAFETY: non-null and valid for a write by the contract.
        unsafe { kind.write(line.kind_code) };
    }
    if xyz.is_null() {
        return line.points.len() as i64;
    }
    // SAFETY: forwarded from this function's contract.
    unsafe { copy_points(&line.points, xyz, max_points) }
}
