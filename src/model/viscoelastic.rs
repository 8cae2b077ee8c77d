//! Prony-series viscoelasticity (paper section III, eq. 10–15), applied so
//! that rigid rotations stay free of viscous force.
//!
//! The paper writes the recurrence on forces: γ_iⁿ = A_i Fⁿ + B_i γ_iⁿ⁻¹ with
//! A_i = Δt α_i/(Δt + τ_i), B_i = τ_i/(Δt + τ_i) (eq. 15) and F̂ = F − Σ γ_i
//! (eq. 13). World-frame nodal forces rotate with the body, so a history kept
//! on them would push back on a rigid rotation. We apply the same recurrence
//! per element to the rest-frame second Piola–Kirchhoff stress S (as SOFA's
//! TLED does): with γ_i symmetric 3×3 per element and term,
//!
//! S_effⁿ = Sⁿ − Σ γ_iⁿ = (1 − Σ A_i) S(Eⁿ) − Σ B_i γ_iⁿ⁻¹,
//!
//! so inside an implicit step the force is the elastic force scaled by
//! (1 − Σ A_i) plus a history force f_p = V F H D_p with H = Σ B_i γ_iⁿ⁻¹
//! fixed during the step; its tangent is −∂f_p/∂u_q = −V (D_q·H D_p) I. After
//! the step converges, γ_iⁿ = A_i S(Eⁿ) + B_i γ_iⁿ⁻¹. Under held strain the
//! stress relaxes as α(t) (eq. 11) up to the backward-Euler time error.
//!
//! [`Viscoelastic`] wraps any elastic [`ForceModel`] (NVTMM's tensor-mass
//! StVK, or element FEM with StVK or Neo-Hookean) with this history. Its
//! working buffers (the elastic part before scaling, per-element history
//! forces and stresses) are sized at construction: no call allocates.

use super::{BlockTangent, ForceModel, Scratch};
use crate::material::{pk2, Lame, Law, Material, PronyTerm};
use crate::math::Mat3;
use crate::math::Vec3;
use crate::mesh::{TetMesh, TET_EDGE_LOCAL};
use rayon::prelude::*;

/// Per-element Prony history on the second Piola–Kirchhoff stress.
#[derive(Debug, Clone)]
pub struct Prony {
    terms: Vec<PronyTerm>,
    law: Law,
    lame: Lame,
    tets: Vec<[u32; 4]>,
    tet_edges: Vec<[u32; 6]>,
    grads: Vec<[Vec3; 4]>,
    volumes: Vec<f64>,
    /// γ_i per element: index `e * terms + i`.
    gamma: Vec<Mat3>,
    /// γ and the skipped-update count at the last `save`.
    saved_gamma: Vec<Mat3>,
    saved_skipped: usize,
    /// H = Σ B_i γ_i per element for the current step.
    history: Vec<Mat3>,
    a: Vec<f64>,
    b: Vec<f64>,
    skipped_updates: usize,
    /// Per-element history forces, reused by `add_history_forces`.
    per_element: Scratch<Vec<[Vec3; 4]>>,
    /// Per-element stresses at the end of a step (`None`: undefined).
    stresses: Vec<Option<Mat3>>,
}

impl Prony {
    /// Builds a relaxed (zero-history) Prony state for `mesh` whose elastic
    /// stress follows `law` with `material`'s constants.
    pub fn new(mesh: &TetMesh, material: &Material, law: Law, terms: &[PronyTerm]) -> Prony {
        let ne = mesh.tets().len();
        Prony {
            terms: terms.to_vec(),
            law,
            lame: material.lame(),
            tets: mesh.tets().to_vec(),
            tet_edges: mesh.tet_edges().to_vec(),
            grads: mesh.grads().to_vec(),
            volumes: mesh.volumes().to_vec(),
            gamma: vec![Mat3::zeros(); ne * terms.len()],
            saved_gamma: vec![Mat3::zeros(); ne * terms.len()],
            saved_skipped: 0,
            history: vec![Mat3::zeros(); ne],
            a: vec![0.0; terms.len()],
            b: vec![0.0; terms.len()],
            skipped_updates: 0,
            per_element: Scratch::new(vec![[Vec3::zeros(); 4]; ne]),
            stresses: vec![None; ne],
        }
    }

    /// The Prony terms.
    pub fn terms(&self) -> &[PronyTerm] {
        &self.terms
    }

