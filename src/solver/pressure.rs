//! Luminal blood pressure: a follower load on the vessel's inner wall.
//!
//! Blood pushes on the deformed lumen surface, normal to it. On a P1 surface
//! the consistent nodal force of a triangle (a, b, c) whose normal points out
//! of the wall (into the lumen) is the same for its three vertices:
//!
//! ```text
//! f_a = f_b = f_c = −(p/3) · ½ (x_b − x_a) × (x_c − x_a) = −(p/6) N,
//! N = x_a × x_b + x_b × x_c + x_c × x_a
//! ```
//!
//! (p/3 of the area-weighted normal, pointing into the wall). The positions
//! x = X + u are the current ones, so the force turns and stretches with the
//! wall: a follower load, whose load stiffness K_p = −∂f/∂u enters Newton.
//! With d_a = x_c − x_b, d_b = x_a − x_c, d_c = x_b − x_a (∂N/∂x_j = \[d_j\]ₓ):
//!
//! ```text
//! K_p(i, j) = (p/6) [d_j]ₓ            for every i, j of the triangle
//! ```
//!
//! K_p is not symmetric. Its symmetric part has no diagonal blocks (they are
//! skew) and, on the pair (a, b), the block (p/12) \[x_a + x_b − 2 x_c\]ₓ.
//! The antisymmetric part cancels between the two triangles of an interior
//! edge and around an interior vertex, so on a closed surface K_p is
//! symmetric (the load is conservative: f = −∂(p V)/∂x with V the enclosed
//! volume) and on an open lumen only the rim triangles keep an unsymmetric
//! part. The linear solvers here are symmetric (CG, Cholesky), so Newton uses
//! the symmetric part ([`PressureTangent::Symmetric`], the default) or none;
//! docs/PRESSURE.md has what each costs in Newton iterations. The exact,
//! unsymmetric product is [`LuminalPressure::add_df`] (tests, dense Newton).
//!
//! The pressure follows a [`PressureSchedule`]: a steady mean, or a heartbeat
//! waveform ([`Waveform`]), switched on by a ramp. Scenes configure it with
//! `[pressure]` ([`PressureConfig`]).

use crate::math::{Mat3, Vec3};
use crate::mesh::TetMesh;
use crate::model::BlockTangent;

/// 1 mmHg in Pa.
pub const MMHG_PA: f64 = 133.322;

/// Largest pressure a scene may set (Pa): 300 mmHg, beyond any physiology.
pub const MAX_PRESSURE_PA: f64 = 40e3;

/// The shape of one heartbeat, s(φ) ∈ [0, 1] for the phase φ ∈ [0, 1):
/// p = p_dia + (p_sys − p_dia) s(φ).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WaveShape {
    /// s = ½ (1 − cos 2πφ): the smooth test waveform (mean ½).
    Sinus,
    /// A physiological aortic pulse: a systolic half-sine over the ejection
    /// time (Weissler's regression, 413 − 1.7 · HR ms), then the
    /// Windkessel's exponential diastolic decay (τ = 1.5 s) from the
    /// dicrotic notch at 0.9 p_sys (Kelly & Fitchett's end-systolic
    /// estimate) down to p_dia at the end of the beat; docs/PRESSURE.md.
    Aortic,
}

/// A periodic heartbeat (scene `[pressure] waveform = { … }`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Waveform {
    /// Peak (systolic) pressure (Pa).
    pub systolic_pa: f64,
    /// Trough (diastolic) pressure (Pa).
    pub diastolic_pa: f64,
    /// Heart rate (beats per minute).
    pub heart_rate_bpm: f64,
    /// The shape of a beat.
    pub shape: WaveShape,
}

/// Time constant of the aortic shape's diastolic decay (s).
const WINDKESSEL_TAU_S: f64 = 1.5;

impl Waveform {
    /// Beat period (s).
    pub fn period(&self) -> f64 {
        60.0 / self.heart_rate_bpm
    }

