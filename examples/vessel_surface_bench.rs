//! Writes a segmentation-like lumen surface for the `mesh vessel`
//! benchmark (docs/BENCHMARKS.md, "Branched arch meshing"): the branched
//! arch's implicit lumen extracted by surface nets on a voxel grid (as a
//! segmentation's marching-cubes / surface-nets export is), with no
//! remeshing, written as binary STL in millimetres.
//!
//! ```text
//! cargo run --release --example vessel_surface_bench -- OUT.stl [GRID_MM]
//! nvtmm mesh vessel OUT.stl --scale 0.001 --nodes 5832 --out wall.vtu
//! ```

use nvtmm::mesh::vessel::implicit::{isosurface, BranchedArchParams, LumenTree};
use std::io::Write;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let out = args.next().ok_or("usage: vessel_surface_bench OUT.stl [GRID_MM]")?;
    let h_mm: f64 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(0.85);
    let tree = LumenTree::arch(&BranchedArchParams::default())?;
    let s = isosurface(&tree, h_mm * 1e-3)?;
    let mut buf = Vec::with_capacity(84 + 50 * s.triangles.len());
    buf.extend_from_slice(&[0u8; 80]);
    buf.extend_from_slice(&(s.triangles.len() as u32).to_le_bytes());
    for t in &s.triangles {
        buf.extend_from_slice(&[0u8; 12]);
        for &v in t {
            let p = s.vertices[v as usize] * 1e3;
            for c in [p.x, p.y, p.z] {
                buf.extend_from_slice(&(c as f32).to_le_bytes());
            }
        }
        buf.extend_from_slice(&[0u8; 2]);
    }
    std::fs::File::create(&out)?.write_all(&buf)?;
    println!(
        "wrote {out}: {} triangles, {} vertices, grid {h_mm} mm",
        s.triangles.len(),
        s.vertices.len()
    );
    Ok(())
}
