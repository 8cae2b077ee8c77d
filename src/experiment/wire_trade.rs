//! The guidewire's speed-for-accuracy knobs (the wire rows of `nvtmm
//! experiment trade`): segment length, Newton iterations per step, the
//! evaluation budget per step, contact stiffness and the friction model
//! (none, or its smoothing), each against a converged reference of
//! the same insertion.
//!
//! The scenario: the default wire (0.035", nitinol, soft angled tip) pushed
//! at 50 mm/s (or the speed given, up to [`MAX_PUSH_M_S`]) into a rigid curved tube shaped like the arch (a 40 mm inlet,
//! a half turn of 30 mm centreline radius, a 100 mm outlet, 4 mm lumen
//! radius), from 20 mm inserted. Errors are the largest tip distance from
//! the reference over the run (sampled every 10 ms) and the mean absolute
//! difference of the hub's axial force over the mean reference force.

use crate::math::Vec3;
use crate::wire::{CurvedTube, CurvedTubeShape, Wire, WireParams};
use std::time::Instant;

/// One measured wire configuration.
#[derive(Debug, Clone, serde::Serialize)]
pub struct WireTradeRow {
    /// Which knob was varied ("reference" for the reference itself).
    pub knob: String,
    /// Its value, as text.
    pub value: String,
    /// Median wall time per 1 ms step (µs).
    pub us_per_step: f64,
    /// Largest tip distance from the reference (mm).
    pub tip_error_mm: f64,
    /// Mean |hub force − reference| over the mean reference hub force.
    pub hub_force_error: f64,
    /// Most wall contacts in one step.
    pub contacts_max: usize,
    /// Active nodes at the end.
    pub nodes: usize,
    /// Most evaluations of the wire's potential in one step (what the
    /// step's worst case costs; `max_evaluations` bounds it).
    pub evaluations_max: usize,
}

/// What one run recorded.
struct Run {
    tips: Vec<Vec3>,
    hub: Vec<f64>,
    us: f64,
    contacts_max: usize,
    nodes: usize,
    evaluations_max: usize,
}

/// The scenario's tube: a rigid curved tube shaped like the arch (a 40 mm
/// inlet, a half turn of 30 mm centreline radius, a 100 mm outlet, 4 mm
/// lumen radius), the wire's access point at its inlet's start (the
/// origin) and the insertion axis +x.
pub fn tube() -> Result<CurvedTube, String> {
    CurvedTube::new(&CurvedTubeShape {
        start: Vec3::zeros(),
        tangent: Vec3::x(),
        toward: Vec3::y(),
        inlet: 0.04,
        bend_radius: 0.03,
        angle: std::f64::consts::PI,
        outlet: 0.1,
        radius: 4e-3,
    })
    .map_err(|e| e.to_string())
}

/// The scenario's default push speed (m/s).
pub const PUSH_M_S: f64 = 0.05;

/// The fastest push the scenario takes (m/s): the drive's limit.
pub const MAX_PUSH_M_S: f64 = 0.1;

/// Inserts the wire with `p` for `seconds` at `speed` m/s.
fn run(p: &WireParams, seconds: f64, speed: f64) -> Result<Run, String> {
    let lumen = tube()?;
    let mut w = Wire::new(p, Vec3::zeros(), Vec3::x(), 0.02).map_err(|e| e.to_string())?;
    let steps = (seconds / p.dt_s).round() as usize;
    let every = (0.01 / p.dt_s).round().max(1.0) as usize;
    let (mut tips, mut hub, mut us) = (Vec::new(), Vec::new(), Vec::with_capacity(steps));
    let (mut contacts_max, mut evaluations_max) = (0, 0);
    for k in 1..=steps {
        w.set_hub(0.02 + speed * k as f64 * p.dt_s, 0.0);
        let t0 = Instant::now();
        let r = w.step(&lumen).map_err(|e| format!("step {k}: {e:?}"))?;
        us.push(t0.elapsed().as_secs_f64() * 1e6);
        contacts_max = contacts_max.max(r.contacts);
        evaluations_max = evaluations_max.max(r.evaluations);
        if k % every == 0 {
            tips.push(w.tip());
            hub.push(r.hub_axial_force_n);
        }
    }
    us.sort_by(f64::total_cmp);
    Ok(Run {
        tips,
        hub,
        us: us.get(us.len() / 2).copied().unwrap_or(0.0),
        contacts_max,
        nodes: w.positions().len(),
        evaluations_max,
    })
}

/// The reference: 1.5 mm segments, 8 Newton iterations, the default
/// contact stiffness and Coulomb friction μ = 0.1.
pub fn reference_params() -> WireParams {
    WireParams {
        segment_length_m: 1.5e-3,
        newton_iterations: 8,
        max_nodes: 200,
        ..WireParams::default()
    }
}

