use nvtmm::material::{dpk1, pk1, Law, Material};
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::mesh::Vec3;
use nvtmm::model::nvtmm::Nvtmm;
use nvtmm::model::{BlockTangent, ForceModel, Mat3};
use rayon::prelude::*;
use std::time::Instant;
fn main() {
    let n: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(23328);
    let mesh = generate(&ArchParams::default(), n).unwrap().mesh;
    let mat = Material::aorta();
    let t = Instant::now();
    let m = Nvtmm::new(&mesh, &mat);
    println!(
        "precompute {:.3}s counts {:?} MB {:.1}",
        t.elapsed().as_secs_f64(),
        m.tensor_counts(),
        m.tensor_bytes() as f64 / 1e6
    );
    let u: Vec<Vec3> = mesh
        .rest()
        .iter()
        .map(|x| Vec3::new(0.01 * x.z, 0.0, 0.02 * x.x))
        .collect();
    let mut f = vec![Vec3::zeros(); mesh.num_nodes()];
    let reps = 10;
    let t = Instant::now();
    for _ in 0..reps {
        m.add_forces(&u, &mut f);
    }
    println!("nvtmm force {:.3} ms", t.elapsed().as_secs_f64() * 1e3 / reps as f64);
    let mut k = BlockTangent::zeros(&mesh);
    let t = Instant::now();
    for _ in 0..reps {
        k.clear();
        m.add_stiffness(&u, &mut k);
    }
    println!(
        "nvtmm stiffness {:.3} ms",
        t.elapsed().as_secs_f64() * 1e3 / reps as f64
    );
    let t = Instant::now();
    for _ in 0..reps {
        m.add_df(&u, &u, &mut f);
    }
    println!("nvtmm df {:.3} ms", t.elapsed().as_secs_f64() * 1e3 / reps as f64);
    let t = Instant::now();
    for _ in 0..reps {
        k.mul(&u, &mut f);
    }
    println!("block matvec {:.3} ms", t.elapsed().as_secs_f64() * 1e3 / reps as f64);
    let l = mat.lame();
    let t = Instant::now();
    for _ in 0..reps {
        let per: Vec<[Vec3; 4]> = mesh
            .tets()
            .par_iter()
            .enumerate()
            .map(|(e, tet)| {
                let g = &mesh.grads()[e];
                let mut fm = Mat3::identity();
                for k in 0..4 {
                    fm += u[tet[k] as usize] * g[k].transpose();
                }
                let p = pk1(Law::Stvk, l, &fm) * mesh.volumes()[e];
                g.map(|d| -(p * d))
            })
            .collect();
        for (e, tet) in mesh.tets().iter().enumerate() {
            for k in 0..4 {
                f[tet[k] as usize] += per[e][k];
            }
        }
    }
    println!("element force {:.3} ms", t.elapsed().as_secs_f64() * 1e3 / reps as f64);
    let t = Instant::now();
    for _ in 0..reps {
        let per: Vec<[[Mat3; 4]; 4]> = mesh
            .tets()
            .par_iter()
            .enumerate()
            .map(|(e, tet)| {
                let g = &mesh.grads()[e];
                let mut fm = Mat3::identity();
                for k in 0..4 {
                    fm += u[tet[k] as usize] * g[k].transpose();
                }
                let mut kk = [[Mat3::zeros(); 4]; 4];
                for q in 0..4 {
                    for b in 0..3 {
                        let mut df = Mat3::zeros();
                        df.set_row(b, &g[q].transpose());
                        let dp = dpk1(Law::Stvk, l, &fm, &df) * mesh.volumes()[e];
                        for p in 0..4 {
                            let c = dp * g[p];
                            kk[p][q].set_column(b, &c);
                        }
                    }
                }
                kk
            })
            .collect();
        k.clear();
        for (e, tet) in mesh.tets().iter().enumerate() {
            let te = &mesh.tet_edges()[e];
            for p in 0..4 {
                k.diag[tet[p] as usize] += per[e][p][p];
            }
            for (ei, [i, j]) in nvtmm::mesh::TET_EDGE_LOCAL.iter().enumerate() {
                let m = if tet[*i] < tet[*j] {
                    per[e][*i][*j]
                } else {
                    per[e][*j][*i]
                };
                k.off[te[ei] as usize] += m;
            }
        }
    }
    println!(
        "element stiffness {:.3} ms",
        t.elapsed().as_secs_f64() * 1e3 / reps as f64
    );
}
