//! The basis cache: a stored basis loads back bit for bit; a corrupt,
//! truncated or foreign file is reported and recomputed (never a panic);
//! another request (r, contact nodes) gets another key; `nvtmm basis` runs on
//! a scene and the second run is a cache hit.

use nvtmm::material::{Law, Material};
use nvtmm::mesh::block::block;
use nvtmm::model::tmm::Tmm;
use nvtmm::reduced::cache::{cache_path, load_or_compute, BasisRequest, CacheStatus, Pressurized};
use nvtmm::reduced::BasisParams;
use std::process::Command;

#[test]
fn cache_round_trip_and_corrupt_file_recovery() {
    let mesh = block([4, 2, 2], [0.04, 0.01, 0.01]).unwrap();
    let mat = Material::aorta();
    let model = Tmm::new(&mesh, &mat);
    let mass = mesh.lumped_mass(mat.density);
    let fixed = mesh.node_set("x_min").unwrap().to_vec();
    let contact = mesh.node_set("x_max").unwrap()[..2].to_vec();
    let req = BasisRequest {
        mesh: &mesh,
        model: &model,
        material: mat,
        law: Law::Stvk,
        mass: &mass,
        fixed: &fixed,
        r: 8,
        contact: &contact,
        max_static: 4,
        params: BasisParams::default(),
        pressurized: None,
    };
    let dir = tempfile::tempdir().unwrap();
    let (b1, o1) = load_or_compute(&req, Some(dir.path()), false).unwrap();
    assert_eq!(o1.status, CacheStatus::Computed);
    assert_eq!(o1.store_error, None);
    assert_eq!(b1.len(), 8);
    assert_eq!(b1.num_static, 4);
    let path = cache_path(dir.path(), req.key());
    assert!(path.exists());
    // No temporary file is left behind.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);

    let (b2, o2) = load_or_compute(&req, Some(dir.path()), false).unwrap();
    assert_eq!(o2.status, CacheStatus::Hit);
    assert_eq!(b1, b2, "the cached basis is the computed one, bit for bit");

    // Corrupt one byte of phi: reported, recomputed, rewritten.
    let mut bytes = std::fs::read(&path).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0xFF;
    std::fs::write(&path, &bytes).unwrap();
    let (b3, o3) = load_or_compute(&req, Some(dir.path()), false).unwrap();
    assert!(
        matches!(&o3.status, CacheStatus::Recomputed(why) if why.contains("checksum")),
        "{:?}",
        o3.status
    );
    assert_eq!(b3, b1);
    assert_eq!(
        load_or_compute(&req, Some(dir.path()), false).unwrap().1.status,
        CacheStatus::Hit
    );

    // Truncated, empty, and garbage files.
    let good = std::fs::read(&path).unwrap();
    for bad in [
        good[..good.len() - 9].to_vec(),
        Vec::new(),
        b"not a basis file at all".to_vec(),
    ] {
        std::fs::write(&path, &bad).unwrap();
        let (b, o) = load_or_compute(&req, Some(dir.path()), false).unwrap();
        assert!(matches!(o.status, CacheStatus::Recomputed(_)), "{:?}", o.status);
        assert_eq!(b, b1);
    }

    // A file stored under this key by another request (renamed by hand) is refused.
    let other = BasisRequest { r: 6, ..req };
    assert_ne!(other.key(), req.key());
    let (_, oo) = load_or_compute(&other, Some(dir.path()), false).unwrap();
    assert_eq!(oo.status, CacheStatus::Computed);
    std::fs::copy(cache_path(dir.path(), other.key()), &path).unwrap();
    let (b, o) = load_or_compute(&req, Some(dir.path()), false).unwrap();
    assert!(
        matches!(&o.status, CacheStatus::Recomputed(why) if why.contains("key")),
        "{:?}",
        o.status
    );
    assert_eq!(b, b1);

    // The key depends on the contact nodes and on the mesh.
    let c2 = [contact[0]];
    assert_ne!(BasisRequest { contact: &c2, ..other }.key(), other.key());
    // A basis linearized about a pressurized state is another basis, and
    // so is one at another pressure or another state's tangent.
    let mut k = nvtmm::model::BlockTangent::zeros(&mesh);
    nvtmm::model::ForceModel::add_stiffness(&model, &vec![nvtmm::math::Vec3::zeros(); mesh.num_nodes()], &mut k);
    let at = |mean_pa: f64, k| BasisRequest {
        pressurized: Some(Pressurized { mean_pa, tangent: k }),
        ..req
    };
    assert_ne!(at(1e4, &k).key(), req.key());
    assert_ne!(at(1e4, &k).key(), at(1.2e4, &k).key());
    let mut k2 = k.clone();
    k2.diag[0][(0, 0)] *= 1.01;
    assert_ne!(at(1e4, &k).key(), at(1e4, &k2).key());
    assert_eq!(at(1e4, &k).key(), at(1e4, &k.clone()).key());
    // force recomputes; no cache dir means no file.
    assert_eq!(
        load_or_compute(&req, Some(dir.path()), true).unwrap().1.status,
        CacheStatus::Bypassed
    );
    let (_, off) = load_or_compute(&req, None, false).unwrap();
    assert_eq!((off.status, off.path), (CacheStatus::Bypassed, None));
}

#[test]
fn basis_command_computes_then_hits_the_cache() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("s.toml");
    std::fs::write(
        &scene,
        r#"
model = "nvtmm"
duration = 0.01
[mesh]
block = { cells = [4, 2, 2], size = [0.04, 0.01, 0.01] }
[material]
youngs_pa = 65e3
poisson = 0.45
[fixed]
sets = ["x_min"]
[reduced]
r = 8
contact_modes = true
contact_region = { center = [0.04, 0.0, 0.0], radius = 0.006, set = "x_max" }
cache_dir = "cache"
"#,
    )
    .unwrap();
    let run = |extra: &[&str]| {
        let out = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
            .arg("basis")
            .arg(&scene)
            .args(extra)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let first = run(&[]);
    assert!(first.contains("computed"), "{first}");
    assert!(first.contains("8 vectors"), "{first}");
    let second = run(&[]);
    assert!(second.contains("loaded from the cache"), "{second}");
    let forced = run(&["--force", "--r", "6"]);
    assert!(
        forced.contains("6 vectors") && forced.contains("cache not read"),
        "{forced}"
    );
    assert_eq!(std::fs::read_dir(dir.path().join("cache")).unwrap().count(), 2);
    // A bad r is an error naming the range, not a panic.
    let out = Command::new(env!("CARGO_BIN_EXE_nvtmm"))
        .args(["basis", scene.to_str().unwrap(), "--r", "65"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("1..=64") && !err.contains("panicked"), "{err}");
}
