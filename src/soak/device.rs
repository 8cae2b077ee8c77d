//! The soak's device: the simulated Touch X behind the real UDP bridge on
//! loopback, in one thread, with device faults injected on a schedule and
//! every force the service commands checked as it is written.
//!
//! ```text
//! service ──read──▶ SoakDevice ──pose datagram──▶ UdpDevice (the bridge the
//!    ▲                 │  (sim advanced to now)      service would use)
//!    └──write_force────┘◀──force datagram── UdpDevice ◀── the service's force
//! ```
//!
//! Faults ([`DeviceFaultKind`]): silence (no datagram), a non-finite pose
//! (alternately through the bridge, which rejects it, and straight to the
//! service as a backend without checks would pass it), a wild pose (straight
//! to the service: beyond the reach, or a jump no hand makes), and garbage
//! datagrams beside the valid ones (short, long, bad magic, bad version,
//! random bytes, stale sequence numbers).
//!
//! Checks on every write ([`DeviceChecks`]): the force is finite, within the
//! device's peak force, zero within the allowed delay of a fault's onset and
//! until it ends; the true port energy (the simulator's sub-step velocity)
//! never exceeds the tank over any window. Allocates nothing after start.

use crate::haptics::device::{DeviceError, DeviceSample, HapticDevice, PortEnergy};
use crate::haptics::touchx::TouchXSim;
use crate::haptics::udp::{encode_pose_v2, PoseDatagram, UdpDevice, POSE_LEN_V2};
use crate::math::Vec3;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// A device fault the soak's device injects.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DeviceFaultKind {
    /// No pose datagram at all.
    Silence,
    /// A non-finite pose.
    NanPose,
    /// A pose beyond the reach or a jump faster than any hand.
    WildPose,
    /// Malformed datagrams beside the valid ones.
    GarbageDatagrams,
}

impl DeviceFaultKind {
    /// Every kind.
    pub const ALL: [DeviceFaultKind; 4] = [
        DeviceFaultKind::Silence,
        DeviceFaultKind::NanPose,
        DeviceFaultKind::WildPose,
        DeviceFaultKind::GarbageDatagrams,
    ];

    /// Whether the service must take the force to zero during the fault
    /// (garbage beside valid datagrams must change nothing).
    pub fn zeroes_force(self) -> bool {
        !matches!(self, DeviceFaultKind::GarbageDatagrams)
    }
}

/// One scheduled device fault, in seconds after the device's first read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceFault {
    /// What.
    pub kind: DeviceFaultKind,
    /// Onset (s after the first read).
    pub from_s: f64,
    /// End (s after the first read).
    pub until_s: f64,
}

/// Largest number of scheduled device faults.
pub const MAX_DEVICE_FAULTS: usize = 4096;

/// What the checks found; shared with the soak's controller (atomics,
/// written by the device thread only).
#[derive(Debug, Default)]
pub struct DeviceChecks {
    /// Device time origin: the service clock (ns bits of f64 s) at the first read.
    pub t0_s_bits: AtomicU64,
    /// Forces written.
    pub writes: AtomicU64,
    /// Non-finite forces written.
    pub nonfinite_forces: AtomicU64,
    /// Forces above the device's peak force.
    pub force_limit_violations: AtomicU64,
    /// Largest force norm written (N, f64 bits).
    pub max_force_bits: AtomicU64,
    /// Writes where the energy delivered over some window exceeded the tank.
    pub energy_violations: AtomicU64,
    /// Largest net energy delivered over any window (J, f64 bits).
    pub max_window_energy_bits: AtomicU64,
    /// Where that window starts and ends (s from the device's first read,
    /// f64 bits).
    pub max_window_from_bits: AtomicU64,
    /// See `max_window_from_bits`.
    pub max_window_to_bits: AtomicU64,
    /// Non-zero forces written later than the allowed delay into a fault.
    pub zero_violations: AtomicU64,
    /// Faults started, per [`DeviceFaultKind::ALL`] index.
    pub started: [AtomicU64; 4],
    /// Faults whose force went (or stayed) to zero in time, per kind.
    pub zeroed: [AtomicU64; 4],
    /// Longest time from a fault's onset to a zero force that then held (ms, f64 bits), per kind.
    pub max_time_to_zero_bits: [AtomicU64; 4],
    /// Garbage datagrams sent.
    pub garbage_sent: AtomicU64,
    /// Garbage datagrams the bridge rejected (read at the end).
    pub garbage_rejected: AtomicU64,
    /// When the device thread's last pause ended (s from the first read,
    /// f64 bits; 0: none yet): the latest gap between two reads longer
    /// than [`CheckLimits::pause_s`], which the service rightly takes for a
    /// silent device (the machine did not run the thread, not a fault
    /// the soak injected).
    pub pause_end_s_bits: AtomicU64,
    /// That pause's length (s, f64 bits).
    pub pause_len_s_bits: AtomicU64,
}

