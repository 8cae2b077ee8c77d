//! The zero-pressure reference: the geometry that, inflated to the mean
//! pressure, is the imaged one.
//!
//! A vessel is imaged already pressurized. Using the image as the rest state
//! and inflating it again overstretches it. The backward-displacement method
//! (Bols, Degroote, Trachet, Verhegghe, Segers & Vierendeels, J. Comput.
//! Appl. Math. 246, 2013) finds the unloaded geometry X by the fixed point
//!
//! ```text
//! X₀ = x_image,   X_{k+1} = X_k − (x(X_k, p) − x_image)
//! ```
//!
//! where x(X, p) is the static equilibrium ([`super::statics`]) of the wall
//! meshed at X under pressure p, with the same tets, fixed nodes (held where
//! the image has them) and loaded surface. A step whose candidate cannot be
//! inflated or inverts a tet is shortened (X_{k+1} = X_k − ω e_k, ω halved
//! down to 1/64 and grown back by 1.5 after each good iteration). It stops when the inflated
//! geometry is within `tol_m` of the image at every node, and refuses when
//! it does not get there: a pressure the material cannot hold (the static
//! solve fails), an iteration that inverts a tet, or no convergence within
//! `max_iters`.
//!
//! [`UnloadRequest::key`] hashes everything the result depends on, for the
//! cache the scene keeps next to the basis cache.

use super::pressure::{LuminalPressure, PressureError, PressureSchedule, PressureTangent};
use super::statics::{mask_of_fixed, solve_pressurized, StaticError, StaticParams, StaticReport};
use crate::material::{Law, Material};
use crate::math::Vec3;
use crate::mesh::{TetMesh, TopologyError};
use crate::model::factory::build_model;
use crate::model::{ForceModel, ModelKind};
use crate::reduced::cache::Fnv1a;

/// Version of what [`UnloadRequest::key`] hashes; bump it when the method
/// changes so old cached references are recomputed.
pub const UNLOAD_VERSION: u64 = 1;

/// Stopping rule of the fixed point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnloadParams {
    /// Converged when every node of the inflated reference is within this
    /// distance of the image (m).
    pub tol_m: f64,
    /// Fixed-point iterations allowed.
    pub max_iters: usize,
    /// The static solves' control (the first one's load steps; later ones
    /// start from the previous displacement in one step).
    pub statics: StaticParams,
}

impl Default for UnloadParams {
    fn default() -> Self {
        UnloadParams {
            tol_m: 1e-5,
            max_iters: 60,
            statics: StaticParams::default(),
        }
    }
}

/// Everything the zero-pressure reference depends on.
#[derive(Clone, Copy)]
pub struct UnloadRequest<'a> {
    /// The imaged (pressurized) mesh.
    pub image: &'a TetMesh,
    /// Force model kind.
    pub kind: ModelKind,
    /// Material (for a viscoelastic wall: its relaxed, long-term modulus,
    /// where a steady mean pressure leaves it).
    pub material: Material,
    /// Law.
    pub law: Law,
    /// The node set the pressure acts on.
    pub set: &'a str,
    /// The pressure the image was taken at (Pa).
    pub pressure_pa: f64,
    /// Fixed nodes (held at their imaged position).
    pub fixed: &'a [u32],
    /// Stopping rule.
    pub params: UnloadParams,
}

/// The result.
#[derive(Debug, Clone)]
pub struct Unloaded {
    /// The zero-pressure mesh (same tets and node sets as the image).
    pub mesh: TetMesh,
    /// Fixed-point iterations done.
    pub iters: usize,
    /// The largest distance (m) between the inflated reference and the image
    /// after each iteration.
    pub history: Vec<f64>,
    /// Newton iterations of all static solves.
    pub newton_iters: usize,
}