    /// Fixes A_i, B_i (eq. 15) for a step of length `dt` and the history
    /// stress H = Σ B_i γ_i that acts during it.
    pub fn begin_step(&mut self, dt: f64) {
        for (i, p) in self.terms.iter().enumerate() {
            self.a[i] = dt * p.alpha / (dt + p.tau);
            self.b[i] = p.tau / (dt + p.tau);
        }
        let nt = self.terms.len();
        let b = &self.b;
        self.history.par_iter_mut().enumerate().for_each(|(e, h)| {
            *h = (0..nt).map(|i| self.gamma[e * nt + i] * b[i]).sum();
        });
    }

    /// 1 − Σ A_i: the factor on the elastic (instantaneous) response in this step.
    pub fn elastic_scale(&self) -> f64 {
        1.0 - self.a.iter().sum::<f64>()
    }

    fn deformation_gradient(&self, e: usize, u: &[Vec3]) -> Mat3 {
        let g = &self.grads[e];
        let mut f = Mat3::identity();
        for (k, &v) in self.tets[e].iter().enumerate() {
            f += u[v as usize] * g[k].transpose();
        }
        f
    }

    /// Adds the history force f_p = V F H D_p at displacement `u`.
    pub fn add_history_forces(&self, u: &[Vec3], out: &mut [Vec3]) {
        self.per_element.with(|per| {
            per.par_iter_mut().enumerate().for_each(|(e, f)| {
                let fh = self.deformation_gradient(e, u) * self.history[e] * self.volumes[e];
                *f = self.grads[e].map(|d| fh * d);
            });
            for (e, f) in per.iter().enumerate() {
                for (k, &v) in self.tets[e].iter().enumerate() {
                    out[v as usize] += f[k];
                }
            }
        });
    }

    /// Adds the derivative of the history force along `du`: V dF H D_p.
    pub fn add_history_df(&self, du: &[Vec3], out: &mut [Vec3]) {
        for e in 0..self.tets.len() {
            let g = &self.grads[e];
            let mut df = Mat3::zeros();
            for (k, &v) in self.tets[e].iter().enumerate() {
                df += du[v as usize] * g[k].transpose();
            }
            let m = df * self.history[e] * self.volumes[e];
            for (k, &v) in self.tets[e].iter().enumerate() {
                out[v as usize] += m * g[k];
            }
        }
    }

    /// Adds the history stiffness −∂f/∂u: block (p, q) gets −V (D_q·H D_p) I.
    pub fn add_history_stiffness(&self, kt: &mut BlockTangent) {
        for e in 0..self.tets.len() {
            let g = &self.grads[e];
            let (h, v) = (&self.history[e], self.volumes[e]);
            let tet = &self.tets[e];
            for k in 0..4 {
                kt.diag[tet[k] as usize] -= Mat3::identity() * (v * g[k].dot(&(h * g[k])));
            }
            for (k, [i, j]) in TET_EDGE_LOCAL.iter().enumerate() {
                let c = -v * g[*i].dot(&(h * g[*j]));
                kt.off[self.tet_edges[e][k] as usize] += Mat3::identity() * c;
            }
        }
    }

    /// Updates γ_iⁿ = A_i S(Eⁿ) + B_i γ_iⁿ⁻¹ at the converged displacement.
    /// Elements whose stress is undefined (a Neo-Hookean element with
    /// det F ≈ 0) keep their history; they are counted in
    /// [`Prony::skipped_updates`].
    pub fn end_step(&mut self, u: &[Vec3]) {
        let nt = self.terms.len();
        let mut stresses = std::mem::take(&mut self.stresses);
        stresses
            .par_iter_mut()
            .enumerate()
            .for_each(|(e, s)| *s = pk2(self.law, self.lame, &self.deformation_gradient(e, u)));
        for (e, &s) in stresses.iter().enumerate() {
            match s {
                Some(s) => {
                    for i in 0..nt {
                        let g = &mut self.gamma[e * nt + i];
                        *g = s * self.a[i] + *g * self.b[i];
                    }
                }
                None => self.skipped_updates += 1,
            }
        }
        self.stresses = stresses;
    }

    /// How many element updates were skipped because the stress was undefined.
    pub fn skipped_updates(&self) -> usize {
        self.skipped_updates
    }

    /// Saves the history γ (see [`ForceModel::save_state`]); no allocation.
    pub fn save(&mut self) {
        self.saved_gamma.copy_from_slice(&self.gamma);
        self.saved_skipped = self.skipped_updates;
    }

