//! `nvtmm mesh …` subcommands.

use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::mesh::io::{read_mesh_scaled, write_mesh};
use nvtmm::mesh::quality::MeshQuality;
use nvtmm::mesh::render::{render_surface, write_png, RenderOptions};
use nvtmm::mesh::surface::{read_and_check, CheckOptions};
use nvtmm::mesh::vessel::caps::CutPlane;
use nvtmm::mesh::vessel::pipeline::{mesh_vessel, SurfaceSize, VesselOptions};
use nvtmm::mesh::vessel::wall::{Thickness, WallOptions};
use nvtmm::mesh::TetMesh;
use std::path::Path;
use std::time::Instant;

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

pub fn arch(nodes: usize, out: &Path) -> Result<()> {
    let t0 = Instant::now();
    let arch = generate(&ArchParams::default(), nodes)?;
    let gen_s = t0.elapsed().as_secs_f64();
    write_mesh(&arch.mesh, out)?;
    let m = &arch.mesh;
    println!(
        "wrote {}: {} nodes, {} tets, {} surface triangles (grid {}x{}x{}), generated in {:.3} s",
        out.display(),
        m.num_nodes(),
        m.tets().len(),
        m.surface().len(),
        arch.grid.axial,
        arch.grid.circumferential,
        arch.grid.layers,
        gen_s
    );
    Ok(())
}

/// `nvtmm mesh arch --branches three`: the branched arch through the vessel
/// pipeline.
pub fn branched_arch(nodes: usize, out: &Path, arch_type: &str, layers: usize) -> Result<()> {
    use nvtmm::mesh::vessel::branched::{branched_arch, default_wall_ratio};
    use nvtmm::mesh::vessel::implicit::{ArchType, BranchedArchParams};
    let arch_type = match arch_type {
        "I" | "1" => ArchType::I,
        "II" | "2" => ArchType::II,
        "III" | "3" => ArchType::III,
        other => return Err(format!("--arch-type {other}: expected I, II or III").into()),
    };
    nvtmm::mesh::io::Format::from_path(out)?;
    let params = BranchedArchParams {
        arch_type,
        ..BranchedArchParams::default()
    };
    let t0 = Instant::now();
    let b = branched_arch(&params, nodes, layers, default_wall_ratio(&params))?;
    let gen_s = t0.elapsed().as_secs_f64();
    write_mesh(&b.wall.mesh, out)?;
    let m = &b.wall.mesh;
    let q = &b.wall.quality;
    println!(
        "wrote {}: branched arch (type {:?}), {} nodes, {} tets, {} layer(s), lumen edge {:.2} mm, meshed in {:.2} s",
        out.display(),
        arch_type,
        m.num_nodes(),
        m.tets().len(),
        layers,
        b.surface_size_m * 1e3,
        gen_s
    );
    for o in &b.wall.openings {
        println!(
            "  {:<28} centre {} mm  normal {}  area {:.1} mm^2",
            o.name,
            vec_fmt(&o.centre, 1e3, 1),
            vec_fmt(&o.normal, 1.0, 3),
            o.area * 1e6
        );
    }
    if let Some((names, label)) = m.segment_labels() {
        for (s, name) in names.iter().enumerate() {
            println!(
                "  segment {:<22} {} nodes",
                name,
                label.iter().filter(|&&l| l as usize == s).count()
            );
        }
    }
    println!(
        "  quality: dihedral {:.2}° .. {:.2}°, aspect max {:.2}, inverted {}, wall {:.2} .. {:.2} mm",
        q.min_dihedral_deg,
        q.max_dihedral_deg,
        q.max_aspect_ratio,
        m.report().inverted,
        b.wall.thickness_range.0 * 1e3,
        b.wall.thickness_range.1 * 1e3
    );
    Ok(())
}

