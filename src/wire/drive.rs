//! The hub drive: how the stylus drives the guidewire's hub, and what the
//! hand feels back. The surgeon moves a wire by two hub motions, insertion
//! (push and pull along the wire) and roll; the stylus gives both:
//!
//! - **Insertion.** The stylus position `p` (device frame, m) projected on
//!   the configured axis `a` through `origin_m`:
//!   `target = inserted_at_origin_m + insertion_scale · (p − origin)·a`,
//!   clamped to [0, the most the wire can insert]; the command follows the
//!   target at most `max_speed_m_s` (never faster than the wire feeds).
//! - **Roll.** The stylus roll (gimbal angle `roll_index`, reported in
//!   (−π, π] or any range within one turn of it) is unwrapped: each
//!   sample adds the change since the last one, wrapped to (−π, π], so the
//!   roll is continuous across ±π and counts whole turns. The wire's roll is
//!   `roll_scale ·` the unwrapped stylus roll since the first sample,
//!   followed at most `max_roll_speed_rad_s`.
//! - **Force.** The hand feels the wire's axial resistance along the axis,
//!   `−force_scale · F_axial · a` (`F_axial` > 0 resists insertion), plus a
//!   virtual guide, a spring–damper toward the axis line
//!   `−k (d − (d·a) a) − c (v − (v·a) a)`, `d = p − origin`; the sum is
//!   clamped to `max_force_n`. In the device frame, newtons: what the
//!   device is commanded (after the passivity filter).
//!
//! An unusable sample (non-finite, or a gimbal angle out of range:
//! [`DeviceSample::is_valid`]) is a device fault: the commands hold and the
//! force is zero. Everything is plain data sized at construction:
//! [`HubDrive::command`] and [`HubDrive::hand_force`] allocate nothing, take
//! no lock and cannot panic.
//!
//! Energy: the hand moves the hub `insertion_scale` metres per metre, so a
//! hub force F does `insertion_scale · F` of work per metre of stylus travel;
//! feeding back `force_scale · F` with `force_scale ≤ insertion_scale` (a
//! checked bound) gives the hand no more than the wire gave.

use super::WireParams;
use crate::config::{Checker, ConfigError};
use crate::haptics::device::{wrap_angle, DeviceSample};
use crate::math::Vec3;
use std::path::Path;

/// Longest time step (s) the rate limits credit at once: after a gap (a
/// silent device, a paused loop) the commands do not leap.
pub const MAX_DT_S: f64 = 0.01;

/// The hub drive's keys (a `[drive]` table inside the wire's, e.g.
/// `[wire.drive]`). Device frame, SI units. [`Default`] suits a Touch X with
/// the OpenHaptics axes: push the stylus away from you (−z) to insert.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct DriveParams {
    /// Insertion axis in the device frame (normalised): moving the stylus
    /// along it inserts the wire.
    pub axis: [f64; 3],
    /// A device point (m) on the axis: the guide holds the stylus on the
    /// line through it along `axis`.
    pub origin_m: [f64; 3],
    /// Inserted length (m) with the stylus at `origin_m` (before the clamp
    /// to what the wire can insert).
    pub inserted_at_origin_m: f64,
    /// Metres of wire inserted per metre of stylus travel along the axis.
    pub insertion_scale: f64,
    /// Fastest insertion or withdrawal (m/s) the command follows; the
    /// wire's feed limit ([`WireParams::max_feed_speed_m_s`]) caps it too.
    pub max_speed_m_s: f64,
    /// Which gimbal angle is the roll (0, 1, 2; OpenHaptics: 2).
    pub roll_index: usize,
    /// Wire roll per stylus roll (negative reverses the sense; 0 holds it).
    pub roll_scale: f64,
    /// Fastest roll (rad/s) the command follows.
    pub max_roll_speed_rad_s: f64,
    /// Hand force per newton of the wire's axial hub force (at most
    /// `insertion_scale`: the map then adds no energy).
    pub force_scale: f64,
    /// Stiffness of the virtual guide toward the axis (N/m).
    pub guide_stiffness_n_per_m: f64,
    /// Damping of the virtual guide across the axis (N·s/m).
    pub guide_damping_ns_per_m: f64,
    /// Clamp on the norm of the force the drive asks for (N).
    pub max_force_n: f64,
}