    /// The shape s ∈ [0, 1] at time `t` (s) from the start of a beat.
    pub fn shape_at(&self, t: f64) -> f64 {
        let period = self.period();
        let tb = t.rem_euclid(period);
        match self.shape {
            WaveShape::Sinus => 0.5 * (1.0 - (2.0 * std::f64::consts::PI * tb / period).cos()),
            WaveShape::Aortic => {
                // Left-ventricular ejection time (men; Weissler et al. 1968),
                // kept inside a physiological share of the beat.
                let t_ej = (0.413 - 0.0017 * self.heart_rate_bpm).clamp(0.2 * period, 0.5 * period);
                let hump = if tb < t_ej {
                    (std::f64::consts::PI * tb / t_ej).sin()
                } else {
                    0.0
                };
                if tb < 0.5 * t_ej {
                    return hump;
                }
                // Diastole: exponential decay from the notch (end-systolic
                // pressure ≈ 0.9 p_sys) that reaches p_dia at the end of
                // the beat; extended back into late systole, where the
                // larger of the two is the pulse (the crossing is the notch).
                let dp = self.systolic_pa - self.diastolic_pa;
                let notch = ((0.9 * self.systolic_pa - self.diastolic_pa) / dp).clamp(0.05, 0.95);
                let end = (-(period - t_ej) / WINDKESSEL_TAU_S).exp();
                let decay = notch * (((-(tb - t_ej) / WINDKESSEL_TAU_S).exp() - end) / (1.0 - end));
                hump.max(decay).min(1.0)
            }
        }
    }

    /// The pressure (Pa) at time `t` (s).
    pub fn pressure_at(&self, t: f64) -> f64 {
        self.diastolic_pa + (self.systolic_pa - self.diastolic_pa) * self.shape_at(t)
    }

    /// The time average of the pressure over a beat (Pa), by the midpoint
    /// rule on 2000 samples.
    pub fn mean_pa(&self) -> f64 {
        let n = 2000;
        let period = self.period();
        (0..n)
            .map(|k| self.pressure_at((k as f64 + 0.5) / n as f64 * period))
            .sum::<f64>()
            / n as f64
    }
}

/// Which part of the load stiffness K_p goes into Newton's matrix.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PressureTangent {
    /// The symmetric part ½ (K_p + K_pᵀ): exact on closed surfaces.
    #[default]
    Symmetric,
    /// None: Newton sees only the wall's stiffness.
    None,
}

fn default_set() -> String {
    "inner_wall".into()
}
fn default_ramp() -> f64 {
    0.25
}

/// Scene `[pressure]`: blood pressure on the lumen (docs/PRESSURE.md has the
/// reference table).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PressureConfig {
    /// The steady (mean) pressure (Pa): the load without a waveform, the
    /// pressure the imaged geometry is taken at and the reduced model is
    /// linearized about. Defaults to the waveform's time average.
    #[serde(default)]
    pub mean_pa: Option<f64>,
    /// A heartbeat; without it the pressure is steady.
    #[serde(default)]
    pub waveform: Option<Waveform>,
    /// The node set whose surface triangles are loaded (all three vertices
    /// in the set, on the mesh boundary).
    #[serde(default = "default_set")]
    pub set: String,
    /// The pressure rises linearly from 0 over this time (s) after t = 0.
    #[serde(default = "default_ramp")]
    pub ramp_s: f64,
    /// What of the load stiffness Newton uses.
    #[serde(default)]
    pub tangent: PressureTangent,
    /// Solve for the zero-pressure geometry so that the mesh as given is the
    /// one at `mean_pa` (docs/PRESSURE.md, "The imaged geometry").
    #[serde(default)]
    pub unload_reference: bool,
}

impl PressureConfig {
    /// A steady pressure on `inner_wall`, with the defaults.
    pub fn steady(mean_pa: f64) -> PressureConfig {
        PressureConfig {
            mean_pa: Some(mean_pa),
            waveform: None,
            set: default_set(),
            ramp_s: default_ramp(),
            tangent: PressureTangent::default(),
            unload_reference: false,
        }
    }

