//! The human aorta scene (rt-config/scenes/aorta_pressure.toml): over one
//! heartbeat, from diastolic to systolic pressure, the lumen diameter of
//! the descending aorta grows by 5–15 %, the range measured in healthy
//! adults (Redheuil et al., Hypertension 2010; docs/PRESSURE.md). The wall
//! is the scene's, its reference the zero-pressure geometry of the imaged
//! mesh at the mean pressure, inflated statically (a heartbeat is slow for
//! the wall's own dynamics). The arch is meshed as in the scene (1458
//! nodes).

use nvtmm::math::Vec3;
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::scene::Scene;
use nvtmm::solver::statics::StaticParams;
use nvtmm::solver::unload::{UnloadParams, UnloadRequest};
use std::path::Path;

#[test]
fn aorta_scene_distends_five_to_fifteen_percent_over_a_heartbeat() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("rt-config/scenes/aorta_pressure.toml");
    let scene = Scene::load(&path).unwrap();
    let p = scene.pressure.clone().expect("the scene has [pressure]");
    let wave = p.waveform.expect("the scene has a waveform");
    let nodes = scene.mesh.arch_nodes.expect("the scene uses the built-in arch");
    let arch = generate(&ArchParams::default(), nodes).unwrap();
    let image = &arch.mesh;
    let mut fixed: Vec<u32> = scene
        .fixed
        .sets
        .iter()
        .flat_map(|s| image.node_set(s).unwrap().to_vec())
        .collect();
    fixed.sort_unstable();
    fixed.dedup();
    let req = UnloadRequest {
        image,
        kind: scene.model,
        material: scene.material(),
        law: scene.material.law,
        set: &p.set,
        pressure_pa: p.schedule().mean_pa,
        fixed: &fixed,
        params: UnloadParams::default(),
    };
    let reference = req.solve().unwrap().mesh;
    // A ring a quarter of the way up the descending aorta.
    let ring = arch.grid.axial / 6;
    let inner: Vec<usize> = (0..arch.grid.circumferential).map(|c| arch.node(ring, c, 0)).collect();
    let diameter = |x: &dyn Fn(usize) -> Vec3| {
        let c = inner.iter().map(|&i| x(i)).sum::<Vec3>() / inner.len() as f64;
        2.0 * inner.iter().map(|&i| (x(i) - c).norm()).sum::<f64>() / inner.len() as f64
    };
    let inflated = |pa: f64| {
        let r = UnloadRequest { pressure_pa: pa, ..req };
        let mut u = vec![Vec3::zeros(); image.num_nodes()];
        r.inflate(&reference, &StaticParams::default(), &mut u).unwrap();
        diameter(&|i| reference.rest()[i] + u[i])
    };
    let d_dia = inflated(wave.diastolic_pa);
    let d_sys = inflated(wave.systolic_pa);
    let d_img = diameter(&|i| image.rest()[i]);
    let d_ref = diameter(&|i| reference.rest()[i]);
    let strain = (d_sys - d_dia) / d_dia;
    println!(
        "diameter: zero-pressure {:.2} mm, diastolic {:.2} mm, image (mean) {:.2} mm, systolic {:.2} mm: {:.1} % over the beat",
        d_ref * 1e3,
        d_dia * 1e3,
        d_img * 1e3,
        d_sys * 1e3,
        100.0 * strain
    );
    assert!(d_dia < d_img && d_img < d_sys);
    assert!((0.05..=0.15).contains(&strain), "{:.1} %", 100.0 * strain);
}