impl Default for DriveParams {
    fn default() -> Self {
        DriveParams {
            axis: [0.0, 0.0, -1.0],
            origin_m: [0.0; 3],
            inserted_at_origin_m: 0.18,
            insertion_scale: 3.0,
            max_speed_m_s: 0.1,
            roll_index: 2,
            roll_scale: 1.0,
            max_roll_speed_rad_s: 10.0,
            force_scale: 1.0,
            guide_stiffness_n_per_m: 200.0,
            guide_damping_ns_per_m: 1.0,
            max_force_n: 3.0,
        }
    }
}

impl DriveParams {
    /// The stylus point (device frame, m) on the axis that asks for
    /// `inserted_m` of wire: the inverse of [`HubDrive::target`] (a
    /// scripted hand's way to the hub).
    pub fn stylus_at(&self, inserted_m: f64) -> Vec3 {
        let a = Vec3::from(self.axis).normalize();
        Vec3::from(self.origin_m) + a * ((inserted_m - self.inserted_at_origin_m) / self.insertion_scale)
    }

    /// The gimbal angles (rad) that roll the wire by `roll_rad`: the roll
    /// joint's angle divided by `roll_scale`, the others zero (all zero if
    /// the roll is held, `roll_scale` = 0).
    pub fn gimbal_for(&self, roll_rad: f64) -> [f64; 3] {
        let mut angles = [0.0; 3];
        if self.roll_scale != 0.0 {
            angles[self.roll_index.min(2)] = roll_rad / self.roll_scale;
        }
        angles
    }

    /// Range checks. `prefix` is prepended to key names (e.g. `drive.`).
    /// The wire's own limits (its length, its feed speed) are applied when
    /// driving, not here: a drive table stays valid for any wire.
    pub fn validate(&self, path: &Path, prefix: &str) -> Result<(), ConfigError> {
        let c = Checker::new(path);
        let k = |s: &str| format!("{prefix}{s}");
        for (i, a) in self.axis.iter().enumerate() {
            c.f64_in(&k(&format!("axis[{i}]")), *a, -1e3, 1e3, "")?;
        }
        let n = Vec3::from(self.axis).norm();
        if n.is_nan() || n < 1e-6 {
            return Err(c.err(
                &k("axis"),
                format!("{:?}: must be a non-zero vector (norm ≥ 1e-6)", self.axis),
            ));
        }
        for (i, o) in self.origin_m.iter().enumerate() {
            c.f64_in(&k(&format!("origin_m[{i}]")), *o, -2.0, 2.0, "m")?;
        }
        c.f64_in(&k("inserted_at_origin_m"), self.inserted_at_origin_m, 0.0, 10.0, "m")?;
        c.f64_in(&k("insertion_scale"), self.insertion_scale, 0.1, 100.0, "")?;
        c.f64_in(&k("max_speed_m_s"), self.max_speed_m_s, 1e-3, 10.0, "m/s")?;
        c.int_in(&k("roll_index"), self.roll_index, 0, 2)?;
        c.f64_in(&k("roll_scale"), self.roll_scale, -10.0, 10.0, "")?;
        c.f64_in(
            &k("max_roll_speed_rad_s"),
            self.max_roll_speed_rad_s,
            0.01,
            1000.0,
            "rad/s",
        )?;
        c.f64_in(
            &k("force_scale"),
            self.force_scale,
            0.0,
            self.insertion_scale,
            "(≤ insertion_scale, so the map adds no energy)",
        )?;
        c.f64_in(
            &k("guide_stiffness_n_per_m"),
            self.guide_stiffness_n_per_m,
            0.0,
            5000.0,
            "N/m",
        )?;
        c.f64_in(
            &k("guide_damping_ns_per_m"),
            self.guide_damping_ns_per_m,
            0.0,
            20.0,
            "N·s/m",
        )?;
        c.f64_in(&k("max_force_n"), self.max_force_n, 0.0, 100.0, "N")?;
        Ok(())
    }
}

