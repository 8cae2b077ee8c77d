//! The catheter: the same discrete elastic rod as the guidewire
//! ([`super::Wire`]), with its own geometry and material (a braided
//! polymer tube with a lumen for the wire and a softer distal part) and a
//! shaped tip ([`TipShape`], a rest-curvature profile along its distal
//! part). [`catheter_params`] gives a diagnostic catheter's
//! [`WireParams`]; [`super::coaxial::Coaxial`] runs it over a wire.
//!
//! Sizes, materials and the shapes' geometry, with their sources:
//! docs/CATHETER.md.

use super::{RestArc, WireParams};
use std::f64::consts::PI;

/// One French (the catheter's outer diameter in thirds of a millimetre), m.
pub const FRENCH_M: f64 = 1e-3 / 3.0;

/// The preset tip shapes of diagnostic catheters. Each is a rest-curvature
/// profile of the distal part ([`TipShape::arcs`]); the catheter takes its
/// shape wherever nothing straightens it (a wire inside, a wall).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TipShape {
    /// No shape: a straight catheter.
    Straight,
    /// Vertebral: one 35° bend 8 mm from the tip.
    Vertebral,
    /// Berenstein: one 45° bend 12 mm from the tip.
    Berenstein,
    /// Cobra (C2): a primary curve of 90° (radius 16 mm) and, near the
    /// tip, a secondary 35° curve the other way.
    Cobra,
    /// Headhunter (H1): a gentle 30° primary curve and a 50° hooked tip
    /// in the same sense.
    Headhunter,
    /// Simmons 2 / sidewinder: a reverse curve, a 170° hairpin (radius
    /// 10 mm) whose 20 mm limb points back along the shaft, and a 45°
    /// shoulder the other way. Straightened by the wire, it has to be
    /// re-formed in the aorta.
    Simmons,
    /// Pigtail: a closed 360° loop of 8 mm diameter at the tip (flushes,
    /// not selective work).
    Pigtail,
}

impl TipShape {
    /// Every preset.
    pub const ALL: [TipShape; 7] = [
        TipShape::Straight,
        TipShape::Vertebral,
        TipShape::Berenstein,
        TipShape::Cobra,
        TipShape::Headhunter,
        TipShape::Simmons,
        TipShape::Pigtail,
    ];

    /// The preset's name, as configuration files spell it.
    pub fn name(self) -> &'static str {
        match self {
            TipShape::Straight => "straight",
            TipShape::Vertebral => "vertebral",
            TipShape::Berenstein => "berenstein",
            TipShape::Cobra => "cobra",
            TipShape::Headhunter => "headhunter",
            TipShape::Simmons => "simmons",
            TipShape::Pigtail => "pigtail",
        }
    }

    /// The preset of that name, if any.
    pub fn from_name(name: &str) -> Option<TipShape> {
        TipShape::ALL.into_iter().find(|s| s.name() == name)
    }

    /// The rest shape as arcs of constant curvature from the tip back
    /// ([`WireParams::rest_shape`]): (length m, turning angle rad; a
    /// negative angle turns the other way), all in one plane.
    fn pieces(self) -> &'static [(f64, f64)] {
        const D: f64 = PI / 180.0;
        match self {
            TipShape::Straight => &[],
            TipShape::Vertebral => &[(8e-3, 0.0), (6e-3, 35.0 * D)],
            TipShape::Berenstein => &[(12e-3, 0.0), (6e-3, 45.0 * D)],
            TipShape::Cobra => &[(6e-3, 0.0), (8e-3, -35.0 * D), (10e-3, 0.0), (25e-3, 90.0 * D)],
            TipShape::Headhunter => &[(4e-3, 0.0), (8e-3, 50.0 * D), (20e-3, 0.0), (20e-3, 30.0 * D)],
            TipShape::Simmons => &[(20e-3, 0.0), (30e-3, 170.0 * D), (15e-3, -45.0 * D)],
            TipShape::Pigtail => &[(25e-3, 2.0 * PI)],
        }
    }

    /// The rest shape's arcs, from the tip back.
    pub fn arcs(self) -> Vec<RestArc> {
        self.pieces()
            .iter()
            .map(|&(length_m, turn)| RestArc {
                length_m,
                curvature_per_m: turn / length_m,
                plane_rad: 0.0,
            })
            .collect()
    }

    /// Length of the shaped part, from the tip (m).
    pub fn shaped_length_m(self) -> f64 {
        self.pieces().iter().map(|p| p.0).sum()
    }

    /// The signed sum of the arcs' turning angles (rad): the tip's
    /// direction relative to the shaft's when nothing straightens it.
    pub fn net_turn_rad(self) -> f64 {
        self.pieces().iter().map(|p| p.1).sum()
    }
}