    /// Checks every value; the error is (dotted key under `pressure`, what
    /// is allowed).
    pub fn validate(&self) -> Result<(), (String, String)> {
        let err = |k: &str, m: String| Err((k.to_string(), m));
        let range = |v: f64| v.is_finite() && (0.0..=MAX_PRESSURE_PA).contains(&v);
        if self.mean_pa.is_none() && self.waveform.is_none() {
            return err("mean_pa", "give mean_pa (Pa), a waveform, or both".into());
        }
        if let Some(m) = self.mean_pa {
            if !range(m) {
                return err("mean_pa", format!("{m}: must be in [0, {MAX_PRESSURE_PA}] Pa"));
            }
        }
        if let Some(w) = &self.waveform {
            if !range(w.diastolic_pa) {
                return err(
                    "waveform.diastolic_pa",
                    format!("{}: must be in [0, {MAX_PRESSURE_PA}] Pa", w.diastolic_pa),
                );
            }
            if !(range(w.systolic_pa) && w.systolic_pa > w.diastolic_pa) {
                return err(
                    "waveform.systolic_pa",
                    format!(
                        "{}: must be in (diastolic_pa = {}, {MAX_PRESSURE_PA}] Pa",
                        w.systolic_pa, w.diastolic_pa
                    ),
                );
            }
            if !(w.heart_rate_bpm.is_finite() && (20.0..=240.0).contains(&w.heart_rate_bpm)) {
                return err(
                    "waveform.heart_rate_bpm",
                    format!("{}: must be in [20, 240] beats/min", w.heart_rate_bpm),
                );
            }
            if let Some(m) = self.mean_pa {
                if !(w.diastolic_pa..=w.systolic_pa).contains(&m) {
                    return err(
                        "mean_pa",
                        format!(
                            "{m}: with a waveform it must lie in [diastolic_pa, systolic_pa] = [{}, {}] Pa",
                            w.diastolic_pa, w.systolic_pa
                        ),
                    );
                }
            }
        }
        if !(self.ramp_s.is_finite() && (0.0..=60.0).contains(&self.ramp_s)) {
            return err("ramp_s", format!("{}: must be in [0, 60] s", self.ramp_s));
        }
        if self.set.is_empty() {
            return err("set", "must name a node set (e.g. \"inner_wall\")".into());
        }
        Ok(())
    }

    /// The schedule p(t) this configures (call [`PressureConfig::validate`]
    /// first).
    pub fn schedule(&self) -> PressureSchedule {
        PressureSchedule {
            mean_pa: self
                .mean_pa
                .unwrap_or_else(|| self.waveform.map_or(0.0, |w| w.mean_pa())),
            waveform: self.waveform,
            ramp_s: self.ramp_s,
        }
    }
}

/// The pressure as a function of time: a linear ramp from 0 over `ramp_s`,
/// times the steady mean or the waveform.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PressureSchedule {
    /// The mean pressure (Pa): the steady load, or the level about which the
    /// waveform's pulsatile part is taken.
    pub mean_pa: f64,
    /// The heartbeat, if any.
    pub waveform: Option<Waveform>,
    /// Ramp time (s).
    pub ramp_s: f64,
}

impl PressureSchedule {
    /// A steady pressure switched on at once.
    pub fn steady(mean_pa: f64) -> PressureSchedule {
        PressureSchedule {
            mean_pa,
            waveform: None,
            ramp_s: 0.0,
        }
    }

    /// The ramp factor at `t` (s).
    pub fn ramp(&self, t: f64) -> f64 {
        if self.ramp_s > 0.0 {
            (t / self.ramp_s).clamp(0.0, 1.0)
        } else if t >= 0.0 {
            1.0
        } else {
            0.0
        }
    }

    /// p(t) (Pa).
    pub fn pressure_at(&self, t: f64) -> f64 {
        self.ramp(t) * self.waveform.map_or(self.mean_pa, |w| w.pressure_at(t))
    }