/// What the drive asks of the wire this tick.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HubCommand {
    /// Inserted length (m) for [`super::Wire::set_hub`].
    pub inserted_m: f64,
    /// Hub roll (rad) for [`super::Wire::set_hub`].
    pub roll_rad: f64,
    /// Where the stylus asks the insertion to be (m), before clamping.
    pub target_m: f64,
    /// The target was outside [0, the most the wire inserts] and clamped.
    pub clamped: bool,
    /// The insertion or the roll was held back by its rate limit.
    pub rate_limited: bool,
    /// The sample was unusable: the commands held.
    pub fault: bool,
    /// Distance (m) of the stylus from the axis line.
    pub off_axis_m: f64,
}

/// What the drive counted (plain fields, read after the fact).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DriveCounters {
    /// Samples taken.
    pub samples: u64,
    /// Unusable samples (non-finite, gimbal out of range).
    pub faults: u64,
    /// Ticks whose target was clamped.
    pub clamped: u64,
    /// Ticks held back by a rate limit.
    pub rate_limited: u64,
    /// Hand forces clamped to `max_force_n`.
    pub force_clamped: u64,
}

/// The hub drive. See the module documentation.
#[derive(Debug, Clone)]
pub struct HubDrive {
    p: DriveParams,
    axis: Vec3,
    origin: Vec3,
    max_inserted: f64,
    max_speed: f64,
    inserted: f64,
    /// Insertion added to the stylus's target (m): where [`HubDrive::engage`]
    /// took the stylus up.
    offset: f64,
    roll0: f64,
    roll: f64,
    /// Stylus roll unwrapped, relative to the first usable sample.
    stylus_roll: f64,
    /// The last usable raw roll, once one arrived.
    last_raw_roll: Option<f64>,
    last_t: Option<f64>,
    counters: DriveCounters,
}