/// Parses `--cut px,py,pz,nx,ny,nz` (the point scaled by `scale` into metres).
fn parse_cut(k: usize, text: &str, scale: f64) -> Result<CutPlane> {
    let v: Vec<f64> = text
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| format!("--cut {k} '{text}': {e} (expected px,py,pz,nx,ny,nz)"))?;
    if v.len() != 6 || v.iter().any(|x| !x.is_finite()) {
        return Err(format!("--cut {k} '{text}': expected six finite numbers px,py,pz,nx,ny,nz").into());
    }
    Ok(CutPlane {
        point: nvtmm::math::Vec3::new(v[0], v[1], v[2]) * scale,
        normal: nvtmm::math::Vec3::new(v[3], v[4], v[5]),
    })
}

/// A vector formatted with `prec` decimals, without "-0.000".
fn vec_fmt(v: &nvtmm::math::Vec3, scale: f64, prec: usize) -> String {
    let f = |x: f64| {
        let t = format!("{:.*}", prec, x * scale);
        match t.strip_prefix('-') {
            Some(u) if u.chars().all(|c| c == '0' || c == '.') => u.to_string(),
            _ => t,
        }
    };
    format!("({}, {}, {})", f(v.x), f(v.y), f(v.z))
}

/// `nvtmm mesh vessel`: surface -> openings -> wall -> file. Nothing is
/// written unless every step succeeds.
pub fn vessel(
    surface: &Path,
    out: &Path,
    (wall_thickness, wall_ratio): (Option<f64>, Option<f64>),
    layers: usize,
    scale: f64,
    cuts: &[String],
    size: SurfaceSize,
) -> Result<()> {
    let t0 = Instant::now();
    // Refuse an unknown output format before any work.
    nvtmm::mesh::io::Format::from_path(out)?;
    let cuts = cuts
        .iter()
        .enumerate()
        .map(|(k, c)| parse_cut(k, c, scale))
        .collect::<Result<Vec<_>>>()?;
    let thickness = match (wall_thickness, wall_ratio) {
        (Some(_), Some(_)) => return Err("give --wall-thickness or --wall-ratio, not both".into()),
        (_, Some(f)) => Thickness::Ratio(f),
        (Some(t), None) => Thickness::Absolute(t),
        (None, None) => WallOptions::default().thickness,
    };
    let checked = read_and_check(
        surface,
        scale,
        &CheckOptions {
            scale,
            ..CheckOptions::default()
        },
    )?;
    let opts = VesselOptions {
        wall: WallOptions { thickness, layers },
        size,
        cuts,
        ..VesselOptions::default()
    };
    let opened = mesh_vessel(&checked, &opts).map_err(|e| format!("{}: {e}", surface.display()))?;
    let wall = &opened.wall;
    write_mesh(&wall.mesh, out)?;
    let m = &wall.mesh;
    println!(
        "wrote {}: {} nodes, {} tets, {} layer(s), wall {:.3}..{:.3} mm, in {:.3} s",
        out.display(),
        m.num_nodes(),
        m.tets().len(),
        wall.layers,
        wall.thickness_range.0 * 1e3,
        wall.thickness_range.1 * 1e3,
        t0.elapsed().as_secs_f64()
    );
    if let Some((st, s)) = &opened.remesh {
        println!(
            "  remeshed lumen: {} vertices, target edge {:.3} mm (capped for 8 around), min angle {:.1}°",
            st.vertices,
            s * 1e3,
            st.min_angle_deg
        );
    }
    for (k, pieces) in opened.dropped_pieces.iter().enumerate() {
        if !pieces.is_empty() {
            println!(
                "  cut {k}: dropped {} disconnected piece(s) of {:?} triangles",
                pieces.len(),
                pieces
            );
        }
    }
    for c in &opened.caps {
        println!(
            "  removed planar cap: {} triangles, centre {} mm, area {:.3} mm^2",
            c.triangles.len(),
            vec_fmt(&c.centre, 1e3, 3),
            c.area * 1e6
        );
    }
    for o in &wall.openings {
        println!(
            "  {:<10} centre {} mm  normal {}  area {:.3} mm^2  {} nodes",
            o.name,
            vec_fmt(&o.centre, 1e3, 3),
            vec_fmt(&o.normal, 1.0, 4),
            o.area * 1e6,
            o.nodes
        );
    }
    if let Some((names, label)) = m.segment_labels() {
        for (k, name) in names.iter().enumerate() {
            println!(
                "  segment {:<16} {} nodes",
                name,
                label.iter().filter(|&&l| l as usize == k).count()
            );
        }
    }
    let q = &wall.quality;
    println!("  volume             {:.6e} m^3", m.total_volume());
    println!("  inverted (fixed)   {}", m.report().inverted);
    println!(
        "  dihedral angles    {:.2}° .. {:.2}°",
        q.min_dihedral_deg, q.max_dihedral_deg
    );
    println!(
        "  aspect ratio       max {:.3}, mean {:.3}",
        q.max_aspect_ratio, q.mean_aspect_ratio
    );
    println!("  edge length        {:.3e} .. {:.3e} m", q.min_edge_m, q.max_edge_m);
    for (k, ids) in m.node_sets() {
        println!("  node set {k:<18} {} nodes", ids.len());
    }
    Ok(())
}