fn f64_of(a: &AtomicU64) -> f64 {
    f64::from_bits(a.load(Ordering::Relaxed))
}

fn store_max(a: &AtomicU64, v: f64) {
    if v > f64_of(a) {
        a.store(v.to_bits(), Ordering::Relaxed);
    }
}

impl DeviceChecks {
    /// The device time origin (s on the service clock), None before the first read.
    pub fn t0_s(&self) -> Option<f64> {
        let b = self.t0_s_bits.load(Ordering::Relaxed);
        (b != 0).then(|| f64::from_bits(b))
    }

    /// The device thread's latest pause: (its end in s from the first
    /// read, its length in s), None if it never paused.
    pub fn last_pause(&self) -> Option<(f64, f64)> {
        let end = f64_of(&self.pause_end_s_bits);
        (end > 0.0).then(|| (end, f64_of(&self.pause_len_s_bits)))
    }

    /// Largest force written (N).
    pub fn max_force_n(&self) -> f64 {
        f64_of(&self.max_force_bits)
    }

    /// Largest net energy over a window (J).
    pub fn max_window_energy_j(&self) -> f64 {
        f64_of(&self.max_window_energy_bits)
    }

    /// Where the window of [`DeviceChecks::max_window_energy_j`] starts
    /// and ends (s from the device's first read).
    pub fn max_window_span_s(&self) -> (f64, f64) {
        (f64_of(&self.max_window_from_bits), f64_of(&self.max_window_to_bits))
    }

    /// Longest onset-to-zero time of a kind (ms).
    pub fn max_time_to_zero_ms(&self, kind: usize) -> f64 {
        f64_of(&self.max_time_to_zero_bits[kind])
    }
}

/// Limits the checks hold the service to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CheckLimits {
    /// The device's peak force (N).
    pub peak_force_n: f64,
    /// Net energy the service may deliver from start (J): the initial tank.
    pub tank_initial_j: f64,
    /// Net energy the service may deliver over any window (J): the tank's capacity.
    pub tank_max_j: f64,
    /// Allowed onset-to-zero delay of the force on a device fault that stops
    /// the data (s): 10 ms.
    pub zero_delay_s: f64,
    /// A gap between two of the device thread's reads longer than this is
    /// a pause of the thread (s): the watchdog's device timeout less one
    /// read period, past which the freshest sample may be too old.
    pub pause_s: f64,
}

/// The soak's instrumented device.
pub struct SoakDevice {
    sim: TouchXSim,
    udp: UdpDevice,
    peer: Option<UdpSocket>,
    to: Option<SocketAddr>,
    faults: Vec<DeviceFault>,
    next_fault: usize,
    active: Option<(DeviceFault, f64, Option<f64>, bool)>,
    checks: Arc<DeviceChecks>,
    limits: CheckLimits,
    t0: Option<f64>,
    now: f64,
    seq: u64,
    nan_direct: bool,
    /// Injected clock leaps seen at the last read.
    jumps_seen: u64,
    wild_far: bool,
    rng: u64,
    buf: [u8; 256],
    min_net_j: f64,
    /// When `min_net_j` was reached (s from the first read).
    min_net_at_s: f64,
    last_good: DeviceSample,
}

impl std::fmt::Debug for SoakDevice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SoakDevice")
            .field("faults", &self.faults.len())
            .finish()
    }
}

impl SoakDevice {
    /// The simulated Touch X `sim` behind a loopback bridge `udp` (bound at
    /// start), the device `faults` (sorted by onset, at most
    /// [`MAX_DEVICE_FAULTS`]), the limits and the shared check results.
    pub fn new(
        sim: TouchXSim,
        udp: UdpDevice,
        mut faults: Vec<DeviceFault>,
        limits: CheckLimits,
        checks: Arc<DeviceChecks>,
        seed: u64,
    ) -> SoakDevice {
        faults.sort_by(|a, b| a.from_s.total_cmp(&b.from_s));
        faults.truncate(MAX_DEVICE_FAULTS);
        SoakDevice {
            sim,
            udp,
            peer: None,
            to: None,
            faults,
            next_fault: 0,
            active: None,
            checks,
            limits,
            t0: None,
            now: 0.0,
            jumps_seen: crate::rt::clock::injected_jumps(),
            seq: 0,
            nan_direct: false,
            wild_far: false,
            rng: seed | 1,
            buf: [0; 256],
            min_net_j: 0.0,
            min_net_at_s: 0.0,
            last_good: DeviceSample::REST,
        }
    }

