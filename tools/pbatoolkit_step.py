#!/usr/bin/env python3
"""Times pbatoolkit doing nvtmm's backward-Euler Newton step, next to `nvtmm bench step`.

The step is the one `nvtmm bench step` takes (src/bench/mod.rs, the
"standard load"; docs/BENCHMARKS.md):

- the built-in arch exported by `nvtmm mesh arch --nodes N --out F.vtu`
  (node sets as `set_<name>` point data), P1 tets, StVK, E = 65 kPa,
  nu = 0.45, rho = 1050 kg/m^3 (`Material::aorta`), lumped mass rho V / 4
  per node;
- both rings fixed (`inlet`, `outlet_descending`: their DOFs removed);
- 0.15 N along -z shared by the outer-wall nodes within 5 mm of the
  highest outer-wall node, ramped in over 20 ms;
- dt = 1 ms, Rayleigh alpha = 0, beta = 1e-3, one Newton iteration from
  v1 = 0 (the linearised step):
      (M + (h beta + h^2) K(u0)) v1 = M v0 + h (f(u0) + f_ext(t0 + h)),
      u1 = u0 + h v1,
  with f = -dW/du and K = dW^2/du^2 from pbatoolkit
  (`fem.hyper_elastic_potential`, SaintVenantKirchhoff, no SPD correction)
  and pbatoolkit's own sparse LDLT (`math.linalg.ldlt`: Eigen's simplicial
  LDLT with AMD ordering; the symbolic analysis is done once, the numeric
  factorization every step, as nvtmm's Cholesky does).

5 warm-up steps, then --steps timed ones (the median is reported), exactly
as `nvtmm bench step`; the loaded node's displacement at the end is printed
for both, so a reader can see that the two codes took the same steps.

Needs: `pip install pbatoolkit meshio` (numpy and scipy come with them) and
a release build of nvtmm (`cargo build --release`). Not part of `cargo test`.

Usage:
    tools/pbatoolkit_step.py --nodes 5832 [--steps 10] [--nvtmm target/release/nvtmm]
"""

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

# Must match src/bench/mod.rs and src/material.rs.
YOUNGS_PA = 65e3
POISSON = 0.45
DENSITY = 1050.0
DT = 1e-3
BETA = 1e-3
FORCE_N = 0.15
PROBE_RADIUS_M = 5e-3
RAMP_S = 0.02
WARMUP = 5


def fail(msg):
    print(f"pbatoolkit_step.py: {msg}", file=sys.stderr)
    sys.exit(2)


def load_modules():
    try:
        import numpy as np
        import scipy.sparse as sps
        import meshio
        from pbatoolkit import pbat, pypbat
    except ImportError as e:
        fail(f"{e}: install with `pip install pbatoolkit meshio`")
    return np, sps, meshio, (pbat, pypbat)


def export_mesh(nvtmm, nodes, out):
    cmd = [nvtmm, "mesh", "arch", "--nodes", str(nodes), "--out", out]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        fail(f"`{' '.join(cmd)}` failed: {r.stderr.strip()}")


def node_set(np, mesh, name, path):
    key = f"set_{name}"
    if key not in mesh.point_data:
        fail(f"{path}: no node set `{name}` (point data `{key}`)")
    return np.flatnonzero(np.asarray(mesh.point_data[key]).reshape(-1) != 0)


