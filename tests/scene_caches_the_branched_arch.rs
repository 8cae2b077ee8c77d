//! `[mesh] arch_nodes = N` with `arch_branches = "three"`: the branched
//! built-in arch is meshed once and cached on disk under a key of the
//! mesher's version tag and its options, so a restart of the service does
//! not mesh it again; a second load is a cache hit with the same mesh, a
//! changed node count is a new key, a corrupt file is meshed again and
//! replaced, and a cache that cannot be written is reported, not fatal.

use nvtmm::mesh::vessel::branched::{branched_arch, default_wall_ratio};
use nvtmm::mesh::vessel::implicit::BranchedArchParams;
use nvtmm::scene::Scene;
use std::path::Path;

fn scene(dir: &Path, nodes: usize, cache_dir: &str) -> Scene {
    let text = format!(
        r#"
model = "nvtmm"
duration = 0.01
[mesh]
arch_nodes = {nodes}
arch_branches = "three"
[material]
youngs_pa = 1e5
poisson = 0.4
[fixed]
sets = ["inlet", "outlet_descending"]
[reduced]
r = 4
cache_dir = "{cache_dir}"
"#
    );
    let p = dir.join("scene.toml");
    std::fs::write(&p, text).unwrap();
    Scene::load(&p).unwrap()
}

fn same(a: &nvtmm::mesh::TetMesh, b: &nvtmm::mesh::TetMesh) {
    // Bitwise: the basis cache's key hashes the rest positions, so a mesh
    // read back from the cache must be the mesh that was meshed.
    assert_eq!(a.rest(), b.rest());
    assert_eq!(a.tets(), b.tets());
    assert_eq!(a.node_sets(), b.node_sets());
    assert_eq!(a.segment_labels(), b.segment_labels());
}

#[test]
fn branched_arch_scene_meshes_once_then_hits_the_cache() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");

    // Miss: meshed and stored.
    let s = scene(dir.path(), 1458, "cache");
    let first = s.branched_arch_mesh().unwrap();
    assert!(!first.cache_hit);
    assert_eq!(first.cache_error, None);
    assert!(first.path.starts_with(&cache), "{:?}", first.path);
    assert!(first.path.exists());
    let params = BranchedArchParams::default();
    let direct = branched_arch(&params, 1458, 1, default_wall_ratio(&params)).unwrap();
    same(&first.mesh, &direct.wall.mesh);
    // Only the cache file is left (the temporary one was renamed).
    assert_eq!(std::fs::read_dir(&cache).unwrap().count(), 1);

    // Hit: the same mesh, bit for bit, and build_mesh goes through it.
    let s2 = scene(dir.path(), 1458, "cache");
    let second = s2.branched_arch_mesh().unwrap();
    assert!(second.cache_hit);
    assert_eq!(second.path, first.path);
    same(&second.mesh, &first.mesh);
    same(&s2.build_mesh().unwrap(), &first.mesh);

    // Another node count is another key.
    let other = scene(dir.path(), 1600, "cache");
    assert_ne!(other.branched_arch_key().unwrap(), s.branched_arch_key().unwrap());
    let third = other.branched_arch_mesh().unwrap();
    assert!(!third.cache_hit);
    assert_ne!(third.path, first.path);
    assert_ne!(third.mesh.num_nodes(), first.mesh.num_nodes());

    // A corrupt (here: truncated) cache file is meshed again and replaced.
    let text = std::fs::read(&first.path).unwrap();
    std::fs::write(&first.path, &text[..text.len() / 2]).unwrap();
    let fourth = scene(dir.path(), 1458, "cache").branched_arch_mesh().unwrap();
    assert!(!fourth.cache_hit);
    assert_eq!(fourth.cache_error, None);
    same(&fourth.mesh, &first.mesh);
    let fifth = scene(dir.path(), 1458, "cache").branched_arch_mesh().unwrap();
    assert!(fifth.cache_hit, "the corrupt file was replaced");
    same(&fifth.mesh, &first.mesh);
}

#[test]
fn branched_arch_scene_reports_a_cache_it_cannot_write() {
    let dir = tempfile::tempdir().unwrap();
    // The cache directory's path is a file: nothing can be stored there.
    std::fs::write(dir.path().join("blocked"), b"a file").unwrap();
    let s = scene(dir.path(), 1458, "blocked");
    let b = s.branched_arch_mesh().unwrap();
    assert!(!b.cache_hit);
    let e = b.cache_error.expect("the cache error is reported");
    println!("{e}");
    assert!(e.contains("blocked"), "{e}");
    assert_eq!(b.mesh.report().inverted, 0);
    // The scene still builds its mesh.
    assert_eq!(s.build_mesh().unwrap().num_nodes(), b.mesh.num_nodes());
}