    fn rand(&mut self) -> u64 {
        // xorshift64*: no allocation, reproducible from the seed.
        let mut x = self.rng;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.rng = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn kind_index(k: DeviceFaultKind) -> usize {
        DeviceFaultKind::ALL.iter().position(|&x| x == k).unwrap_or(0)
    }

    /// Starts and ends faults at device time `t` (s after the first read).
    fn update_faults(&mut self, t: f64) {
        if let Some((f, _, _, _)) = self.active {
            // The checks run until the fault ends, and at least until the
            // force had to be zero.
            if t >= f.until_s.max(f.from_s + self.limits.zero_delay_s + 0.002) {
                self.end_fault();
            }
        }
        if self.active.is_none() {
            while let Some(f) = self.faults.get(self.next_fault).copied() {
                if f.from_s > t {
                    break;
                }
                self.next_fault += 1;
                if f.until_s > t {
                    let k = Self::kind_index(f.kind);
                    self.checks.started[k].fetch_add(1, Ordering::Relaxed);
                    // Onset on the service clock, as the checks' `now`.
                    self.active = Some((f, self.now, None, false));
                    if f.kind == DeviceFaultKind::NanPose {
                        self.nan_direct = !self.nan_direct;
                    }
                    if f.kind == DeviceFaultKind::WildPose {
                        self.wild_far = !self.wild_far;
                    }
                    break;
                }
            }
        }
    }

    /// Closes the active fault: was its force zero in time and did it stay so?
    fn end_fault(&mut self) {
        if let Some((f, onset, zero_since, violated)) = self.active.take() {
            let k = Self::kind_index(f.kind);
            if !f.kind.zeroes_force() {
                if !violated {
                    self.checks.zeroed[k].fetch_add(1, Ordering::Relaxed);
                }
                return;
            }
            if let Some(z) = zero_since {
                store_max(&self.checks.max_time_to_zero_bits[k], (z - onset).max(0.0) * 1e3);
            }
            if !violated && zero_since.is_some() {
                self.checks.zeroed[k].fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// Sends the pose (and garbage) datagrams of this read.
    fn send_poses(&mut self, s: &DeviceSample, nan: bool, garbage: bool) {
        let (Some(peer), Some(to)) = (self.peer.take(), self.to) else {
            return;
        };
        self.seq += 1;
        let mut d = PoseDatagram {
            seq: self.seq,
            device_time_s: s.time_s,
            position: [s.position.x, s.position.y, s.position.z],
            velocity: [s.velocity.x, s.velocity.y, s.velocity.z],
            buttons: s.buttons,
            status: 0,
            error_code: 0,
            gimbal_rad: s.gimbal_rad,
        };
        // Every other non-finite pose has its roll, not its position, NaN
        // (the bridge must reject either).
        if nan && self.seq % 2 == 0 {
            d.position[0] = f64::NAN;
        } else if nan {
            d.gimbal_rad[2] = f64::NAN;
        }
        // Version 2: the gimbal angles ride along (a guidewire's roll).
        let valid = encode_pose_v2(&d);
        if garbage {
            let n = 1 + (self.rand() % 4) as usize;
            for _ in 0..n {
                let kind = self.rand() % 6;
                let len = match kind {
                    0 => (self.rand() % POSE_LEN_V2 as u64) as usize,
                    1 => POSE_LEN_V2 + 1 + (self.rand() % 100) as usize,
                    _ => POSE_LEN_V2,
                };
                let mut b = [0u8; 256];
                b[..POSE_LEN_V2].copy_from_slice(&valid);
                match kind {
                    2 => b[0] ^= 0x5A,
                    3 => b[4] = 9,
                    4 => {
                        for x in b.iter_mut().take(len) {
                            *x = self.rng as u8;
                            self.rng = self.rng.rotate_left(7) ^ 0x9E37_79B9_7F4A_7C15;
                        }
                        b[0] = b'X';
                    }
                    5 => {
                        // A replayed (older) sequence number.
                        let old = PoseDatagram {
                            seq: self.seq.saturating_sub(1 + self.rand() % 50),
                            ..d
                        };
                        b[..POSE_LEN_V2].copy_from_slice(&encode_pose_v2(&old));
                    }
                    _ => {}
                }
                if peer.send_to(&b[..len], to).is_ok() {
                    self.checks.garbage_sent.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        let _ = peer.send_to(&valid, to);
        self.peer = Some(peer);
    }

    /// Applies the force datagrams the bridge sent to the simulated device.
    fn drain_forces(&mut self) {
        let Some(peer) = self.peer.as_ref() else {
            return;
        };
        let mut newest = None;
        while let Ok((len, _)) = peer.recv_from(&mut self.buf) {
            if let Ok(d) = crate::haptics::udp::decode_force(&self.buf[..len]) {
                newest = Some(Vec3::new(d.force[0], d.force[1], d.force[2]));
            }
        }
        if let Some(f) = newest {
            let _ = self.sim.write_force(f);
        }
    }

    /// The checks on one commanded force.
    fn check(&mut self, force: Vec3) {
        let c = &self.checks;
        c.writes.fetch_add(1, Ordering::Relaxed);
        let n = force.norm();
        if !n.is_finite() {
            c.nonfinite_forces.fetch_add(1, Ordering::Relaxed);
        } else {
            store_max(&c.max_force_bits, n);
            if n > self.limits.peak_force_n * (1.0 + 1e-9) {
                c.force_limit_violations.fetch_add(1, Ordering::Relaxed);
            }
        }
        if let Some(e) = self.sim.port_energy() {
            let net = e.net_delivered_j();
            let t = self.now - self.t0.unwrap_or(self.now);
            if net < self.min_net_j {
                self.min_net_j = net;
                self.min_net_at_s = t;
            }
            let window = net - self.min_net_j;
            // The net from the start counts as a window from the start.
            let (worst, from) = if net >= window {
                (net, 0.0)
            } else {
                (window, self.min_net_at_s)
            };
            if worst > c.max_window_energy_j() {
                c.max_window_energy_bits.store(worst.to_bits(), Ordering::Relaxed);
                c.max_window_from_bits.store(from.to_bits(), Ordering::Relaxed);
                c.max_window_to_bits.store(t.to_bits(), Ordering::Relaxed);
            }
            if net > self.limits.tank_initial_j + 1e-9 || window > self.limits.tank_max_j + 1e-9 {
                c.energy_violations.fetch_add(1, Ordering::Relaxed);
            }
        }
        let now = self.now;
        let limits = self.limits;
        if let Some((f, onset, zero_since, violated)) = self.active.as_mut() {
            if f.kind.zeroes_force() {
                let allowed = limits.zero_delay_s;
                let zero = n.is_finite() && n <= 1e-9;
                if zero {
                    if zero_since.is_none() {
                        *zero_since = Some(now);
                    }
                } else {
                    *zero_since = None;
                    if now - *onset > allowed && !*violated {
                        *violated = true;
                        c.zero_violations.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
        }
    }
}

impl HapticDevice for SoakDevice {
    fn name(&self) -> &'static str {
        "soak (touchx-sim over udp)"
    }

    fn start(&mut self) -> Result<(), DeviceError> {
        self.sim.start()?;
        self.udp.start()?;
        let to = self.udp.local_addr().ok_or(DeviceError::Start(0))?;
        let peer = UdpSocket::bind("127.0.0.1:0").map_err(|e| DeviceError::Start(e.raw_os_error().unwrap_or(-1)))?;
        peer.set_nonblocking(true)
            .map_err(|e| DeviceError::Start(e.raw_os_error().unwrap_or(-1)))?;
        self.peer = Some(peer);
        self.to = Some(to);
        Ok(())
    }

    fn read(&mut self, now_s: f64) -> Result<DeviceSample, DeviceError> {
        let t0 = *self.t0.get_or_insert_with(|| {
            self.checks.t0_s_bits.store(now_s.to_bits(), Ordering::Relaxed);
            now_s
        });
        // An injected clock leap (the soak's `clock_jump`) is not a pause.
        let jumps = crate::rt::clock::injected_jumps();
        let leapt = jumps != self.jumps_seen;
        self.jumps_seen = jumps;
        let gap = now_s - self.now;
        if self.now > 0.0 && gap > self.limits.pause_s && !leapt {
            self.checks.pause_len_s_bits.store(gap.to_bits(), Ordering::Relaxed);
            self.checks
                .pause_end_s_bits
                .store((now_s - t0).to_bits(), Ordering::Relaxed);
        }
        self.now = now_s;
        self.update_faults(now_s - t0);
        // The hand and the stylus move on whatever the link does.
        let s = self.sim.read(now_s)?;
        // Inject only until the fault's end (the checks may run on a little).
        let t = now_s - t0;
        let kind = self.active.and_then(|(f, _, _, _)| (t < f.until_s).then_some(f.kind));
        match kind {
            Some(DeviceFaultKind::Silence) => {
                let _ = self.udp.read(now_s);
                Err(DeviceError::Stale)
            }
            Some(DeviceFaultKind::NanPose) if self.nan_direct => {
                self.send_poses(&s, true, false);
                let _ = self.udp.read(now_s);
                Ok(DeviceSample {
                    position: Vec3::new(f64::NAN, s.position.y, s.position.z),
                    ..s
                })
            }
            Some(DeviceFaultKind::WildPose) => {
                let _ = self.udp.read(now_s);
                let off = if self.wild_far {
                    Vec3::new(0.0, 0.0, 1.0)
                } else {
                    Vec3::new(0.05, 0.0, 0.0)
                };
                Ok(DeviceSample {
                    position: self.last_good.position + off,
                    seq: s.seq,
                    ..s
                })
            }
            _ => {
                let nan = kind == Some(DeviceFaultKind::NanPose);
                let garbage = kind == Some(DeviceFaultKind::GarbageDatagrams);
                self.send_poses(&s, nan, garbage);
                let r = self.udp.read(now_s);
                if let Ok(g) = r {
                    self.last_good = g;
                }
                r
            }
        }
    }

    fn write_force(&mut self, force: Vec3) -> Result<Vec3, DeviceError> {
        self.check(force);
        let r = self.udp.write_force(force);
        self.drain_forces();
        r
    }

    fn stop(&mut self) {
        self.end_fault();
        let c = self.udp.counters();
        let rejected = c.short + c.long + c.bad_magic + c.bad_version + c.out_of_order;
        self.checks.garbage_rejected.store(rejected, Ordering::Relaxed);
        self.udp.stop();
        self.sim.stop();
    }

    fn port_energy(&self) -> Option<PortEnergy> {
        self.sim.port_energy()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::haptics::touchx::{GimbalWaypoint, TouchXParams, Waypoint};
    use crate::haptics::udp::UdpParams;

    /// The stylus roll the simulated hand scripts reaches the service
    /// through the bridge (version-2 pose datagrams carry the gimbal): a
    /// guidewire scene's soak rolls the wire.
    #[test]
    fn the_gimbal_angles_pass_through_the_bridge() {
        let pts = [
            Waypoint {
                t_s: 0.0,
                position: Vec3::zeros(),
            },
            Waypoint {
                t_s: 10.0,
                position: Vec3::zeros(),
            },
        ];
        let mut sim = TouchXSim::new(TouchXParams::default(), &pts).unwrap();
        sim.set_gimbal_script(&[
            GimbalWaypoint {
                t_s: 0.0,
                angles_rad: [0.0, 0.0, 1.0],
            },
            GimbalWaypoint {
                t_s: 10.0,
                angles_rad: [0.0, 0.0, 1.0],
            },
        ])
        .unwrap();
        let udp = UdpDevice::new(UdpParams {
            bind: "127.0.0.1:0".into(),
            peer: String::new(),
            max_age_s: 0.5,
            ..UdpParams::default()
        });
        let limits = CheckLimits {
            peak_force_n: 7.9,
            tank_initial_j: 0.01,
            tank_max_j: 0.05,
            zero_delay_s: 0.01,
            pause_s: 0.004,
        };
        let mut dev = SoakDevice::new(sim, udp, Vec::new(), limits, Arc::new(DeviceChecks::default()), 1);
        dev.start().unwrap();
        let mut roll = None;
        for k in 0..2000 {
            if let Ok(s) = dev.read(k as f64 * 1e-3) {
                roll = Some(s.gimbal_rad[2]);
                break;
            }
            std::thread::sleep(std::time::Duration::from_micros(200));
        }
        let roll = roll.expect("no pose came through the bridge");
        assert!((roll - 1.0).abs() < 0.01, "roll {roll}");
    }
}
