//! An application that embeds the service (the C ABI in capi/ is one) does
//! not pull the tools' crates: `nvtmm-capi` depends on nvtmm without the
//! feature `tools`, so neither plotters nor indicatif is in its tree of
//! normal dependencies. Runs `cargo tree` offline (the lockfile and the
//! registry cache the build used).

use std::process::Command;

#[test]
fn embedding_pulls_no_tools() {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let root = env!("CARGO_MANIFEST_DIR");
    let tree = |package: &str| {
        let out = Command::new(&cargo)
            .current_dir(root)
            .args(["tree", "--offline", "-p", package, "-e", "normal", "--prefix", "none"])
            .output()
            .expect("cargo tree runs");
        assert!(
            out.status.success(),
            "cargo tree -p {package}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let has = |tree: &str, krate: &str| tree.lines().any(|l| l.split(' ').next() == Some(krate));
    let capi = tree("nvtmm-capi");
    assert!(has(&capi, "nvtmm"), "nvtmm-capi's tree lacks nvtmm:\n{capi}");
    for krate in ["plotters", "indicatif"] {
        assert!(
            !has(&capi, krate),
            "nvtmm-capi pulls {krate}: depend on nvtmm with default-features = false"
        );
    }
    // The check has teeth: the default build (with `tools`) has both.
    let full = tree("nvtmm");
    assert!(has(&full, "plotters") && has(&full, "indicatif"), "{full}");
}
