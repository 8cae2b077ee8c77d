//! A small guidewire service for the guidewire tests: a branched arch of
//! about 2000 nodes written to `dir`, r = 16 without static modes, the
//! scripted hand inserting the wire up the descending aorta.

use std::path::{Path, PathBuf};

/// Writes the mesh, the scene and the service configuration into `dir`;
/// returns the configuration's path. `script` rows are
/// `[time s, inserted m, roll rad]`; `load_wall`: the wire's contact
/// forces load the vessel.
pub fn write(dir: &Path, seconds: f64, script: &str, load_wall: bool) -> PathBuf {
    use nvtmm::mesh::vessel::branched::{branched_arch, default_wall_ratio};
    use nvtmm::mesh::vessel::implicit::BranchedArchParams;
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let params = BranchedArchParams::default();
    let arch = branched_arch(&params, 2000, 1, default_wall_ratio(&params)).expect("branched arch");
    nvtmm::mesh::io::write_mesh(&arch.wall.mesh, &dir.join("arch.vtu")).expect("mesh written");
    std::fs::write(
        dir.join("scene.toml"),
        format!(
            r#"model = "nvtmm"
duration = 1.0
[mesh]
file = "arch.vtu"
[material]
youngs_pa = 65e3
poisson = 0.45
[fixed]
sets = ["inlet", "outlet_descending", "outlet_brachiocephalic", "outlet_left_common_carotid", "outlet_left_subclavian"]
[integrator]
dt = 1e-2
newton = {{ max_iters = 1 }}
linear = {{ kind = "cholesky_pcg", tol = 1e-6, refactor_every = 3, factor_f32 = true }}
[reduced]
r = 16
contact_modes = false
cache_dir = "{}"
"#,
            dir.join("cache").display()
        ),
    )
    .unwrap();
    let guide = std::fs::read_to_string(root.join("rt-config/guidewire.toml")).unwrap();
    // The shipped scenario's [wire], [wire.drive] and [device.frame], with
    // this scene, a short run and the given script.
    let wire_part = &guide[guide.find("[wire]").unwrap()..guide.find("[guidewire]").unwrap()];
    let frame_part = &guide[guide.find("[device.frame]").unwrap()..guide.find("[contact]").unwrap()];
    let cfg = format!(
        r#"scene = "scene.toml"
seconds = {seconds}
[loop]
baseline_s = 0.2
[device]
touchx = "{touchx}"
{frame_part}
[stream]
enabled = false
[background]
basis_refresh_s = 0.0
[rings]
contact = 4096
{wire_part}
[guidewire]
access_point_m = [0.0011, 0.0, 0.0049]
axis = [0.216, 0.0, 0.976]
inserted_m = 0.02
load_wall = {load_wall}
script = {script}
"#,
        touchx = root.join("rt-config/touchx.toml").display()
    );
    let path = dir.join("guidewire.toml");
    std::fs::write(&path, cfg).unwrap();
    path
}
