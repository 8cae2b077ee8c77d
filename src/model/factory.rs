//! The model factory: a force model from the model kind, the material, the
//! law and the Prony terms (what scenes, benchmarks and experiments build).

use super::fem::Fem;
use super::msm::Msm;
use super::nvtmm::Nvtmm;
use super::tmm::Tmm;
use super::viscoelastic::Viscoelastic;
use super::{ForceModel, ModelKind};
use crate::material::{Law, Material, PronyTerm};
use crate::mesh::TetMesh;

/// Builds a force model. NVTMM with the Neo-Hookean law is evaluated per
/// element (log J has no tensor-mass polynomial form); Prony terms wrap the
/// elastic model in [`Viscoelastic`].
pub fn build_model(
    kind: ModelKind,
    mesh: &TetMesh,
    material: &Material,
    law: Law,
    prony: &[PronyTerm],
) -> Box<dyn ForceModel> {
    match (kind, law) {
        (ModelKind::Msm, _) => Box::new(Msm::new(mesh, material)),
        (ModelKind::Tmm, _) => Box::new(Tmm::new(mesh, material)),
        (ModelKind::Nvtmm, Law::Stvk) => {
            let m = Nvtmm::new(mesh, material);
            if prony.is_empty() {
                Box::new(m)
            } else {
                Box::new(Viscoelastic::new(m, mesh, material, law, prony))
            }
        }
        (ModelKind::Nvtmm, Law::NeoHookean) | (ModelKind::Fem, _) => {
            let m = Fem::new(mesh, material, law);
            if prony.is_empty() {
                Box::new(m)
            } else {
                Box::new(Viscoelastic::new(m, mesh, material, law, prony))
            }
        }
    }
}