/// Runs every row (`quick`: 1 s of insertion instead of 2.5 s) with the
/// wire pushed at `speed` m/s (in (0, [`MAX_PUSH_M_S`]]; [`PUSH_M_S`] by
/// default).
pub fn rows(quick: bool, speed: f64) -> Result<Vec<WireTradeRow>, String> {
    if !(speed > 0.0 && speed <= MAX_PUSH_M_S) {
        return Err(format!(
            "the wire's push speed is {} mm/s: it must be above 0 and at most {} mm/s",
            speed * 1e3,
            MAX_PUSH_M_S * 1e3
        ));
    }
    let seconds = if quick { 1.0 } else { 2.5 };
    let reference = reference_params();
    let base = run(&reference, seconds, speed)?;
    let mean_ref = base.hub.iter().map(|f| f.abs()).sum::<f64>() / base.hub.len().max(1) as f64;
    let row = |knob: &str, value: String, r: &Run| -> WireTradeRow {
        let tip_error_mm = r
            .tips
            .iter()
            .zip(&base.tips)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max)
            * 1e3;
        let diff = r.hub.iter().zip(&base.hub).map(|(a, b)| (a - b).abs()).sum::<f64>() / r.hub.len().max(1) as f64;
        WireTradeRow {
            knob: knob.into(),
            value,
            us_per_step: r.us,
            tip_error_mm,
            hub_force_error: if mean_ref > 0.0 { diff / mean_ref } else { f64::NAN },
            contacts_max: r.contacts_max,
            nodes: r.nodes,
            evaluations_max: r.evaluations_max,
        }
    };
    let mut out = vec![row("reference", "1.5 mm, 8 it., 1e6 N/m, μ 0.1".into(), &base)];
    let mut add = |knob: &str, value: String, p: WireParams| -> Result<(), String> {
        let r = run(&p, seconds, speed)?;
        out.push(row(knob, value, &r));
        Ok(())
    };
    for h in [3e-3, 6e-3] {
        add(
            "segment_length",
            format!("{} mm", h * 1e3),
            WireParams {
                segment_length_m: h,
                ..reference.clone()
            },
        )?;
    }
    for it in [1, 2, 3] {
        add(
            "newton_iterations",
            it.to_string(),
            WireParams {
                newton_iterations: it,
                ..reference.clone()
            },
        )?;
    }
    for k in [1e5, 1e7] {
        add(
            "contact_stiffness",
            format!("{k:.0e} N/m"),
            WireParams {
                contact_stiffness_n_per_m: k,
                ..reference.clone()
            },
        )?;
    }
    for e in [8, 16] {
        add(
            "max_evaluations",
            e.to_string(),
            WireParams {
                max_evaluations: e,
                ..reference.clone()
            },
        )?;
    }
    add(
        "friction",
        "none (μ 0)".into(),
        WireParams {
            friction: 0.0,
            ..reference.clone()
        },
    )?;
    for eps in [1e-7, 1e-5] {
        add(
            "friction_smoothing",
            format!("{:.1} µm", eps * 1e6),
            WireParams {
                friction_smoothing_m: eps,
                ..reference.clone()
            },
        )?;
    }
    add(
        "contact_onset",
        "0 (penalty from contact)".into(),
        WireParams {
            contact_onset_m: 0.0,
            ..reference.clone()
        },
    )?;
    add(
        "shipped",
        "3 mm, 2 it. (rt-config/guidewire.toml)".into(),
        WireParams {
            segment_length_m: 3e-3,
            newton_iterations: 2,
            ..reference.clone()
        },
    )?;
    add(
        "shipped + residual_tolerance",
        "3 mm, 2 it., 0 N (no iterations past 2)".into(),
        WireParams {
            segment_length_m: 3e-3,
            newton_iterations: 2,
            residual_tolerance_n: 0.0,
            ..reference.clone()
        },
    )?;
    for budget in [6, 4] {
        add(
            "shipped + max_evaluations",
            format!("3 mm, 2 it., {budget} evaluations"),
            WireParams {
                segment_length_m: 3e-3,
                newton_iterations: 2,
                max_evaluations: budget,
                ..reference.clone()
            },
        )?;
    }
    Ok(out)
}

/// The rows as a Markdown table.
pub fn markdown(rows: &[WireTradeRow]) -> String {
    let mut s = String::from(
        "| wire knob | value | µs per step (p50) | tip error (mm, max) | hub force error (mean, rel.) | contacts max | nodes | evaluations a step (max) |\n|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        s += &format!(
            "| {} | {} | {:.0} | {:.3} | {:.3} | {} | {} | {} |\n",
            r.knob,
            r.value,
            r.us_per_step,
            r.tip_error_mm,
            r.hub_force_error,
            r.contacts_max,
            r.nodes,
            r.evaluations_max
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reference_row_has_no_error_and_every_row_is_finite() {
        let r = rows(true, PUSH_M_S).unwrap();
        assert_eq!(r[0].knob, "reference");
        assert_eq!(r[0].tip_error_mm, 0.0);
        assert_eq!(r[0].hub_force_error, 0.0);
        assert!(r.len() >= 9);
        for row in &r {
            assert!(row.us_per_step > 0.0 && row.tip_error_mm.is_finite(), "{row:?}");
            assert!(row.contacts_max > 0, "the wire touches the tube: {row:?}");
        }
        // A coarser wire or fewer iterations is cheaper per step than the
        // reference's 8 iterations on 1.5 mm segments.
        let coarse = r
            .iter()
            .find(|x| x.knob == "segment_length" && x.value == "6 mm")
            .unwrap();
        assert!(coarse.nodes < r[0].nodes);
        // Friction's smoothing is a knob: a tenth and ten times the default.
        let eps: Vec<_> = r.iter().filter(|x| x.knob == "friction_smoothing").collect();
        assert_eq!(eps.len(), 2);
        assert!(eps.iter().all(|x| x.tip_error_mm > 0.0), "{eps:?}");
        // So are the penalty's onset and the residual tolerance.
        for knob in ["contact_onset", "shipped + residual_tolerance"] {
            assert_eq!(r.iter().filter(|x| x.knob == knob).count(), 1, "{knob}");
        }
    }

    #[test]
    fn a_push_speed_out_of_range_is_refused_by_name() {
        for v in [0.0, -0.01, 0.2, f64::NAN] {
            let e = rows(true, v).unwrap_err();
            assert!(e.contains("push speed") && e.contains("100 mm/s"), "{e}");
        }
    }
}