/// The Newton iterations of a catheter's step before the residual's extra
/// ones that the service runs by default (`catheter.newton_iterations`):
/// the catheter, second in the pair's step and loaded by the wire's forces
/// of the same step, ends one iteration within the residual tolerance on
/// nearly every step (docs/CATHETER.md "The catheter's iterations").
/// [`catheter_params`] keeps [`WireParams::default`]'s.
pub const CATHETER_NEWTON_ITERATIONS: usize = 1;

/// A diagnostic catheter of `french` size (4–5 F are the usual; its outer
/// diameter is `french` / 3 mm) with the tip `shape`: a braided polymer
/// shaft (effective Young's modulus 1 GPa), a lumen of 1.07 mm where the
/// wall allows (it takes a 0.035" or 0.038" wire; at most outer − 0.33
/// mm), a 30 mm distal part three times softer than the shaft, 3 mm
/// segments and 128 nodes. Other keys as [`WireParams::default`]. The
/// figures and their sources: docs/CATHETER.md.
pub fn catheter_params(french: f64, shape: TipShape) -> WireParams {
    let outer = french * FRENCH_M;
    let inner = 1.07e-3_f64.min(outer - 0.33e-3).max(0.0);
    WireParams {
        length_m: 1.0,
        diameter_m: outer,
        inner_diameter_m: inner,
        youngs_modulus_pa: 1.0e9,
        poisson_ratio: 0.4,
        density_kg_m3: 1500.0,
        tip_length_m: 0.03_f64.max(shape.shaped_length_m()),
        tip_curvature_per_m: 0.0,
        tip_stiffness_factor: 1.0 / 3.0,
        rest_shape: shape.arcs(),
        segment_length_m: 3e-3,
        max_nodes: 128,
        ..WireParams::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    #[test]
    fn every_preset_makes_valid_parameters_with_its_turning() {
        for shape in TipShape::ALL {
            for french in [4.0, 5.0] {
                let p = catheter_params(french, shape);
                p.validate(Path::new("(catheter)")).unwrap();
                let (t1, t2) = p.rest_turning(0.0, 1.0);
                assert!((t1 - shape.net_turn_rad()).abs() < 1e-12 && t2 == 0.0, "{shape:?}");
                assert!(p.inner_diameter_m > 0.97e-3, "{french} F takes a 0.038\" wire");
            }
            assert_eq!(TipShape::from_name(shape.name()), Some(shape));
        }
        let p = catheter_params(5.0, TipShape::Vertebral);
        assert!((p.diameter_m - 1.6667e-3).abs() < 1e-7);
        // The annulus' moments.
        let i = PI * (p.diameter_m.powi(4) - p.inner_diameter_m.powi(4)) / 64.0;
        assert!((p.bending_stiffness() - 1e9 * i).abs() < 1e-12 * p.bending_stiffness().abs().max(1.0));
        assert!((p.twisting_stiffness() - 1e9 / 2.8 * 2.0 * i).abs() < 1e-9 * p.twisting_stiffness());
    }
}