/// The `mesh info` summary; field names are a scripting contract.
#[derive(serde::Serialize)]
struct Info {
    nodes: usize,
    tets: usize,
    edges: usize,
    surface_triangles: usize,
    volume_m3: f64,
    inverted: usize,
    isolated_nodes: usize,
    min_dihedral_deg: f64,
    max_dihedral_deg: f64,
    max_aspect_ratio: f64,
    mean_aspect_ratio: f64,
    min_edge_m: f64,
    max_edge_m: f64,
    bbox_min: [f64; 3],
    bbox_max: [f64; 3],
    node_sets: std::collections::BTreeMap<String, usize>,
}

fn info_of(m: &TetMesh) -> Info {
    let q = MeshQuality::of(m);
    let (lo, hi) = m.bbox();
    Info {
        nodes: m.num_nodes(),
        tets: m.tets().len(),
        edges: m.edges().len(),
        surface_triangles: m.surface().len(),
        volume_m3: m.total_volume(),
        inverted: m.report().inverted,
        isolated_nodes: m.report().isolated_nodes,
        min_dihedral_deg: q.min_dihedral_deg,
        max_dihedral_deg: q.max_dihedral_deg,
        max_aspect_ratio: q.max_aspect_ratio,
        mean_aspect_ratio: q.mean_aspect_ratio,
        min_edge_m: q.min_edge_m,
        max_edge_m: q.max_edge_m,
        bbox_min: [lo.x, lo.y, lo.z],
        bbox_max: [hi.x, hi.y, hi.z],
        node_sets: m.node_sets().iter().map(|(k, v)| (k.clone(), v.len())).collect(),
    }
}

pub fn info(file: &Path, json: bool, scale: f64) -> Result<()> {
    let m = match read_mesh_scaled(file, scale) {
        Ok(m) => m,
        // Not a volume mesh: a lumen surface is described, with the way to
        // a wall mesh; anything else keeps the volume reader's error.
        Err(e) => match read_and_check(file, scale, &CheckOptions::default()) {
            Ok(s) => return surface_info(file, &s, json),
            Err(_) => return Err(e.into()),
        },
    };
    let i = info_of(&m);
    if json {
        println!("{}", serde_json::to_string_pretty(&i)?);
    } else {
        println!("{}", file.display());
        println!("  nodes              {}", i.nodes);
        println!("  tets               {}", i.tets);
        println!("  edges              {}", i.edges);
        println!("  surface triangles  {}", i.surface_triangles);
        println!("  volume             {:.6e} m^3", i.volume_m3);
        println!("  inverted (fixed)   {}", i.inverted);
        println!("  isolated nodes     {}", i.isolated_nodes);
        println!(
            "  dihedral angles    {:.2}° .. {:.2}°",
            i.min_dihedral_deg, i.max_dihedral_deg
        );
        println!(
            "  aspect ratio       max {:.3}, mean {:.3}",
            i.max_aspect_ratio, i.mean_aspect_ratio
        );
        println!("  edge length        {:.3e} .. {:.3e} m", i.min_edge_m, i.max_edge_m);
        println!("  bbox               {:?} .. {:?} m", i.bbox_min, i.bbox_max);
        for (k, n) in &i.node_sets {
            println!("  node set {k:<18} {n} nodes");
        }
    }
    Ok(())
}

