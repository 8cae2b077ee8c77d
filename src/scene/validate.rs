//! Every key of a scene checked against its allowed range before anything
//! runs; errors name the file, the key and the range.

use super::*;

impl Scene {
    /// Checks every key against its allowed range.
    pub fn validate(&self) -> Result<(), SceneError> {
        let m = &self.mesh;
        if m.arch_branches.is_some() && m.arch_nodes.is_none() {
            return Err(self.err(
                "mesh.arch_branches",
                "only with mesh.arch_nodes (it picks which built-in arch that builds)",
            ));
        }
        let sources =
            m.arch_nodes.is_some() as u8 + m.block.is_some() as u8 + m.file.is_some() as u8 + m.vessel.is_some() as u8;
        if sources != 1 {
            return Err(self.err("mesh", "give exactly one of arch_nodes, block, file, vessel"));
        }
        if let Some(v) = &m.vessel {
            if v.wall_thickness.is_some() && v.wall_ratio.is_some() {
                return Err(self.err("mesh.vessel", "give wall_thickness or wall_ratio, not both"));
            }
            if let Some(t) = v.wall_thickness {
                if !(t.is_finite() && t > 0.0 && t <= 0.05) {
                    return Err(self.err("mesh.vessel.wall_thickness", format!("{t}: must be in (0, 0.05] m")));
                }
            }
            if let Some(f) = v.wall_ratio {
                if !(f.is_finite() && f > 0.0 && f <= 2.0) {
                    return Err(self.err("mesh.vessel.wall_ratio", format!("{f}: must be in (0, 2]")));
                }
            }
            if !(1..=64).contains(&v.layers) {
                return Err(self.err("mesh.vessel.layers", format!("{}: must be in 1..=64", v.layers)));
            }
            if v.nodes.is_some() && v.edge_length.is_some() {
                return Err(self.err("mesh.vessel", "give nodes or edge_length, not both"));
            }
            if let Some(n) = v.nodes {
                if !(32..=2_000_000).contains(&n) {
                    return Err(self.err("mesh.vessel.nodes", format!("{n}: must be in 32..=2000000")));
                }
            }
            if let Some(e) = v.edge_length {
                if !(e.is_finite() && e > 0.0 && e <= 0.1) {
                    return Err(self.err("mesh.vessel.edge_length", format!("{e}: must be in (0, 0.1] m")));
                }
            }
            if !(v.scale.is_finite() && v.scale > 0.0) {
                return Err(self.err("mesh.vessel.scale", format!("{}: must be finite and > 0", v.scale)));
            }
        }
        if let (Some(n), Some(ArchBranches::Three)) = (m.arch_nodes, m.arch_branches) {
            if !BRANCHED_ARCH_NODES.contains(&n) {
                return Err(self.err(
                    "mesh.arch_nodes",
                    format!(
                        "{n} is out of range {}..={} for the branched arch (mesh.arch_branches = \"three\")",
                        BRANCHED_ARCH_NODES.start(),
                        BRANCHED_ARCH_NODES.end()
                    ),
                ));
            }
        } else if let Some(n) = m.arch_nodes {
            if !(crate::mesh::arch::MIN_NODES..=crate::mesh::arch::MAX_NODES).contains(&n) {
                return Err(self.err(
                    "mesh.arch_nodes",
                    format!(
                        "{n} is out of range {}..={}",
                        crate::mesh::arch::MIN_NODES,
                        crate::mesh::arch::MAX_NODES
                    ),
                ));
            }
        }
        if let Some(b) = &m.block {
            if b.cells.iter().any(|&c| c == 0 || c > 400) {
                return Err(self.err("mesh.block.cells", format!("{:?}: each must be in 1..=400", b.cells)));
            }
            if b.size.iter().any(|&s| !(s.is_finite() && s > 0.0)) {
                return Err(self.err(
                    "mesh.block.size",
                    format!("{:?}: each must be finite and > 0 (m)", b.size),
                ));
            }
        }
        if !(m.scale.is_finite() && m.scale > 0.0) {
            return Err(self.err("mesh.scale", format!("{}: must be finite and > 0", m.scale)));
        }
        let mat = &self.material;
        if !(mat.youngs_pa.is_finite() && (1.0..=1e10).contains(&mat.youngs_pa)) {
            return Err(self.err(
                "material.youngs_pa",
                format!("{}: must be in [1, 1e10] Pa", mat.youngs_pa),
            ));
        }
        if !(mat.poisson.is_finite() && (0.0..=0.4999).contains(&mat.poisson)) {
            return Err(self.err("material.poisson", format!("{}: must be in [0, 0.4999]", mat.poisson)));
        }
        if !(mat.density.is_finite() && (1.0..=1e5).contains(&mat.density)) {
            return Err(self.err(
                "material.density",
                format!("{}: must be in [1, 1e5] kg/m^3", mat.density),
            ));
        }
        if !self.prony.is_empty() && !matches!(self.model, ModelKind::Nvtmm | ModelKind::Fem) {
            return Err(self.err(
                "prony",
                format!(
                    "Prony terms apply to the nvtmm and fem models, not {}",
                    self.model.name()
                ),
            ));
        }
        if self.model == ModelKind::Tmm && mat.law != Law::Stvk {
            return Err(self.err("material.law", "the tmm model is linear elasticity; use law = \"stvk\""));
        }
        let mut sum = 0.0;
        for (i, p) in self.prony.iter().enumerate() {
            if !(p.alpha.is_finite() && p.alpha > 0.0 && p.alpha < 1.0) {
                return Err(self.err(&format!("prony[{i}].alpha"), format!("{}: must be in (0, 1)", p.alpha)));
            }
            if !(p.tau.is_finite() && p.tau > 0.0) {
                return Err(self.err(
                    &format!("prony[{i}].tau"),
                    format!("{}: must be finite and > 0 (s)", p.tau),
                ));
            }
            sum += p.alpha;
        }
        if sum >= 1.0 {
            return Err(self.err("prony", format!("the alphas sum to {sum}: the sum must be < 1")));
        }
        for (i, b) in self.fixed.boxes.iter().enumerate() {
            if b.min.iter().chain(&b.max).any(|v| !v.is_finite()) || (0..3).any(|k| b.min[k] > b.max[k]) {
                return Err(self.err(
                    &format!("fixed.boxes[{i}]"),
                    "min and max must be finite with min <= max",
                ));
            }
        }
        for (i, l) in self.loads.iter().enumerate() {
            let key = format!("load[{i}]");
            let sel = (!l.nodes.is_empty()) as u8 + l.set.is_some() as u8 + l.near.is_some() as u8;
            if sel != 1 {
                return Err(self.err(&key, "give exactly one of nodes, set, near"));
            }
            if l.force_n.iter().any(|v| !v.is_finite()) {
                return Err(self.err(&format!("{key}.force_n"), "must be finite (N)"));
            }
            if l.near.is_some_and(|p| p.iter().any(|v| !v.is_finite())) {
                return Err(self.err(&format!("{key}.near"), "must be finite (m)"));
            }
            let ok = match l.profile {
                TimeProfile::Constant { from_t0 } => from_t0.is_finite(),
                TimeProfile::Ramp { t0, t1 } => t0.is_finite() && t1.is_finite(),
                TimeProfile::Sine { freq_hz, phase } => freq_hz.is_finite() && freq_hz >= 0.0 && phase.is_finite(),
            };
            if !ok {
                return Err(self.err(&format!("{key}.profile"), "parameters must be finite (freq_hz >= 0)"));
            }
        }
        if self.gravity.iter().any(|v| !v.is_finite()) {
            return Err(self.err("gravity", "must be finite (m/s^2)"));
        }
        self.validate_reduced()?;
        if let Some(p) = &self.pressure {
            p.validate()
                .map_err(|(key, msg)| self.err(&format!("pressure.{key}"), msg))?;
        }
        self.validate_roi()?;
        let dt = self.integrator.dt;
        self.checker().f64_in("integrator.dt", dt, 1e-6, 0.1, "s")?;
        self.integrator.validate().map_err(|msg| self.err("integrator", msg))?;
        if !(self.duration.is_finite() && self.duration > 0.0 && self.duration / dt <= 1e8) {
            return Err(self.err(
                "duration",
                format!("{}: must be > 0 and at most 1e8 steps of dt", self.duration),
            ));
        }
        Ok(())
    }