    /// The pulsatile part p(t) − p_mean (Pa) once the ramp is over: what the
    /// reduced model adds as a modal load about its pressurized state.
    pub fn pulsatile_at(&self, t: f64) -> f64 {
        self.waveform.map_or(0.0, |w| w.pressure_at(t) - self.mean_pa)
    }
}

/// What is wrong with a pressure surface.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PressureError {
    /// The node set does not exist.
    #[error("the mesh has no node set {0:?} to put the pressure on")]
    NoSet(String),
    /// No boundary triangle has all three vertices in the set.
    #[error("node set {0:?} holds no boundary triangle: nothing for the pressure to act on")]
    NoTriangles(String),
}

/// The pressure load on a set of boundary triangles of one mesh.
#[derive(Debug, Clone, PartialEq)]
pub struct LuminalPressure {
    /// The schedule p(t).
    pub schedule: PressureSchedule,
    /// What of the load stiffness Newton uses.
    pub tangent: PressureTangent,
    rest: Vec<Vec3>,
    tris: Vec<[u32; 3]>,
    /// Edge indices of (a, b), (b, c), (c, a) for each triangle.
    tri_edges: Vec<[u32; 3]>,
}

impl LuminalPressure {
    /// The pressure on the boundary triangles of `mesh` whose three vertices
    /// are in node set `set` (their normals, out of the wall, point into the
    /// lumen).
    pub fn on_set(
        mesh: &TetMesh,
        set: &str,
        schedule: PressureSchedule,
        tangent: PressureTangent,
    ) -> Result<LuminalPressure, PressureError> {
        let ids = mesh.node_set(set).ok_or_else(|| PressureError::NoSet(set.into()))?;
        let mut member = vec![false; mesh.num_nodes()];
        for &i in ids {
            member[i as usize] = true;
        }
        let tris: Vec<[u32; 3]> = mesh
            .surface()
            .iter()
            .filter(|t| t.iter().all(|&i| member[i as usize]))
            .copied()
            .collect();
        if tris.is_empty() {
            return Err(PressureError::NoTriangles(set.into()));
        }
        Ok(LuminalPressure::on_triangles(mesh, tris, schedule, tangent))
    }

    /// The pressure on the given boundary triangles of `mesh` (oriented with
    /// their normals out of the body; edges must be mesh edges, which every
    /// face of a tet's is).
    pub fn on_triangles(
        mesh: &TetMesh,
        tris: Vec<[u32; 3]>,
        schedule: PressureSchedule,
        tangent: PressureTangent,
    ) -> LuminalPressure {
        let edge = |a: u32, b: u32| mesh.edge_index(a, b).unwrap_or(u32::MAX);
        let tri_edges = tris
            .iter()
            .map(|&[a, b, c]| [edge(a, b), edge(b, c), edge(c, a)])
            .collect();
        LuminalPressure {
            schedule,
            tangent,
            rest: mesh.rest().to_vec(),
            tris,
            tri_edges,
        }
    }

    /// A load on no triangle for no mesh (a placeholder while the real one
    /// is lent out; allocates nothing).
    pub fn empty() -> LuminalPressure {
        LuminalPressure {
            schedule: PressureSchedule::steady(0.0),
            tangent: PressureTangent::None,
            rest: Vec::new(),
            tris: Vec::new(),
            tri_edges: Vec::new(),
        }
    }

