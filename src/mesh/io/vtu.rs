//! VTK XML `.vtu` (ASCII data arrays) and ParaView `.pvd` time series.
//!
//! The reader understands what the writer produces and what ParaView writes
//! with "Data Mode: Ascii": one `Piece`, `Points`, `Cells` (`connectivity`,
//! `offsets`, `types`) and `PointData`; arrays named `set_<name>` become node
//! sets (non-zero = member). Binary, appended or compressed arrays are
//! rejected with a message saying so. The XML scanner is a small hand-written
//! one: the subset VTK writes (elements, attributes, text, comments,
//! declarations) needs no dependency.

use super::scan::{quote, Scan};
use super::vtk::{cells_to_tets, membership, SET_PREFIX};
use super::{write_file, MeshError, RawMesh};
use crate::mesh::{TetMesh, Vec3};
use std::collections::{BTreeMap, HashMap};
use std::io::Write;
use std::path::{Path, PathBuf};

/// One XML start tag: name, attributes, whether it closes itself, its line,
/// and (for a non-empty element) the raw text up to the next tag.
struct Tag<'a> {
    name: &'a str,
    attrs: HashMap<&'a str, String>,
    line: usize,
    /// `<a/>`: no content and no end tag follows.
    self_closing: bool,
    /// Text after the tag and the line it starts on.
    text: (&'a [u8], usize),
}

/// XML events the VTU reader needs.
enum Ev<'a> {
    Start(Tag<'a>),
    End(&'a str),
}

struct Xml<'a> {
    s: Scan<'a>,
    data: &'a [u8],
}

impl<'a> Xml<'a> {
    fn err(&self, line: usize, msg: impl Into<String>) -> MeshError {
        self.s.err_at(line, msg)
    }

    /// Skips to the next `<`; returns false at end of input.
    fn skip_to_tag(&mut self) -> bool {
        self.s.skip_past(b"<")
    }

    fn next(&mut self) -> Result<Option<Ev<'a>>, MeshError> {
        loop {
            if !self.skip_to_tag() {
                return Ok(None);
            }
            let line = self.s.line();
            let rest = &self.data[self.s.pos()..];
            if rest.starts_with(b"?") {
                if !self.s.skip_past(b"?>") {
                    return Err(self.err(line, "unterminated '<?'"));
                }
            } else if rest.starts_with(b"!--") {
                if !self.s.skip_past(b"-->") {
                    return Err(self.err(line, "unterminated comment"));
                }
            } else if rest.starts_with(b"!") {
                if !self.s.skip_past(b">") {
                    return Err(self.err(line, "unterminated '<!'"));
                }
            } else if rest.starts_with(b"/") {
                let start = self.s.pos() + 1;
                if !self.s.skip_past(b">") {
                    return Err(self.err(line, "unterminated end tag"));
                }
                let raw = &self.data[start..self.s.pos() - 1];
                let name = std::str::from_utf8(raw)
                    .map_err(|_| self.err(line, "a tag name is not UTF-8"))?
                    .trim();
                return Ok(Some(Ev::End(name)));
            } else {
                return self.start_tag(line).map(|t| Some(Ev::Start(t)));
            }
        }
    }

    fn start_tag(&mut self, line: usize) -> Result<Tag<'a>, MeshError> {
        let start = self.s.pos();
        // Find the closing '>' outside quotes.
        let mut i = start;
        let mut quote_ch: Option<u8> = None;
        loop {
            let Some(&b) = self.data.get(i) else {
                return Err(self.err(line, "unterminated tag"));
            };
            match quote_ch {
                Some(q) if b == q => quote_ch = None,
                Some(_) => {}
                None if b == b'"' || b == b'\'' => quote_ch = Some(b),
                None if b == b'>' => break,
                None => {}
            }
            i += 1;
        }
        let body = &self.data[start..i];
        self.s
            .bytes(i + 1 - start, "a tag")
            .map_err(|_| self.err(line, "unterminated tag"))?;
        let body = std::str::from_utf8(body).map_err(|_| self.err(line, "a tag is not UTF-8 text"))?;
        let (body, self_closing) = match body.strip_suffix('/') {
            Some(b) => (b, true),
            None => (body, false),
        };
        let name_end = body.find(|c: char| c.is_whitespace()).unwrap_or(body.len());
        let name = &body[..name_end];
        if name.is_empty() {
            return Err(self.err(line, "a tag has no name"));
        }
        let mut attrs = HashMap::new();
        let mut rest = body[name_end..].trim_start();
        while !rest.is_empty() {
            let Some(eq) = rest.find('=') else {
                return Err(self.err(line, format!("attribute '{}' has no value", quote(rest))));
            };
            let key = rest[..eq].trim();
            let after = rest[eq + 1..].trim_start();
            let q = after.chars().next().filter(|&c| c == '"' || c == '\'');
            let Some(q) = q else {
                return Err(self.err(line, format!("attribute '{}' value is not quoted", quote(key))));
            };
            let Some(close) = after[1..].find(q) else {
                return Err(self.err(line, format!("attribute '{}' value is not closed", quote(key))));
            };
            attrs.insert(key, unescape(&after[1..1 + close]));
            rest = after[close + 2..].trim_start();
        }
        let text_line = self.s.line();
        let text_start = self.s.pos();
        let text_end = if self_closing {
            text_start
        } else {
            self.data[text_start..]
                .iter()
                .position(|&b| b == b'<')
                .map_or(self.data.len(), |p| text_start + p)
        };
        Ok(Tag {
            name,
            attrs,
            line,
            self_closing,
            text: (&self.data[text_start..text_end], text_line),
        })
    }
}