    fn validate_reduced(&self) -> Result<(), SceneError> {
        let Some(r) = &self.reduced else { return Ok(()) };
        if !(1..=MAX_REDUCED_R).contains(&r.r) {
            return Err(self.err("reduced.r", format!("{}: must be in 1..={MAX_REDUCED_R}", r.r)));
        }
        if !(r.alpha.is_finite() && (0.0..=1e4).contains(&r.alpha)) {
            return Err(self.err("reduced.alpha", format!("{}: must be in [0, 1e4] 1/s", r.alpha)));
        }
        if !(r.beta.is_finite() && (0.0..=1.0).contains(&r.beta)) {
            return Err(self.err("reduced.beta", format!("{}: must be in [0, 1] s", r.beta)));
        }
        if r.contact_modes && r.contact_region.is_none() {
            return Err(self.err(
                "reduced.contact_region",
                "contact_modes = true needs a contact_region ({ center, radius } and/or set)",
            ));
        }
        if let Some(c) = &r.contact_region {
            let key = "reduced.contact_region";
            if c.center.is_some() != c.radius.is_some() {
                return Err(self.err(key, "give center and radius together"));
            }
            if c.center.is_none() && c.set.is_none() {
                return Err(self.err(key, "give a sphere ({ center, radius }), a set, or both"));
            }
            if c.center.is_some_and(|p| p.iter().any(|v| !v.is_finite())) {
                return Err(self.err(&format!("{key}.center"), "must be finite (m)"));
            }
            if let Some(rad) = c.radius {
                if !(rad.is_finite() && rad > 0.0) {
                    return Err(self.err(&format!("{key}.radius"), format!("{rad}: must be finite and > 0 (m)")));
                }
            }
        }
        let c = self.checker();
        c.f64_in("reduced.couple_radius_m", r.couple_radius_m, 5e-4, 0.05, "m")?;
        c.f64_in(
            "reduced.separation_m",
            r.separation_m,
            2.0 * r.couple_radius_m,
            0.5,
            "m (at least 2 couple_radius_m)",
        )?;
        if r.cache_dir.as_ref().is_some_and(|d| d.as_os_str().is_empty()) {
            return Err(self.err("reduced.cache_dir", "must not be empty"));
        }
        Ok(())
    }