    /// The loaded triangles.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.tris
    }

    /// Number of mesh nodes this load was built for.
    pub fn num_nodes(&self) -> usize {
        self.rest.len()
    }

    /// The sorted, distinct nodes the pressure acts on.
    pub fn nodes(&self) -> Vec<u32> {
        let mut v: Vec<u32> = self.tris.iter().flatten().copied().collect();
        v.sort_unstable();
        v.dedup();
        v
    }

    #[inline]
    fn corners(&self, t: &[u32; 3], u: &[Vec3]) -> [Vec3; 3] {
        t.map(|i| self.rest[i as usize] + u[i as usize])
    }

    /// Adds the nodal forces of pressure `p` (Pa) at displacement `u` into
    /// `out`.
    pub fn add_forces(&self, p: f64, u: &[Vec3], out: &mut [Vec3]) {
        if p == 0.0 {
            return;
        }
        for t in &self.tris {
            let [xa, xb, xc] = self.corners(t, u);
            let f = (xb - xa).cross(&(xc - xa)) * (-p / 6.0);
            for &i in t {
                out[i as usize] += f;
            }
        }
    }

    /// Adds (∂f/∂u) · du, the exact (unsymmetric) directional derivative of
    /// the pressure force, into `out`.
    pub fn add_df(&self, p: f64, u: &[Vec3], du: &[Vec3], out: &mut [Vec3]) {
        for t in &self.tris {
            let [xa, xb, xc] = self.corners(t, u);
            let [a, b, c] = t.map(|i| i as usize);
            let d_n = (xc - xb).cross(&du[a]) + (xa - xc).cross(&du[b]) + (xb - xa).cross(&du[c]);
            let df = d_n * (-p / 6.0);
            for &i in t {
                out[i as usize] += df;
            }
        }
    }

    /// Adds the symmetric part of the load stiffness −∂f/∂u at pressure `p`
    /// into `k` (nothing with [`PressureTangent::None`]).
    pub fn add_stiffness(&self, p: f64, u: &[Vec3], k: &mut BlockTangent) {
        if p == 0.0 || self.tangent == PressureTangent::None {
            return;
        }
        let s = p / 12.0;
        for (t, e) in self.tris.iter().zip(&self.tri_edges) {
            let x = self.corners(t, u);
            for (m, &edge) in e.iter().enumerate() {
                let (i, j, o) = (m, (m + 1) % 3, (m + 2) % 3);
                if edge == u32::MAX {
                    continue;
                }
                let w = (x[i] + x[j] - 2.0 * x[o]) * s;
                k.add_block(t[i], t[j], edge, &skew(&w));
            }
        }
    }

    /// The full, unsymmetric load stiffness −∂f/∂u as a dense 3n × 3n matrix
    /// (tests and small problems only).
    pub fn dense_stiffness(&self, p: f64, u: &[Vec3]) -> nalgebra::DMatrix<f64> {
        let n = self.rest.len();
        let mut m = nalgebra::DMatrix::zeros(3 * n, 3 * n);
        for t in &self.tris {
            let [xa, xb, xc] = self.corners(t, u);
            let d = [xc - xb, xa - xc, xb - xa];
            for &i in t {
                for (jj, &j) in t.iter().enumerate() {
                    let blk = skew(&d[jj]) * (p / 6.0);
                    let mut view = m.fixed_view_mut::<3, 3>(3 * i as usize, 3 * j as usize);
                    view += blk;
                }
            }
        }
        m
    }

    /// (1/6) Σ x_a · (x_b × x_c) over the loaded triangles at displacement
    /// `u`: on a closed surface the volume it encloses (m³), so that the
    /// pressure force is −p ∂V/∂u (a check of consistency).
    pub fn enclosed_volume(&self, u: &[Vec3]) -> f64 {
        self.tris
            .iter()
            .map(|t| {
                let [xa, xb, xc] = self.corners(t, u);
                xa.dot(&xb.cross(&xc))
            })
            .sum::<f64>()
            / 6.0
    }
}