    /// Returns γ to the last [`Prony::save`]. The history stress H is
    /// recomputed by the next `begin_step`.
    pub fn restore(&mut self) {
        self.gamma.copy_from_slice(&self.saved_gamma);
        self.skipped_updates = self.saved_skipped;
    }

    /// Forgets all history.
    pub fn reset(&mut self) {
        self.gamma.iter_mut().for_each(|g| *g = Mat3::zeros());
        self.history.iter_mut().for_each(|g| *g = Mat3::zeros());
        self.a.iter_mut().for_each(|a| *a = 0.0);
        self.b.iter_mut().for_each(|b| *b = 0.0);
    }
}

/// An elastic model with Prony-series viscoelasticity on top.
#[derive(Debug, Clone)]
pub struct Viscoelastic<M> {
    elastic: M,
    prony: Prony,
    scale: f64,
    scratch: Scratch<ElasticPart>,
}

/// The elastic model's contribution before scaling by 1 − Σ A_i.
#[derive(Debug, Clone)]
struct ElasticPart {
    force: Vec<Vec3>,
    tangent: BlockTangent,
}

impl<M: ForceModel> Viscoelastic<M> {
    /// Wraps `elastic` (whose stress law is `law`) with the Prony `terms`.
    pub fn new(elastic: M, mesh: &TetMesh, material: &Material, law: Law, terms: &[PronyTerm]) -> Self {
        Viscoelastic {
            elastic,
            prony: Prony::new(mesh, material, law, terms),
            scale: 1.0,
            scratch: Scratch::new(ElasticPart {
                force: vec![Vec3::zeros(); mesh.num_nodes()],
                tangent: BlockTangent::zeros(mesh),
            }),
        }
    }
    /// The wrapped elastic model.
    pub fn elastic(&self) -> &M {
        &self.elastic
    }
    /// The Prony history.
    pub fn prony(&self) -> &Prony {
        &self.prony
    }
}

fn scale_into(k: f64, tmp: &[Vec3], out: &mut [Vec3]) {
    out.iter_mut().zip(tmp).for_each(|(o, t)| *o += t * k);
}

impl<M: ForceModel> ForceModel for Viscoelastic<M> {
    fn name(&self) -> &'static str {
        self.elastic.name()
    }

    fn add_forces(&self, u: &[Vec3], out: &mut [Vec3]) {
        self.scratch.with(|sc| {
            let tmp = &mut sc.force[..out.len()];
            tmp.iter_mut().for_each(|t| *t = Vec3::zeros());
            self.elastic.add_forces(u, tmp);
            scale_into(self.scale, tmp, out);
        });
        self.prony.add_history_forces(u, out);
    }

    fn add_df(&self, u: &[Vec3], du: &[Vec3], out: &mut [Vec3]) {
        self.scratch.with(|sc| {
            let tmp = &mut sc.force[..out.len()];
            tmp.iter_mut().for_each(|t| *t = Vec3::zeros());
            self.elastic.add_df(u, du, tmp);
            scale_into(self.scale, tmp, out);
        });
        self.prony.add_history_df(du, out);
    }

    fn add_stiffness(&self, u: &[Vec3], k: &mut BlockTangent) {
        if self.scale == 1.0 {
            self.elastic.add_stiffness(u, k);
        } else {
            self.scratch.with(|sc| {
                let tmp = &mut sc.tangent;
                tmp.clear();
                self.elastic.add_stiffness(u, tmp);
                k.add_scaled(self.scale, tmp);
            });
        }
        self.prony.add_history_stiffness(k);
    }

    fn energy(&self, u: &[Vec3]) -> f64 {
        self.elastic.energy(u)
    }

    fn begin_step(&mut self, dt: f64) {
        self.prony.begin_step(dt);
        self.scale = self.prony.elastic_scale();
        self.elastic.begin_step(dt);
    }

    fn end_step(&mut self, u: &[Vec3]) {
        self.prony.end_step(u);
        self.elastic.end_step(u);
    }

    fn reset_history(&mut self) {
        self.prony.reset();
        self.scale = 1.0;
        self.elastic.reset_history();
    }

    fn save_state(&mut self) {
        self.prony.save();
        self.elastic.save_state();
    }

    fn restore_state(&mut self) {
        self.prony.restore();
        self.elastic.restore_state();
    }

    fn is_viscoelastic(&self) -> bool {
        true
    }
}