def pbat_steps(nodes, steps, mesh_path):
    """Runs WARMUP + steps linearised steps with pbatoolkit; returns a dict."""
    np, sps, meshio, (pbat, pypbat) = load_modules()
    fem = pbat.fem
    m = meshio.read(mesh_path)
    tets = [c.data for c in m.cells if c.type == "tetra"]
    if not tets:
        fail(f"{mesh_path}: no tetrahedra")
    X = np.asfortranarray(np.asarray(m.points, dtype=np.float64).T)  # 3 x n
    E = np.asfortranarray(np.vstack(tets).astype(np.int64).T)  # 4 x m
    n = X.shape[1]
    fixed = np.union1d(node_set(np, m, "inlet", mesh_path), node_set(np, m, "outlet_descending", mesh_path))
    outer = node_set(np, m, "outer_wall", mesh_path)
    # The arch top: the outer-wall node of highest z (ties: the last one, as
    # Rust's max_by does).
    zs = X[2, outer]
    top = outer[len(zs) - 1 - int(np.argmax(zs[::-1]))]
    patch = outer[np.linalg.norm(X[:, outer] - X[:, [top]], axis=0) <= PROBE_RADIUS_M]
    if len(patch) == 0:
        patch = np.array([top])

    element = fem.Element.Tetrahedron
    t_setup = time.perf_counter()
    wg = fem.mesh_quadrature_weights(E, X, element, order=1, quadrature_order=1)
    eg = fem.mesh_quadrature_elements(E, wg)
    GNeg = fem.shape_function_gradients(E, X, element=element, order=1, dims=3, quadrature_order=1)
    mu = YOUNGS_PA / (2 * (1 + POISSON))
    lam = YOUNGS_PA * POISSON / ((1 + POISSON) * (1 - 2 * POISSON))
    mug = np.full(wg.size, mu)
    lamg = np.full(wg.size, lam)
    # Lumped mass rho V / 4 per node, as TetMesh::lumped_mass.
    vol = np.ravel(wg)  # one quadrature point per tet: its weight is V
    mnode = np.zeros(n)
    np.add.at(mnode, E.reshape(-1, order="F"), np.repeat(DENSITY * vol / 4.0, 4))
    mdof = np.repeat(mnode, 3)  # x is ravel(X, order="F"): (x0, y0, z0, x1, ...)
    free_nodes = np.setdiff1d(np.arange(n), fixed)
    free = (3 * free_nodes[:, None] + np.arange(3)[None, :]).reshape(-1)
    fext_dir = np.zeros(3 * n)
    for p in patch:
        fext_dir[3 * p + 2] = -FORCE_N / len(patch)
    flags = fem.ElementElasticityComputationFlags.Gradient | fem.ElementElasticityComputationFlags.Hessian
    x0 = np.ravel(X, order="F")
    u = np.zeros(3 * n)
    v = np.zeros(3 * n)
    solver = None
    setup_s = time.perf_counter() - t_setup

    parts = {"grad_hess": [], "assemble": [], "factor": [], "solve": []}
    total = []
    t = 0.0
    for step in range(WARMUP + steps):
        t1 = t + DT
        s = min(1.0, max(0.0, t1 / RAMP_S))
        a = time.perf_counter()
        _, grad, H = fem.hyper_elastic_potential(
            E,
            n,
            eg=np.ravel(eg),
            wg=np.ravel(wg),
            GNeg=GNeg,
            mug=mug,
            lambdag=lamg,
            x=x0 + u,
            energy=fem.HyperElasticEnergy.SaintVenantKirchhoff,
            flags=flags,
            spd_correction=fem.HyperElasticSpdCorrection.NoCorrection,
            element=element,
            order=1,
            dims=3,
        )
        b = time.perf_counter()
        A = (H * (DT * BETA + DT * DT) + sps.diags(mdof)).tocsc()[free][:, free]
        rhs = mdof * v + DT * (-grad + s * fext_dir)
        c = time.perf_counter()
        if solver is None:
            solver = pypbat.math.linalg.ldlt(A)
            solver.analyze(A)
        solver.factorize(A)
        d = time.perf_counter()
        v_free = solver.solve(rhs[free])
        v = np.zeros(3 * n)
        v[free] = v_free
        u = u + DT * v
        e = time.perf_counter()
        if not np.all(np.isfinite(u)):
            fail(f"pbatoolkit step {step + 1}: non-finite displacement")
        t = t1
        if step >= WARMUP:
            parts["grad_hess"].append(b - a)
            parts["assemble"].append(c - b)
            parts["factor"].append(d - c)
            parts["solve"].append(e - d)
            total.append(e - a)
    med = lambda xs: float(np.median(xs)) * 1e3  # noqa: E731
    return {
        "nodes": n,
        "tets": E.shape[1],
        "free_dofs": len(free),
        "patch_nodes": len(patch),
        "setup_s": setup_s,
        "ms_per_step": med(total),
        "mean_ms_per_step": float(np.mean(total)) * 1e3,
        "ms_grad_hess": med(parts["grad_hess"]),
        "ms_assemble": med(parts["assemble"]),
        "ms_factor": med(parts["factor"]),
        "ms_solve": med(parts["solve"]),
        "load_node_displacement_m": float(np.linalg.norm(u[3 * top : 3 * top + 3])),
        "version": pbat_version(),
    }


def pbat_version():
    try:
        from importlib.metadata import version

        return version("pbatoolkit")
    except Exception:  # noqa: BLE001
        return "unknown"