    fn validate_roi(&self) -> Result<(), SceneError> {
        let Some(roi) = &self.roi else { return Ok(()) };
        let kinds = roi.aabb.is_some() as u8 + roi.sphere.is_some() as u8 + roi.arclength.is_some() as u8;
        if kinds != 1 {
            return Err(self.err("roi", "give exactly one of box, sphere, arclength"));
        }
        if let Some(b) = &roi.aabb {
            if b.min.iter().chain(&b.max).any(|v| !v.is_finite()) || (0..3).any(|k| b.min[k] >= b.max[k]) {
                return Err(self.err("roi.box", "min and max must be finite with min < max (m)"));
            }
        }
        if let Some(sp) = &roi.sphere {
            if sp.center.iter().any(|v| !v.is_finite()) {
                return Err(self.err("roi.sphere.center", "must be finite (m)"));
            }
            if !(sp.radius.is_finite() && sp.radius > 0.0) {
                return Err(self.err(
                    "roi.sphere.radius",
                    format!("{}: must be finite and > 0 (m)", sp.radius),
                ));
            }
        }
        if let Some([s0, s1]) = roi.arclength {
            if self.mesh.arch_nodes.is_none() {
                return Err(self.err("roi.arclength", "only for the built-in arch (mesh.arch_nodes)"));
            }
            if self.mesh.arch_branches == Some(ArchBranches::Three) {
                return Err(self.err(
                    "roi.arclength",
                    "only for the unbranched built-in arch (mesh.arch_branches = \"three\" is set): use roi.box or roi.sphere",
                ));
            }
            if !(s0.is_finite() && s1.is_finite() && s0 >= 0.0 && s0 < s1) {
                return Err(self.err("roi.arclength", format!("[{s0}, {s1}]: need 0 <= s0 < s1 (m)")));
            }
        }
        Ok(())
    }
}