/// Why no zero-pressure reference was found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum UnloadError {
    /// The pressure surface is missing.
    #[error("zero-pressure reference: {0}")]
    Surface(#[from] PressureError),
    /// A static inflation failed.
    #[error("zero-pressure reference, iteration {iter}: {source}")]
    Static {
        /// Fixed-point iteration.
        iter: usize,
        /// The static solve's error.
        source: StaticError,
    },
    /// An iterate turned tets inside out.
    #[error("zero-pressure reference, iteration {iter}: the unloaded geometry inverts {tets} tets (the pressure is too high for this material)")]
    Inverted {
        /// Fixed-point iteration.
        iter: usize,
        /// Tets inverted.
        tets: usize,
    },
    /// The iterate could not be meshed.
    #[error("zero-pressure reference: {0}")]
    Mesh(#[from] TopologyError),
    /// Not within the tolerance after the allowed iterations.
    #[error("zero-pressure reference not converged after {iters} iterations: the inflated geometry is still {max_error_m:.2e} m from the image (tolerance {tol_m:.1e} m); the pressure may be more than this material can hold")]
    NotConverged {
        /// Iterations done.
        iters: usize,
        /// The last largest distance (m).
        max_error_m: f64,
        /// The tolerance (m).
        tol_m: f64,
    },
}

impl UnloadRequest<'_> {
    /// The cache key: a hash of the method version, the image's positions
    /// and tets, the model, material, law, surface set, pressure, fixed
    /// nodes and stopping rule.
    pub fn key(&self) -> u64 {
        let mut h = Fnv1a::default();
        h.str("nvtmm zero-pressure reference");
        h.u64(UNLOAD_VERSION);
        h.u64(self.image.num_nodes() as u64);
        for p in self.image.rest() {
            p.iter().for_each(|&c| h.f64(c));
        }
        h.u64(self.image.tets().len() as u64);
        for t in self.image.tets() {
            t.iter().for_each(|&i| h.u64(i as u64));
        }
        h.str(self.kind.name());
        h.material(&self.material, self.law);
        h.str(self.set);
        h.f64(self.pressure_pa);
        h.u64(self.fixed.len() as u64);
        self.fixed.iter().for_each(|&i| h.u64(i as u64));
        h.f64(self.params.tol_m);
        h.u64(self.params.max_iters as u64);
        h.finish()
    }

    fn model(&self, mesh: &TetMesh) -> Box<dyn ForceModel> {
        build_model(self.kind, mesh, &self.material, self.law, &[])
    }

    /// Inflates `mesh` (a candidate reference) to the request's pressure;
    /// returns the displacement and the solve's report. `u` is the start.
    pub fn inflate(&self, mesh: &TetMesh, statics: &StaticParams, u: &mut [Vec3]) -> Result<StaticReport, UnloadError> {
        let load = LuminalPressure::on_set(
            mesh,
            self.set,
            PressureSchedule::steady(self.pressure_pa),
            PressureTangent::Symmetric,
        )?;
        let model = self.model(mesh);
        let mask = mask_of_fixed(mesh.num_nodes(), self.fixed);
        solve_pressurized(mesh, model.as_ref(), &load, self.pressure_pa, &mask, statics, u)
            .map_err(|source| UnloadError::Static { iter: 0, source })
    }

    /// Runs the backward-displacement fixed point.
    pub fn solve(&self) -> Result<Unloaded, UnloadError> {
        let image = self.image;
        let n = image.num_nodes();
        let x_img = image.rest();
        let mut reference = image.clone();
        let mut u = vec![Vec3::zeros(); n];
        let mut history = Vec::new();
        let mut newton_iters = 0;
        let mut statics = self.params.statics;
        // The step X ← X − ω e starts at ω = 1 (Bols et al.'s plain fixed
        // point); a candidate whose inflation fails or whose mesh inverts is
        // replaced by a shorter step from the last good reference (ω halved,
        // down to 1/64), and ω grows back after every good iteration.
        let mut omega: f64 = 1.0;
        let mut last: Option<(TetMesh, Vec<Vec3>, Vec<Vec3>)> = None;
        let step = |good: &TetMesh, e: &[Vec3], omega: f64| -> Result<TetMesh, UnloadError> {
            let next = good.rest().iter().zip(e).map(|(x, d)| x - d * omega).collect();
            Ok(TetMesh::new(next, image.tets().to_vec(), image.node_sets().clone())?)
        };
        let mut iter = 0;
        while iter < self.params.max_iters {
            iter += 1;
            let failure = match self.inflate(&reference, &statics, &mut u) {
                Err(UnloadError::Static { source, .. }) => UnloadError::Static { iter, source },
                Err(e) => return Err(e),
                Ok(rep) => {
                    newton_iters += rep.total_iters();
                    // Later solves start from the last displacement: one step.
                    statics.load_steps = 1;
                    let e: Vec<Vec3> = reference
                        .rest()
                        .iter()
                        .zip(&u)
                        .zip(x_img)
                        .map(|((x_ref, d), img)| x_ref + d - img)
                        .collect();
                    let worst = e.iter().map(|v| v.norm()).fold(0.0, f64::max);
                    history.push(worst);
                    if worst <= self.params.tol_m {
                        return Ok(Unloaded {
                            mesh: reference,
                            iters: iter,
                            history,
                            newton_iters,
                        });
                    }
                    omega = (1.5 * omega).min(1.0);
                    let candidate = step(&reference, &e, omega)?;
                    last = Some((reference, e, u.clone()));
                    if candidate.report().inverted == 0 {
                        reference = candidate;
                        continue;
                    }
                    UnloadError::Inverted {
                        iter,
                        tets: candidate.report().inverted,
                    }
                }
            };
            // Back off: a shorter step from the last good reference.
            let Some((good, e, u_good)) = last.as_ref() else {
                return Err(failure);
            };
            loop {
                omega *= 0.5;
                if omega < 1.0 / 64.0 {
                    return Err(failure);
                }
                let candidate = step(good, e, omega)?;
                if candidate.report().inverted == 0 {
                    reference = candidate;
                    u.copy_from_slice(u_good);
                    statics.load_steps = self.params.statics.load_steps;
                    break;
                }
            }
        }
        Err(UnloadError::NotConverged {
            iters: self.params.max_iters,
            max_error_m: history.last().copied().unwrap_or(f64::INFINITY),
            tol_m: self.params.tol_m,
        })
    }
}
