//! A small software renderer: the boundary surface of a mesh, shaded, to PNG.
//!
//! Good enough for README pictures and quick looks without a GUI: an
//! orthographic camera, Lambert shading with a head light plus ambient,
//! a z-buffer and 2×2 supersampling. Optionally colours by a per-node scalar
//! (e.g. displacement magnitude) with a blue→red map.

use super::TetMesh;
use crate::math::Vec3;
use nalgebra::Rotation3;
use std::io::BufWriter;
use std::path::Path;

/// Camera and image settings.
#[derive(Debug, Clone)]
pub struct RenderOptions {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Rotation about the world z axis (degrees), applied first.
    pub azimuth_deg: f64,
    /// Rotation tilting the view down from horizontal (degrees).
    pub elevation_deg: f64,
    /// Background colour.
    pub background: [u8; 3],
    /// Surface colour when no scalar field is given.
    pub color: [u8; 3],
    /// Draw triangle edges darker (wireframe overlay).
    pub edges: bool,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            width: 900,
            height: 700,
            azimuth_deg: 125.0,
            elevation_deg: 20.0,
            background: [255, 255, 255],
            color: [205, 70, 60],
            edges: true,
        }
    }
}

/// Renders the boundary surface of `mesh` at `positions` (rest positions if
/// `None`) to an RGB image buffer (row-major, 3 bytes per pixel).
pub fn render_surface(
    mesh: &TetMesh,
    positions: Option<&[Vec3]>,
    scalar: Option<&[f64]>,
    opt: &RenderOptions,
) -> Vec<u8> {
    let pos = positions.unwrap_or(mesh.rest());
    // World z is up; the camera looks along +y_view after rotation.
    let rot = Rotation3::from_axis_angle(&Vec3::x_axis(), opt.elevation_deg.to_radians())
        * Rotation3::from_axis_angle(&Vec3::z_axis(), opt.azimuth_deg.to_radians());
    // View coordinates: x right, y depth (into the screen), z up.
    let view: Vec<Vec3> = pos.iter().map(|p| rot * p).collect();
    let (lo, hi) = super::bbox(&view);
    let ss = 2u32;
    let (w, h) = (opt.width * ss, opt.height * ss);
    let margin = 0.06;
    let sx = (w as f64) * (1.0 - 2.0 * margin) / (hi.x - lo.x).max(1e-30);
    let sz = (h as f64) * (1.0 - 2.0 * margin) / (hi.z - lo.z).max(1e-30);
    let s = sx.min(sz);
    let cx = 0.5 * (lo.x + hi.x);
    let cz = 0.5 * (lo.z + hi.z);
    let to_px =
        |v: &Vec3| -> (f64, f64, f64) { (w as f64 / 2.0 + (v.x - cx) * s, h as f64 / 2.0 - (v.z - cz) * s, v.y) };
    let (smin, smax) = scalar
        .map(|f| {
            f.iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)))
        })
        .unwrap_or((0.0, 1.0));
    let mut color = vec![opt.background; (w * h) as usize];
    let mut depth = vec![f64::INFINITY; (w * h) as usize];
    let light = Vec3::new(-0.3, -1.0, 0.5).normalize();
    for tri in mesh.surface() {
        let [a, b, c] = tri.map(|i| i as usize);
        let n = (view[b] - view[a]).cross(&(view[c] - view[a]));
        let nl = n.norm();
        if nl == 0.0 {
            continue;
        }
        let n = n / nl;
        // Two-sided lighting so the lumen reads well through the open ends.
        let lambert = n.dot(&light).abs();
        let shade = 0.35 + 0.65 * lambert;
        let base = match scalar {
            Some(f) => colormap(((f[a] + f[b] + f[c]) / 3.0 - smin) / (smax - smin).max(1e-30)),
            None => opt.color,
        };
        let rgb = base.map(|ch| (ch as f64 * shade).min(255.0) as u8);
        let p = [to_px(&view[a]), to_px(&view[b]), to_px(&view[c])];
        let xmin = p.iter().map(|q| q.0).fold(f64::INFINITY, f64::min).floor().max(0.0) as i64;
        let xmax = p
            .iter()
            .map(|q| q.0)
            .fold(f64::NEG_INFINITY, f64::max)
            .ceil()
            .min(w as f64 - 1.0) as i64;
        let ymin = p.iter().map(|q| q.1).fold(f64::INFINITY, f64::min).floor().max(0.0) as i64;
        let ymax = p
            .iter()
            .map(|q| q.1)
            .fold(f64::NEG_INFINITY, f64::max)
            .ceil()
            .min(h as f64 - 1.0) as i64;
        let area = (p[1].0 - p[0].0) * (p[2].1 - p[0].1) - (p[2].0 - p[0].0) * (p[1].1 - p[0].1);
        if area.abs() < 1e-12 {
            continue;
        }
        for y in ymin..=ymax {
            for x in xmin..=xmax {
                let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                let w0 = ((p[1].0 - px) * (p[2].1 - py) - (p[2].0 - px) * (p[1].1 - py)) / area;
                let w1 = ((p[2].0 - px) * (p[0].1 - py) - (p[0].0 - px) * (p[2].1 - py)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                let z = w0 * p[0].2 + w1 * p[1].2 + w2 * p[2].2;
                let idx = (y as u32 * w + x as u32) as usize;
                if z < depth[idx] {
                    depth[idx] = z;
                    let edge = opt.edges && w0.min(w1).min(w2) * area.abs().sqrt() < 0.9;
                    color[idx] = if edge {
                        rgb.map(|ch| (ch as f64 * 0.6) as u8)
                    } else {
                        rgb
                    };
                }
            }
        }
    }
    // Downsample.
    let mut out = Vec::with_capacity((opt.width * opt.height * 3) as usize);
    for y in 0..opt.height {
        for x in 0..opt.width {
            let mut acc = [0u32; 3];
            for dy in 0..ss {
                for dx in 0..ss {
                    let c = color[((y * ss + dy) * w + x * ss + dx) as usize];
                    for k in 0..3 {
                        acc[k] += c[k] as u32;
                    }
                }
            }
            out.extend(acc.map(|v| (v / (ss * ss)) as u8));
        }
    }
    out
}

/// Blue → white → red colour map for t in [0, 1].
pub fn colormap(t: f64) -> [u8; 3] {
    let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 };
    let (r, g, b) = if t < 0.5 {
        let u = t / 0.5;
        (0.23 + 0.77 * u, 0.30 + 0.70 * u, 0.75 + 0.25 * u)
    } else {
        let u = (t - 0.5) / 0.5;
        (1.0 - 0.3 * u, 1.0 - 0.85 * u, 1.0 - 0.85 * u)
    };
    [(r * 255.0) as u8, (g * 255.0) as u8, (b * 255.0) as u8]
}

/// Writes an RGB buffer as a PNG file.
pub fn write_png(path: &Path, width: u32, height: u32, rgb: &[u8]) -> std::io::Result<()> {
    let file = std::fs::File::create(path)?;
    let mut enc = png::Encoder::new(BufWriter::new(file), width, height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut writer = enc.write_header().map_err(std::io::Error::other)?;
    writer.write_image_data(rgb).map_err(std::io::Error::other)?;
    Ok(())
}