/// \[w\]ₓ: the matrix with \[w\]ₓ v = w × v.
pub fn skew(w: &Vec3) -> Mat3 {
    Mat3::new(0.0, -w.z, w.y, w.z, 0.0, -w.x, -w.y, w.x, 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::block::block;

    fn perturbed(n: usize, scale: f64, seed: u64) -> Vec<Vec3> {
        let mut s = seed;
        let mut r = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * scale
        };
        (0..n).map(|_| Vec3::new(r(), r(), r())).collect()
    }

    /// A closed surface (a block's whole boundary): the force is minus the
    /// gradient of p V, checked by central differences.
    #[test]
    fn force_is_the_gradient_of_the_pressure_work_on_a_closed_surface() {
        let mesh = block([2, 2, 2], [0.01, 0.01, 0.01]).unwrap();
        let p = 1.3e4;
        let load = LuminalPressure::on_triangles(
            &mesh,
            mesh.surface().to_vec(),
            PressureSchedule::steady(p),
            PressureTangent::Symmetric,
        );
        let u = perturbed(mesh.num_nodes(), 1e-3, 7);
        let mut f = vec![Vec3::zeros(); mesh.num_nodes()];
        load.add_forces(p, &u, &mut f);
        let h = 1e-7;
        let fmax = f.iter().map(|v| v.norm()).fold(0.0, f64::max);
        for i in 0..mesh.num_nodes() {
            for k in 0..3 {
                let mut up = u.clone();
                up[i][k] += h;
                let mut um = u.clone();
                um[i][k] -= h;
                let dw = p * (load.enclosed_volume(&up) - load.enclosed_volume(&um)) / (2.0 * h);
                assert!(
                    (f[i][k] + dw).abs() < 1e-6 * fmax,
                    "node {i} axis {k}: {} vs {}",
                    f[i][k],
                    -dw
                );
            }
        }
    }

    /// The exact product and the dense tangent against central differences
    /// of the force, on an open surface (one face of a block) where the
    /// tangent is unsymmetric; the assembled symmetric part is the dense
    /// tangent's symmetric part.
    #[test]
    fn tangent_matches_finite_differences_of_the_force() {
        let mesh = block([2, 2, 2], [0.01, 0.01, 0.01]).unwrap();
        let top: Vec<[u32; 3]> = mesh
            .surface()
            .iter()
            .filter(|t| t.iter().all(|&i| mesh.rest()[i as usize].z > 0.0099))
            .copied()
            .collect();
        assert!(!top.is_empty());
        let p = 1.3e4;
        let load = LuminalPressure::on_triangles(&mesh, top, PressureSchedule::steady(p), PressureTangent::Symmetric);
        let n = mesh.num_nodes();
        let u = perturbed(n, 1e-3, 3);
        let du = perturbed(n, 1.0, 11);
        let h = 1e-7;
        let up: Vec<Vec3> = u.iter().zip(&du).map(|(a, b)| a + b * h).collect();
        let um: Vec<Vec3> = u.iter().zip(&du).map(|(a, b)| a - b * h).collect();
        let (mut fp, mut fm) = (vec![Vec3::zeros(); n], vec![Vec3::zeros(); n]);
        load.add_forces(p, &up, &mut fp);
        load.add_forces(p, &um, &mut fm);
        let mut df = vec![Vec3::zeros(); n];
        load.add_df(p, &u, &du, &mut df);
        let scale = df.iter().map(|v| v.norm()).fold(0.0, f64::max);
        assert!(scale > 0.0);
        for i in 0..n {
            let fd = (fp[i] - fm[i]) / (2.0 * h);
            assert!((fd - df[i]).norm() < 1e-6 * scale, "node {i}: {fd:?} vs {:?}", df[i]);
        }
        // Dense K = −∂f/∂u applied to du equals −df.
        let kd = load.dense_stiffness(p, &u);
        let duv = nalgebra::DVector::from_iterator(3 * n, du.iter().flat_map(|v| v.iter().copied()));
        let kdu = &kd * duv;
        for i in 0..n {
            for k in 0..3 {
                assert!((kdu[3 * i + k] + df[i][k]).abs() < 1e-9 * scale);
            }
        }
        assert!(
            (&kd - kd.transpose()).norm() > 1e-3 * kd.norm(),
            "an open surface's tangent is unsymmetric"
        );
        let mut ks = BlockTangent::zeros(&mesh);
        load.add_stiffness(p, &u, &mut ks);
        let sym = (&kd + kd.transpose()) * 0.5;
        assert!((ks.to_dense() - sym).norm() < 1e-12 * kd.norm());
    }

    /// On a closed surface the unsymmetric part cancels.
    #[test]
    fn tangent_is_symmetric_on_a_closed_surface() {
        let mesh = block([2, 1, 2], [0.01, 0.005, 0.01]).unwrap();
        let load = LuminalPressure::on_triangles(
            &mesh,
            mesh.surface().to_vec(),
            PressureSchedule::steady(1e4),
            PressureTangent::Symmetric,
        );
        let u = perturbed(mesh.num_nodes(), 1e-3, 5);
        let kd = load.dense_stiffness(1e4, &u);
        assert!((&kd - kd.transpose()).norm() < 1e-12 * kd.norm());
    }

    #[test]
    fn waveforms_span_diastole_to_systole() {
        for shape in [WaveShape::Sinus, WaveShape::Aortic] {
            let w = Waveform {
                systolic_pa: 120.0 * MMHG_PA,
                diastolic_pa: 80.0 * MMHG_PA,
                heart_rate_bpm: 70.0,
                shape,
            };
            let period = w.period();
            let samples: Vec<f64> = (0..=1000).map(|k| w.pressure_at(k as f64 / 1000.0 * period)).collect();
            let lo = samples.iter().cloned().fold(f64::INFINITY, f64::min);
            let hi = samples.iter().cloned().fold(0.0, f64::max);
            assert!(
                (lo - w.diastolic_pa).abs() < 1e-6 * w.diastolic_pa,
                "{shape:?} min {lo}"
            );
            assert!((hi - w.systolic_pa).abs() < 1e-3 * w.systolic_pa, "{shape:?} max {hi}");
            // Continuous: no jump between samples 1/1000 of a beat apart
            // larger than a tenth of the pulse pressure.
            let dp = w.systolic_pa - w.diastolic_pa;
            for s in samples.windows(2) {
                assert!((s[1] - s[0]).abs() < 0.1 * dp, "{shape:?} jumps");
            }
            let mean = w.mean_pa();
            assert!(mean > w.diastolic_pa && mean < w.systolic_pa);
        }
        // The aortic pulse's mean sits near the clinical rule dia + (sys − dia)/3.
        let w = Waveform {
            systolic_pa: 120.0 * MMHG_PA,
            diastolic_pa: 80.0 * MMHG_PA,
            heart_rate_bpm: 70.0,
            shape: WaveShape::Aortic,
        };
        let m = w.mean_pa() / MMHG_PA;
        assert!((85.0..=100.0).contains(&m), "aortic mean {m} mmHg");
    }

    #[test]
    fn config_errors_name_the_key() {
        let bad = |s: &str| {
            let c: PressureConfig = toml::from_str(s).unwrap();
            c.validate().unwrap_err().0
        };
        assert_eq!(bad("mean_pa = -1.0"), "mean_pa");
        assert_eq!(bad("ramp_s = 0.1"), "mean_pa");
        assert_eq!(
            bad("waveform = { systolic_pa = 1e4, diastolic_pa = 1.2e4, heart_rate_bpm = 60, shape = \"sinus\" }"),
            "waveform.systolic_pa"
        );
        assert_eq!(
            bad("waveform = { systolic_pa = 1.6e4, diastolic_pa = 1.0e4, heart_rate_bpm = 600, shape = \"aortic\" }"),
            "waveform.heart_rate_bpm"
        );
        assert_eq!(
            bad("mean_pa = 2e4\nwaveform = { systolic_pa = 1.6e4, diastolic_pa = 1.0e4, heart_rate_bpm = 60, shape = \"aortic\" }"),
            "mean_pa"
        );
        assert!(toml::from_str::<PressureConfig>("mean_pa = 1.0\nshape = \"sinus\"").is_err());
        let ok: PressureConfig = toml::from_str(
            "waveform = { systolic_pa = 1.6e4, diastolic_pa = 1.07e4, heart_rate_bpm = 70, shape = \"aortic\" }",
        )
        .unwrap();
        ok.validate().unwrap();
        let s = ok.schedule();
        assert!(s.mean_pa > 1.07e4 && s.mean_pa < 1.6e4);
        assert_eq!(s.pressure_at(0.0), 0.0);
    }
}