def nvtmm_step(nvtmm, nodes, steps, model, linear):
    cmd = [nvtmm, "bench", "step", "--model", model, "--nodes", str(nodes), "--steps", str(steps), "--json"]
    if linear:
        cmd += ["--linear", linear]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        fail(f"`{' '.join(cmd)}` failed: {r.stderr.strip()}")
    return json.loads(r.stdout)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nodes", type=int, default=5832, help="arch size asked of `nvtmm mesh arch`")
    ap.add_argument("--steps", type=int, default=10, help="timed steps (after 5 warm-up steps)")
    ap.add_argument("--nvtmm", default=None, help="nvtmm binary (default: target/release/nvtmm)")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    a = ap.parse_args()
    if a.steps < 1:
        fail("--steps must be at least 1")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    nvtmm = a.nvtmm or os.path.join(root, "target", "release", "nvtmm")
    if not os.access(nvtmm, os.X_OK):
        fail(f"{nvtmm}: not an executable (build with `cargo build --release` or pass --nvtmm)")
    load_modules()
    with tempfile.TemporaryDirectory() as d:
        mesh_path = os.path.join(d, f"arch{a.nodes}.vtu")
        export_mesh(nvtmm, a.nodes, mesh_path)
        pb = pbat_steps(a.nodes, a.steps, mesh_path)
    # nvtmm on the same mesh, load and step: the element FEM and NVTMM with a
    # direct sparse Cholesky every step (pbatoolkit's setting), and NVTMM
    # with the fastest exact solver (`bench step`'s default).
    rows = [
        ("fem", "cholesky"),
        ("nvtmm", "cholesky"),
        ("nvtmm", None),
    ]
    nv = [(m, l, nvtmm_step(nvtmm, a.nodes, a.steps, m, l)) for m, l in rows]
    out = {
        "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
        "machine": f"{platform.machine()} {os.cpu_count()} CPUs, {platform.platform()}",
        "load_average": os.getloadavg(),
        "pbatoolkit": pb,
        "nvtmm": [
            {
                "model": m,
                "linear": j["linear"],
                "ms_per_step": j["ms_per_step"],
                "mean_ms_per_step": j["mean_ms_per_step"],
                "load_node_displacement_m": j["load_node_displacement_m"],
                "pbatoolkit_over_nvtmm": pb["ms_per_step"] / j["ms_per_step"],
                "displacement_rel_diff": abs(j["load_node_displacement_m"] - pb["load_node_displacement_m"])
                / max(pb["load_node_displacement_m"], 1e-300),
            }
            for m, l, j in nv
        ],
    }
    if a.json:
        print(json.dumps(out))
        return
    print(f"{out['date_utc']} UTC, {out['machine']}, load average {out['load_average'][0]:.2f}")
    print(
        f"mesh: {pb['nodes']} nodes, {pb['tets']} tets, {pb['free_dofs']} free DOFs, "
        f"{pb['patch_nodes']} loaded nodes; {WARMUP} warm-up + {a.steps} timed steps of {DT * 1e3:g} ms"
    )
    print()
    print(
        "| code | model | linear solve | median ms/step | mean ms/step | loaded node (mm) "
        "| vs pbatoolkit's (rel.) | pbatoolkit / this (median) |"
    )
    print("|---|---|---|---:|---:|---:|---:|---:|")
    print(
        f"| pbatoolkit {pb['version']} | FEM StVK | Eigen simplicial LDLT (AMD) | {pb['ms_per_step']:.1f} | "
        f"{pb['mean_ms_per_step']:.1f} | {pb['load_node_displacement_m'] * 1e3:.6f} | – | 1.00 |"
    )
    for r in out["nvtmm"]:
        print(
            f"| nvtmm | {r['model']} | {r['linear']} | {r['ms_per_step']:.1f} | {r['mean_ms_per_step']:.1f} | "
            f"{r['load_node_displacement_m'] * 1e3:.6f} | {r['displacement_rel_diff']:.1e} | {r['pbatoolkit_over_nvtmm']:.1f} |"
        )
    print()
    print(
        f"pbatoolkit median parts (ms): gradient + Hessian {pb['ms_grad_hess']:.1f}, "
        f"A = M + (h beta + h^2) K and free-DOF slice {pb['ms_assemble']:.1f}, "
        f"LDLT factorization {pb['ms_factor']:.1f}, solve {pb['ms_solve']:.1f}"
    )


if __name__ == "__main__":
    main()