impl HubDrive {
    /// A drive for a wire with `wire` parameters (its `drive` table
    /// configures this), the wire starting at `inserted_m` with roll
    /// `roll_rad` (e.g. [`super::Wire::inserted`] and
    /// [`super::Wire::roll`]). The first commands hold these and then
    /// follow the stylus at the rate limits, so taking the stylus does not
    /// jerk the wire.
    pub fn new(wire: &WireParams, inserted_m: f64, roll_rad: f64) -> Result<HubDrive, ConfigError> {
        wire.validate(Path::new("(wire)"))?;
        let p = wire.drive;
        let axis = Vec3::from(p.axis).normalize();
        let max_inserted = wire.max_inserted_m();
        Ok(HubDrive {
            p,
            axis,
            origin: Vec3::from(p.origin_m),
            max_inserted,
            max_speed: p.max_speed_m_s.min(wire.max_feed_speed_m_s()),
            inserted: if inserted_m.is_finite() {
                inserted_m.clamp(0.0, max_inserted)
            } else {
                0.0
            },
            offset: 0.0,
            roll0: if roll_rad.is_finite() { roll_rad } else { 0.0 },
            roll: if roll_rad.is_finite() { roll_rad } else { 0.0 },
            stylus_roll: 0.0,
            last_raw_roll: None,
            last_t: None,
            counters: DriveCounters::default(),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &DriveParams {
        &self.p
    }

    /// The insertion axis in the device frame (unit).
    pub fn axis(&self) -> Vec3 {
        self.axis
    }

    /// The most the drive inserts (m): the wire's length or what its nodes
    /// hold, whichever is less.
    pub fn max_inserted(&self) -> f64 {
        self.max_inserted
    }

    /// The counters so far.
    pub fn counters(&self) -> DriveCounters {
        self.counters
    }

    /// Re-seats the commands at the wire's state (e.g. after the wire was
    /// restored to its last good state); the stylus roll keeps counting.
    pub fn reseat(&mut self, inserted_m: f64, roll_rad: f64) {
        if inserted_m.is_finite() {
            self.inserted = inserted_m.clamp(0.0, self.max_inserted);
        }
        if roll_rad.is_finite() {
            self.roll0 += roll_rad - self.roll;
            self.roll = roll_rad;
        }
    }

    /// Where the stylus asks the insertion to be (m), unclamped.
    pub fn target(&self, position: Vec3) -> f64 {
        self.p.inserted_at_origin_m + self.p.insertion_scale * (position - self.origin).dot(&self.axis) + self.offset
    }

    /// Takes the stylus up where it is, as a hand takes hold of an
    /// instrument it let go of: from sample `s` on, the stylus's motions
    /// since this sample move the hub from its present commands (insertion
    /// and roll), so the instrument does not jump to where the stylus's
    /// absolute position would put it. What the stylus did while this drive
    /// was not sampled (another instrument was active) is not this
    /// instrument's. An unusable sample changes nothing.
    pub fn engage(&mut self, s: &DeviceSample) {
        let roll_raw = s.gimbal_rad.get(self.p.roll_index).copied().unwrap_or(0.0);
        if !s.is_valid() || !roll_raw.is_finite() {
            return;
        }
        self.offset = 0.0;
        self.offset = self.inserted - self.target(s.position);
        self.last_raw_roll = Some(roll_raw);
        self.roll0 = self.roll - self.p.roll_scale * self.stylus_roll;
    }

    /// Takes a sample at time `now_s` (s, the caller's clock) and returns
    /// the hub command. Allocates nothing.
    pub fn command(&mut self, s: &DeviceSample, now_s: f64) -> HubCommand {
        self.counters.samples += 1;
        let dt = match self.last_t {
            Some(t) if now_s.is_finite() && now_s > t => (now_s - t).min(MAX_DT_S),
            _ => 0.0,
        };
        if now_s.is_finite() {
            self.last_t = Some(now_s);
        }
        let mut out = HubCommand {
            inserted_m: self.inserted,
            roll_rad: self.roll,
            target_m: self.inserted,
            ..HubCommand::default()
        };
        let roll_raw = s.gimbal_rad.get(self.p.roll_index).copied().unwrap_or(0.0);
        if !s.is_valid() || !roll_raw.is_finite() {
            self.counters.faults += 1;
            out.fault = true;
            return out;
        }
        // Insertion: project, clamp, rate-limit.
        let d = s.position - self.origin;
        let along = d.dot(&self.axis);
        out.off_axis_m = (d - self.axis * along).norm();
        let target = self.target(s.position);
        out.target_m = target;
        let clamped = target.clamp(0.0, self.max_inserted);
        out.clamped = clamped != target;
        let step = self.max_speed * dt;
        let want = clamped - self.inserted;
        let moved = want.clamp(-step, step);
        self.inserted += moved;
        let mut limited = moved != want;
        // Roll: unwrap, scale, rate-limit.
        if let Some(last) = self.last_raw_roll {
            self.stylus_roll += wrap_angle(roll_raw - last);
        }
        self.last_raw_roll = Some(roll_raw);
        let roll_target = self.roll0 + self.p.roll_scale * self.stylus_roll;
        let rstep = self.p.max_roll_speed_rad_s * dt;
        let rwant = roll_target - self.roll;
        let rmoved = rwant.clamp(-rstep, rstep);
        self.roll += rmoved;
        limited |= rmoved != rwant;
        if out.clamped {
            self.counters.clamped += 1;
        }
        if limited {
            self.counters.rate_limited += 1;
        }
        out.rate_limited = limited;
        out.inserted_m = self.inserted;
        out.roll_rad = self.roll;
        out
    }

    /// The force (N, device frame) the device should render for sample `s`
    /// when the wire pushes back on the hub with `hub_axial_force_n` (> 0
    /// resists insertion, [`super::StepReport::hub_axial_force_n`]): the
    /// axial resistance along the axis plus the guide, clamped to
    /// `max_force_n`. Zero for an unusable sample or a non-finite force.
    pub fn hand_force(&mut self, s: &DeviceSample, hub_axial_force_n: f64) -> Vec3 {
        if !s.is_valid() || !hub_axial_force_n.is_finite() {
            return Vec3::zeros();
        }
        let a = self.axis;
        let d = s.position - self.origin;
        let perp = d - a * d.dot(&a);
        let v_perp = s.velocity - a * s.velocity.dot(&a);
        let guide = -(perp * self.p.guide_stiffness_n_per_m) - v_perp * self.p.guide_damping_ns_per_m;
        let axial = -a * (self.p.force_scale * hub_axial_force_n);
        let f = guide + axial;
        let n = f.norm();
        if n > self.p.max_force_n {
            self.counters.force_clamped += 1;
            if n.is_finite() && n > 0.0 {
                return f * (self.p.max_force_n / n);
            }
            return Vec3::zeros();
        }
        f
    }
}