fn unescape(v: &str) -> String {
    v.replace("&lt;", "<")
        .replace("&gt;", ">")
        .replace("&quot;", "\"")
        .replace("&apos;", "'")
        .replace("&amp;", "&")
}

fn escape(v: &str) -> String {
    v.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A `DataArray` found in the file, with its text.
struct Array<'a> {
    name: String,
    ty: String,
    ncomp: u64,
    line: usize,
    text: (&'a [u8], usize),
}

pub(crate) fn read(path: &Path, data: &[u8]) -> Result<RawMesh, MeshError> {
    let mut x = Xml {
        s: Scan::new(path, data),
        data,
    };
    let mut stack: Vec<&str> = Vec::new();
    let mut counts: Option<(u64, u64, usize)> = None;
    let mut points: Option<Array> = None;
    let mut cell_arrays: Vec<Array> = Vec::new();
    let mut point_data: Vec<Array> = Vec::new();
    let mut saw_root = false;
    while let Some(ev) = x.next()? {
        match ev {
            Ev::End(name) => {
                if stack.pop() != Some(name) {
                    return Err(x.err(x.s.line(), format!("unexpected end tag '</{}>'", quote(name))));
                }
            }
            Ev::Start(tag) => {
                let parent = stack.last().copied();
                match tag.name {
                    "VTKFile" => {
                        saw_root = true;
                        if let Some(t) = tag.attrs.get("type").filter(|t| *t != "UnstructuredGrid") {
                            return Err(x.err(tag.line, format!("VTKFile type '{}' is not UnstructuredGrid", quote(t))));
                        }
                        if tag.attrs.contains_key("compressor") {
                            return Err(x.err(
                                tag.line,
                                "compressed .vtu files are not supported; save with ascii data",
                            ));
                        }
                    }
                    "Piece" => {
                        if counts.is_some() {
                            return Err(x.err(tag.line, "more than one Piece (only single-piece files are read)"));
                        }
                        let get = |k: &str| -> Result<u64, MeshError> {
                            let v = tag
                                .attrs
                                .get(k)
                                .ok_or_else(|| x.err(tag.line, format!("Piece has no {k}")))?;
                            v.trim()
                                .parse()
                                .map_err(|_| x.err(tag.line, format!("Piece {k}='{}' is not a count", quote(v))))
                        };
                        counts = Some((get("NumberOfPoints")?, get("NumberOfCells")?, tag.line));
                    }
                    "AppendedData" => {
                        return Err(x.err(
                            tag.line,
                            "appended (raw/base64) data is not supported; save with ascii data",
                        ));
                    }
                    "DataArray" => {
                        let fmt = tag.attrs.get("format").map_or("ascii", String::as_str);
                        let name = tag.attrs.get("Name").cloned().unwrap_or_default();
                        if fmt != "ascii" {
                            return Err(x.err(
                                tag.line,
                                format!(
                                    "DataArray '{}' has format '{}'; only ascii is read",
                                    quote(&name),
                                    quote(fmt)
                                ),
                            ));
                        }
                        let ncomp = match tag.attrs.get("NumberOfComponents") {
                            None => 1,
                            Some(v) => v.trim().parse().map_err(|_| {
                                x.err(tag.line, format!("NumberOfComponents='{}' is not a count", quote(v)))
                            })?,
                        };
                        let a = Array {
                            name,
                            ty: tag.attrs.get("type").cloned().unwrap_or_default(),
                            ncomp,
                            line: tag.line,
                            text: tag.text,
                        };
                        match parent {
                            Some("Points") => points = Some(a),
                            Some("Cells") => cell_arrays.push(a),
                            Some("PointData") => point_data.push(a),
                            _ => {}
                        }
                    }
                    _ => {}
                }
                if !tag.self_closing {
                    stack.push(tag.name);
                }
            }
        }
    }
    if !saw_root {
        return Err(x.err(1, "not a VTK XML file (no <VTKFile> element)"));
    }
    if let Some(open) = stack.last() {
        return Err(x.err(x.s.line(), format!("the file ends inside <{}>", quote(open))));
    }
    let Some((npts, ncells, pline)) = counts else {
        return Err(x.err(1, "no <Piece> element"));
    };
    let Some(points) = points else {
        return Err(x.err(pline, "no <Points> DataArray"));
    };
    if points.ncomp != 3 {
        return Err(x.err(points.line, "Points must have NumberOfComponents=\"3\""));
    }
    let coords = reals(path, &points, npts.saturating_mul(3))?;
    let mut nodes = Vec::with_capacity(coords.len() / 3);
    for (i, c) in coords.chunks_exact(3).enumerate() {
        let p = Vec3::new(c[0], c[1], c[2]);
        if let Some(k) = (0..3).find(|&k| !p[k].is_finite()) {
            return Err(x.err(
                points.line,
                format!("point {i}: coordinate {} is not finite", ["x", "y", "z"][k]),
            ));
        }
        nodes.push(p);
    }
    let find = |n: &str| {
        cell_arrays
            .iter()
            .find(|a| a.name == n)
            .ok_or_else(|| x.err(pline, format!("no Cells DataArray named '{n}'")))
    };
    let (conn_a, off_a, ty_a) = (find("connectivity")?, find("offsets")?, find("types")?);
    let offsets = ints(path, off_a, Some(ncells))?;
    let types = ints(path, ty_a, Some(ncells))?;
    let conn = ints(path, conn_a, None)?;
    let mut cells = Vec::with_capacity(offsets.len());
    let mut prev = 0usize;
    for (c, &o) in offsets.iter().enumerate() {
        let o = usize::try_from(o).ok().filter(|&o| o >= prev && o <= conn.len());
        let Some(o) = o else {
            return Err(x.err(
                off_a.line,
                format!("cell {c}: offset is out of order or past the connectivity"),
            ));
        };
        cells.push(&conn[prev..o]);
        prev = o;
    }
    let tets = cells_to_tets(path, conn_a.line, &cells, &types, nodes.len())?;
    let mut sets = BTreeMap::new();
    for a in &point_data {
        if let Some(set) = a.name.strip_prefix(SET_PREFIX) {
            let v = reals(path, a, npts.saturating_mul(a.ncomp))?;
            let ids = v.iter().enumerate().filter(|(_, &x)| x != 0.0).map(|(i, _)| i as u32);
            if a.ncomp == 1 {
                sets.insert(set.to_string(), ids.collect());
            }
        }
    }
    Ok(RawMesh { nodes, tets, sets })
}

/// Exactly `n` (or, when `n` is None, all) numbers of an array's text.
fn values<T: std::str::FromStr>(path: &Path, a: &Array, n: Option<u64>) -> Result<Vec<T>, MeshError> {
    let mut s = Scan::at_line(path, a.text.0, a.text.1);
    let mut v = Vec::with_capacity(n.map_or(0, |n| s.cap(n, 2)));
    let what = format!("a value of DataArray '{}'", quote(&a.name));
    while n.is_none_or(|n| (v.len() as u64) < n) {
        if n.is_none() && s.at_eof() {
            break;
        }
        let t = s.token(&what)?;
        v.push(
            t.parse::<T>()
                .map_err(|_| s.err(format!("expected {what} ({}), found '{}'", a.ty, quote(t))))?,
        );
    }
    if !s.at_eof() {
        return Err(s.err(format!(
            "DataArray '{}' has more than {} values",
            quote(&a.name),
            v.len()
        )));
    }
    Ok(v)
}

fn reals(path: &Path, a: &Array, n: u64) -> Result<Vec<f64>, MeshError> {
    values(path, a, Some(n))
}

fn ints(path: &Path, a: &Array, n: Option<u64>) -> Result<Vec<i64>, MeshError> {
    values(path, a, n)
}

/// Writes a `.vtu` of the mesh at rest with its node sets.
pub fn write_vtu(mesh: &TetMesh, path: &Path) -> Result<(), MeshError> {
    write_vtu_with_data(path, mesh, None, &[], &[])
}

/// Writes a `.vtu` (VTK XML unstructured grid, ASCII) for ParaView.
///
/// - `positions`: where to draw the nodes (e.g. the deformed state); `None`
///   draws the rest shape. Either way the cells are the mesh's tets.
/// - `point_vectors`: named 3-vector arrays per node (displacement, velocity,
///   force), written as `Float64` with 3 components.
/// - `point_scalars`: named scalar arrays per node.
///
/// Node sets are always written, as `Int32` arrays `set_<name>` (1 = member),
/// which [`read_mesh`](super::read_mesh) turns back into node sets. Every
/// array must have one value per node; a mismatch or a non-finite position is
/// an error and nothing is written.
pub fn write_vtu_with_data(
    path: &Path,
    mesh: &TetMesh,
    positions: Option<&[Vec3]>,
    point_vectors: &[(&str, &[Vec3])],
    point_scalars: &[(&str, &[f64])],
) -> Result<(), MeshError> {
    let n = mesh.num_nodes();
    let bad = |what: String| MeshError::InvalidData {
        path: path.to_path_buf(),
        what,
    };
    let pos = positions.unwrap_or(mesh.rest());
    if pos.len() != n {
        return Err(bad(format!("{} positions for {n} nodes", pos.len())));
    }
    if let Some(i) = pos.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(bad(format!("position of node {i} is not finite")));
    }
    for (name, v) in point_vectors {
        if v.len() != n {
            return Err(bad(format!(
                "point vector '{name}' has {} values for {n} nodes",
                v.len()
            )));
        }
    }
    for (name, v) in point_scalars {
        if v.len() != n {
            return Err(bad(format!(
                "point scalar '{name}' has {} values for {n} nodes",
                v.len()
            )));
        }
    }
    write_file(path, |w| {
        writeln!(w, "<?xml version=\"1.0\"?>")?;
        writeln!(
            w,
            "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">"
        )?;
        writeln!(w, "  <UnstructuredGrid>")?;
        writeln!(
            w,
            "    <Piece NumberOfPoints=\"{n}\" NumberOfCells=\"{}\">",
            mesh.tets().len()
        )?;
        writeln!(w, "      <PointData>")?;
        for (name, ids) in mesh.node_sets() {
            let name = escape(&format!("{SET_PREFIX}{name}"));
            writeln!(w, "        <DataArray type=\"Int32\" Name=\"{name}\" format=\"ascii\">")?;
            for v in membership(n, ids) {
                writeln!(w, "{v}")?;
            }
            writeln!(w, "        </DataArray>")?;
        }
        for (name, v) in point_vectors {
            writeln!(
                w,
                "        <DataArray type=\"Float64\" Name=\"{}\" NumberOfComponents=\"3\" format=\"ascii\">",
                escape(name)
            )?;
            for x in *v {
                writeln!(w, "{} {} {}", x.x, x.y, x.z)?;
            }
            writeln!(w, "        </DataArray>")?;
        }
        for (name, v) in point_scalars {
            writeln!(
                w,
                "        <DataArray type=\"Float64\" Name=\"{}\" format=\"ascii\">",
                escape(name)
            )?;
            for x in *v {
                writeln!(w, "{x}")?;
            }
            writeln!(w, "        </DataArray>")?;
        }
        writeln!(w, "      </PointData>")?;
        writeln!(w, "      <Points>")?;
        writeln!(
            w,
            "        <DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">"
        )?;
        for x in pos {
            writeln!(w, "{} {} {}", x.x, x.y, x.z)?;
        }
        writeln!(w, "        </DataArray>")?;
        writeln!(w, "      </Points>")?;
        writeln!(w, "      <Cells>")?;
        writeln!(
            w,
            "        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">"
        )?;
        for t in mesh.tets() {
            writeln!(w, "{} {} {} {}", t[0], t[1], t[2], t[3])?;
        }
        writeln!(w, "        </DataArray>")?;
        writeln!(
            w,
            "        <DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">"
        )?;
        for k in 1..=mesh.tets().len() {
            writeln!(w, "{}", 4 * k)?;
        }
        writeln!(w, "        </DataArray>")?;
        writeln!(w, "        <DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">")?;
        for _ in mesh.tets() {
            writeln!(w, "10")?;
        }
        writeln!(w, "        </DataArray>")?;
        writeln!(w, "      </Cells>")?;
        writeln!(w, "    </Piece>")?;
        writeln!(w, "  </UnstructuredGrid>")?;
        writeln!(w, "</VTKFile>")
    })
}

/// A time series for ParaView: one `.vtu` per step in a directory and a
/// `.pvd` collection that lists them with their times.
///
/// ```no_run
/// # use nvtmm::mesh::arch::{generate, ArchParams};
/// # use nvtmm::mesh::io::PvdSeries;
/// # let mesh = generate(&ArchParams::default(), 1458).unwrap().mesh;
/// let mut series = PvdSeries::create(std::path::Path::new("out"), "arch")?;
/// for step in 0..3 {
///     let u = vec![nvtmm::mesh::Vec3::zeros(); mesh.num_nodes()];
///     series.add_step(step as f64 * 1e-3, &mesh, None, &[("displacement", &u)], &[])?;
/// }
/// let pvd = series.finish()?; // out/arch.pvd, out/arch_000000.vtu …
/// # Ok::<(), nvtmm::mesh::io::MeshError>(())
/// ```
///
/// The `.pvd` is rewritten after every step, so a run that stops early
/// still leaves a collection ParaView can open.
#[derive(Debug)]
pub struct PvdSeries {
    dir: PathBuf,
    name: String,
    steps: Vec<(f64, String)>,
}

impl PvdSeries {
    /// Creates `dir` (and parents) for a series whose files are named
    /// `<name>_NNNNNN.vtu` and `<name>.pvd`.
    pub fn create(dir: &Path, name: &str) -> Result<PvdSeries, MeshError> {
        if name.is_empty() || name.contains(['/', '\\']) {
            return Err(MeshError::InvalidData {
                path: dir.to_path_buf(),
                what: format!("series name '{name}' must be non-empty and contain no path separator"),
            });
        }
        std::fs::create_dir_all(dir).map_err(|source| MeshError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        Ok(PvdSeries {
            dir: dir.to_path_buf(),
            name: name.to_string(),
            steps: Vec::new(),
        })
    }

    /// Number of steps written so far.
    pub fn len(&self) -> usize {
        self.steps.len()
    }

    /// Whether no step has been written.
    pub fn is_empty(&self) -> bool {
        self.steps.is_empty()
    }

    /// The `.pvd` collection's path.
    pub fn pvd_path(&self) -> PathBuf {
        self.dir.join(format!("{}.pvd", self.name))
    }

    /// Writes step `len()` at `time` (seconds) as `<name>_NNNNNN.vtu` with
    /// [`write_vtu_with_data`]'s arguments, updates the `.pvd`, and returns the
    /// `.vtu` path. Times must be finite.
    pub fn add_step(
        &mut self,
        time: f64,
        mesh: &TetMesh,
        positions: Option<&[Vec3]>,
        point_vectors: &[(&str, &[Vec3])],
        point_scalars: &[(&str, &[f64])],
    ) -> Result<PathBuf, MeshError> {
        let file = format!("{}_{:06}.vtu", self.name, self.steps.len());
        let path = self.dir.join(&file);
        if !time.is_finite() {
            return Err(MeshError::InvalidData {
                path,
                what: format!("step time {time} is not finite"),
            });
        }
        write_vtu_with_data(&path, mesh, positions, point_vectors, point_scalars)?;
        self.steps.push((time, file));
        self.write_pvd()?;
        Ok(path)
    }

    /// Writes the final `.pvd` and returns its path.
    pub fn finish(self) -> Result<PathBuf, MeshError> {
        self.write_pvd()?;
        Ok(self.pvd_path())
    }

    fn write_pvd(&self) -> Result<(), MeshError> {
        write_file(&self.pvd_path(), |w| {
            writeln!(w, "<?xml version=\"1.0\"?>")?;
            writeln!(
                w,
                "<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">"
            )?;
            writeln!(w, "  <Collection>")?;
            for (t, f) in &self.steps {
                writeln!(
                    w,
                    "    <DataSet timestep=\"{t}\" group=\"\" part=\"0\" file=\"{}\"/>",
                    escape(f)
                )?;
            }
            writeln!(w, "  </Collection>")?;
            writeln!(w, "</VTKFile>")
        })
    }
}