/// `mesh info` on a surface file: its openings, and how to mesh a wall
/// from it.
fn surface_info(file: &Path, s: &nvtmm::mesh::surface::CheckedSurface, json: bool) -> Result<()> {
    let loops = &s.report.boundary_loops;
    let f = file.display();
    let next = if loops.is_empty() {
        format!(
            "a closed surface (no opening): `nvtmm mesh vessel {f} --out wall.vtu` removes flat end caps if it \
             finds them; otherwise open each end with --cut px,py,pz,nx,ny,nz (a plane; the side the normal \
             points to is removed)"
        )
    } else {
        format!("a lumen surface: `nvtmm mesh vessel {f} --out wall.vtu` builds the vessel wall's tet mesh")
    };
    if json {
        let openings: Vec<serde_json::Value> = loops
            .iter()
            .map(|l| {
                serde_json::json!({
                    "centre_m": [l.centre.x, l.centre.y, l.centre.z],
                    "normal": [l.normal.x, l.normal.y, l.normal.z],
                    "perimeter_m": l.perimeter,
                })
            })
            .collect();
        let v = serde_json::json!({
            "kind": "surface",
            "vertices": s.mesh.vertices.len(),
            "triangles": s.mesh.triangles.len(),
            "openings": openings,
            "next": next,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        println!("{f}: a surface, not a volume (tet) mesh");
        println!("  vertices           {}", s.mesh.vertices.len());
        println!("  triangles          {}", s.mesh.triangles.len());
        println!("  openings           {}", loops.len());
        for (k, l) in loops.iter().enumerate() {
            println!(
                "    opening {k}: centre ({:.1}, {:.1}, {:.1}) mm, perimeter {:.1} mm",
                l.centre.x * 1e3,
                l.centre.y * 1e3,
                l.centre.z * 1e3,
                l.perimeter * 1e3
            );
        }
        println!("  {next}");
    }
    Ok(())
}

pub fn convert(input: &Path, output: &Path, scale: f64) -> Result<()> {
    let m = read_mesh_scaled(input, scale)?;
    write_mesh(&m, output)?;
    if nvtmm::mesh::io::Format::from_path(output)?.is_surface_only() {
        println!(
            "wrote {}: boundary surface, {} triangles",
            output.display(),
            m.surface().len()
        );
    } else {
        println!(
            "wrote {}: {} nodes, {} tets",
            output.display(),
            m.num_nodes(),
            m.tets().len()
        );
    }
    Ok(())
}

pub fn render(input: &str, out: &Path, width: u32, height: u32, azimuth: f64, elevation: f64) -> Result<()> {
    let mesh = match input.strip_prefix("arch:") {
        Some(n) => {
            generate(
                &ArchParams::default(),
                n.parse().map_err(|_| format!("arch:N: '{n}' is not a node count"))?,
            )?
            .mesh
        }
        None => read_mesh_scaled(Path::new(input), 1.0)?,
    };
    if width == 0 || height == 0 || width > 8192 || height > 8192 {
        return Err(format!("--width/--height must be in 1..=8192, got {width}x{height}").into());
    }
    let opt = RenderOptions {
        width,
        height,
        azimuth_deg: azimuth,
        elevation_deg: elevation,
        ..Default::default()
    };
    let rgb = render_surface(&mesh, None, None, &opt);
    write_png(out, width, height, &rgb).map_err(|e| format!("{}: {e}", out.display()))?;
    println!("wrote {}", out.display());
    Ok(())
}
