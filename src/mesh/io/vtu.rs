//! VTK XML `.vtu` and ParaView `.pvd` time series.
//!
//! The reader takes one `Piece` with `Points`, `Cells` (`connectivity`,
//! `offsets`, `types`) and `PointData`, with arrays stored as ascii, inline
//! binary (base64) or appended (raw or base64), uncompressed or
//! zlib-compressed ([`super::vtkdata`]): what nvtmm writes and what ParaView
//! and VTK write by default. Arrays named `set_<name>` become node sets
//! (non-zero = member). The writer writes ascii. The XML scanner is a small
//! hand-written one: the subset VTK writes (elements, attributes, text,
//! comments, declarations, appended bytes after `_`) needs no dependency.

use super::scan::{quote, Endian, Scan};
use super::vtk::{cells_to_tets, members, membership, SET_PREFIX};
use super::vtkdata::{decode, to_f64, to_i64, type_size, Encoding, Source};
use super::{write_file, MeshError, RawMesh};
use crate::math::Vec3;
use crate::mesh::TetMesh;
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
        let mut text_line = self.s.line();
        let mut text_start = self.s.pos();
        let rest = &self.data[text_start..];
        let text_end = if self_closing {
            text_start
        } else if name == "DataArray" {
            // VTK may put <InformationKey> elements before the values.
            let end = find(rest, b"</DataArray").unwrap_or(rest.len());
            if let Some(k) = rfind(&rest[..end], b"</InformationKey>") {
                let skip = k + b"</InformationKey>".len();
                text_line += rest[..skip].iter().filter(|&&b| b == b'\n').count();
                text_start += skip;
            }
            self.s.pos() + end
        } else {
            rest.iter()
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

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

fn rfind(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).rposition(|w| w == needle)
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

/// How a `DataArray` stores its values.
#[derive(Clone, Copy, PartialEq)]
pub(crate) enum Fmt {
    Ascii,
    /// Inline base64.
    Binary,
    /// In `<AppendedData>`, at this offset.
    Appended(usize),
}

/// A `DataArray` found in the file, with its text.
pub(crate) struct Array<'a> {
    pub(crate) name: String,
    ty: String,
    pub(crate) ncomp: u64,
    pub(crate) line: usize,
    fmt: Fmt,
    text: (&'a [u8], usize),
}

/// What decoding binary arrays needs: the file's encoding and its appended data.
pub(crate) struct Ctx<'a> {
    path: &'a Path,
    enc: Encoding,
    /// Appended data after the `_` marker, and whether it is raw (else base64).
    appended: Option<(&'a [u8], bool)>,
}

/// A VTK XML file scanned: its encoding and appended data, the one
/// `Piece`'s attributes, and every `DataArray` with the element it sits in
/// (`Points`, `Cells`, `Polys`, `PointData`, …). Shared by `.vtu` and the
/// `.vtp` surface reader.
pub(crate) struct Doc<'a> {
    pub(crate) ctx: Ctx<'a>,
    /// The `Piece`'s attributes and its line.
    piece: (HashMap<&'a str, String>, usize),
    /// Each `DataArray` with the name of its parent element.
    pub(crate) arrays: Vec<(&'a str, Array<'a>)>,
}

impl<'a> Doc<'a> {
    /// A parse error at `line`.
    pub(crate) fn err(&self, line: usize, msg: impl Into<String>) -> MeshError {
        MeshError::Parse {
            path: self.ctx.path.to_path_buf(),
            line,
            msg: msg.into(),
        }
    }

    /// The `Piece` element's line.
    pub(crate) fn piece_line(&self) -> usize {
        self.piece.1
    }

    /// A count attribute of the `Piece` (`NumberOfPoints`, …); `None` when absent.
    pub(crate) fn count(&self, key: &str) -> Result<Option<u64>, MeshError> {
        let (attrs, line) = &self.piece;
        attrs
            .get(key)
            .map(|v| {
                v.trim()
                    .parse()
                    .map_err(|_| self.err(*line, format!("Piece {key}='{}' is not a count", quote(v))))
            })
            .transpose()
    }

    /// A count attribute the `Piece` must have.
    pub(crate) fn required(&self, key: &str) -> Result<u64, MeshError> {
        self.count(key)?
            .ok_or_else(|| self.err(self.piece.1, format!("Piece has no {key}")))
    }

    /// The arrays inside elements named `parent`.
    pub(crate) fn arrays_in<'s>(&'s self, parent: &'s str) -> impl Iterator<Item = &'s Array<'a>> + 's {
        self.arrays.iter().filter(move |(p, _)| *p == parent).map(|(_, a)| a)
    }
}

/// Scans a VTK XML file whose `VTKFile type` must be `dataset` (when given).
pub(crate) fn scan_doc<'a>(path: &'a Path, data: &'a [u8], dataset: &str) -> Result<Doc<'a>, MeshError> {
    let mut x = Xml {
        s: Scan::new(path, data),
        data,
    };
    let mut stack: Vec<&str> = Vec::new();
    let mut piece: Option<(HashMap<&str, String>, usize)> = None;
    let mut arrays: Vec<(&str, Array)> = Vec::new();
    let mut saw_root = false;
    let mut enc = Encoding {
        endian: Endian::Little,
        header: 4,
        zlib: false,
    };
    let mut appended = None;
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
                        if let Some(t) = tag.attrs.get("type").filter(|t| *t != dataset) {
                            return Err(x.err(tag.line, format!("VTKFile type '{}' is not {dataset}", quote(t))));
                        }
                        enc.endian = match tag.attrs.get("byte_order").map(String::as_str) {
                            None | Some("LittleEndian") => Endian::Little,
                            Some("BigEndian") => Endian::Big,
                            Some(o) => return Err(x.err(tag.line, format!("byte_order '{}' is unknown", quote(o)))),
                        };
                        enc.header = match tag.attrs.get("header_type").map(String::as_str) {
                            None | Some("UInt32") => 4,
                            Some("UInt64") => 8,
                            Some(h) => return Err(x.err(tag.line, format!("header_type '{}' is unknown", quote(h)))),
                        };
                        enc.zlib = match tag.attrs.get("compressor").map(String::as_str) {
                            None | Some("") => false,
                            Some("vtkZLibDataCompressor") => true,
                            Some(c) => {
                                return Err(x.err(
                                    tag.line,
                                    format!("compressor '{}' is not supported (zlib or none are read)", quote(c)),
                                ))
                            }
                        };
                    }
                    "Piece" => {
                        if piece.is_some() {
                            return Err(x.err(tag.line, "more than one Piece (only single-piece files are read)"));
                        }
                        piece = Some((tag.attrs.clone(), tag.line));
                    }
                    "AppendedData" => {
                        let raw = match tag.attrs.get("encoding").map(String::as_str) {
                            None | Some("raw") => true,
                            Some("base64") => false,
                            Some(e) => {
                                return Err(x.err(tag.line, format!("AppendedData encoding '{}' is unknown", quote(e))))
                            }
                        };
                        // The data starts after a '_' and may hold any bytes:
                        // nothing after it is parsed as XML.
                        let start = x.s.pos();
                        let Some(us) = data[start..].iter().position(|&b| b == b'_') else {
                            return Err(x.err(tag.line, "AppendedData has no '_' marker"));
                        };
                        appended = Some((&data[start + us + 1..], raw));
                        stack.clear();
                        break;
                    }
                    "DataArray" => {
                        let name = tag.attrs.get("Name").cloned().unwrap_or_default();
                        let fmt = match tag.attrs.get("format").map_or("ascii", String::as_str) {
                            "ascii" => Fmt::Ascii,
                            "binary" => Fmt::Binary,
                            "appended" => {
                                let off = tag.attrs.get("offset").and_then(|o| o.trim().parse().ok());
                                let Some(off) = off else {
                                    return Err(x.err(
                                        tag.line,
                                        format!("appended DataArray '{}' has no valid offset", quote(&name)),
                                    ));
                                };
                                Fmt::Appended(off)
                            }
                            f => {
                                return Err(x.err(
                                    tag.line,
                                    format!("DataArray '{}' has unknown format '{}'", quote(&name), quote(f)),
                                ))
                            }
                        };
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
                            fmt,
                            text: tag.text,
                        };
                        if let Some(p) = parent {
                            arrays.push((p, a));
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
    let Some(piece) = piece else {
        return Err(x.err(1, "no <Piece> element"));
    };
    Ok(Doc {
        ctx: Ctx { path, enc, appended },
        piece,
        arrays,
    })
}

pub(super) fn read(path: &Path, data: &[u8]) -> Result<RawMesh, MeshError> {
    let doc = scan_doc(path, data, "UnstructuredGrid")?;
    let x = &doc;
    let npts = doc.required("NumberOfPoints")?;
    let ncells = doc.required("NumberOfCells")?;
    let pline = doc.piece_line();
    let ctx = &doc.ctx;
    let points = doc.arrays_in("Points").last();
    let cell_arrays: Vec<&Array> = doc.arrays_in("Cells").collect();
    let point_data: Vec<&Array> = doc.arrays_in("PointData").collect();
    let Some(points) = points else {
        return Err(x.err(pline, "no <Points> DataArray"));
    };
    if points.ncomp != 3 {
        return Err(x.err(points.line, "Points must have NumberOfComponents=\"3\""));
    }
    let coords = reals(ctx, points, npts.saturating_mul(3))?;
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
    let offsets = ints(ctx, off_a, Some(ncells))?;
    let types = ints(ctx, ty_a, Some(ncells))?;
    let conn = ints(ctx, conn_a, None)?;
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
            // Check every set_ array parses, but only one-component ones are sets.
            let v = reals(ctx, a, npts.saturating_mul(a.ncomp))?;
            if a.ncomp == 1 {
                sets.insert(set.to_string(), members(&v));
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

/// The decoded bytes of a binary or appended array: at most what `n` values
/// need (or, for `None`, what the stored bytes could expand to).
fn binary_bytes(ctx: &Ctx, a: &Array, n: Option<u64>) -> Result<Vec<u8>, MeshError> {
    let err = |msg: String| ctx_err(ctx, a, msg);
    let (size, _) = type_size(&a.ty).ok_or_else(|| err(format!("type '{}' is unknown", quote(&a.ty))))?;
    let src = match a.fmt {
        Fmt::Appended(off) => {
            let Some((bytes, raw)) = ctx.appended else {
                return Err(err("is appended but the file has no <AppendedData>".into()));
            };
            let bytes = bytes
                .get(off..)
                .ok_or_else(|| err(format!("offset {off} is past the appended data")))?;
            if raw {
                Source::Raw(bytes)
            } else {
                Source::Base64(bytes)
            }
        }
        _ => Source::Base64(a.text.0),
    };
    let stored = match src {
        Source::Raw(b) | Source::Base64(b) => b.len(),
    };
    // zlib expands by at most ~1032x; a declared count beyond that is a lie.
    let max = n
        .and_then(|n| usize::try_from(n).ok())
        .and_then(|n| n.checked_mul(size))
        .unwrap_or(usize::MAX)
        .min(stored.saturating_mul(if ctx.enc.zlib { 1100 } else { 1 }));
    decode(src, ctx.enc, max).map_err(err)
}

fn ctx_err(ctx: &Ctx, a: &Array, msg: String) -> MeshError {
    MeshError::Parse {
        path: ctx.path.to_path_buf(),
        line: a.line,
        msg: format!("DataArray '{}': {msg}", quote(&a.name)),
    }
}

/// Checks a decoded array has exactly `n` values.
fn exact<T>(ctx: &Ctx, a: &Array, v: Vec<T>, n: Option<u64>) -> Result<Vec<T>, MeshError> {
    match n {
        Some(n) if v.len() as u64 != n => Err(ctx_err(ctx, a, format!("has {} values, expected {n}", v.len()))),
        _ => Ok(v),
    }
}

pub(crate) fn reals(ctx: &Ctx, a: &Array, n: u64) -> Result<Vec<f64>, MeshError> {
    if a.fmt == Fmt::Ascii {
        return values(ctx.path, a, Some(n));
    }
    let b = binary_bytes(ctx, a, Some(n))?;
    let v = to_f64(&b, &a.ty, ctx.enc.endian).ok_or_else(|| ctx_err(ctx, a, "has no numeric type".into()))?;
    exact(ctx, a, v, Some(n))
}

pub(crate) fn ints(ctx: &Ctx, a: &Array, n: Option<u64>) -> Result<Vec<i64>, MeshError> {
    if a.fmt == Fmt::Ascii {
        return values(ctx.path, a, n);
    }
    let b = binary_bytes(ctx, a, n)?;
    let v = to_i64(&b, &a.ty, ctx.enc.endian)
        .ok_or_else(|| ctx_err(ctx, a, format!("must hold integers, not '{}'", quote(&a.ty))))?;
    exact(ctx, a, v, n)
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
    let sets: Vec<(String, Vec<u8>)> = mesh
        .node_sets()
        .iter()
        .map(|(name, ids)| (format!("{SET_PREFIX}{name}"), membership(n, ids)))
        .collect();
    let cells: Vec<u32> = mesh.tets().iter().flatten().copied().collect();
    write_ascii(path, pos, 10, 4, &cells, &sets, point_vectors, point_scalars)
}

/// Writes a `.vtu` of arbitrary cells of one VTK type (e.g. 5 = triangle,
/// 1 = vertex), `nodes_per_cell` indices each in `cells`, for surfaces and
/// points that are not a [`TetMesh`] (the state stream's decimated surface
/// and its tool). Arrays as in [`write_vtu_with_data`]; every array must have
/// one value per point, indices must be in range, positions finite.
pub fn write_vtu_cells(
    path: &Path,
    points: &[Vec3],
    cell_type: u8,
    nodes_per_cell: usize,
    cells: &[u32],
    point_vectors: &[(&str, &[Vec3])],
    point_scalars: &[(&str, &[f64])],
) -> Result<(), MeshError> {
    let n = points.len();
    let bad = |what: String| MeshError::InvalidData {
        path: path.to_path_buf(),
        what,
    };
    if nodes_per_cell == 0 || cells.len() % nodes_per_cell != 0 {
        return Err(bad(format!(
            "{} cell indices for {nodes_per_cell} per cell",
            cells.len()
        )));
    }
    if let Some(i) = cells.iter().find(|&&i| i as usize >= n) {
        return Err(bad(format!("cell index {i} out of range ({n} points)")));
    }
    if let Some(i) = points.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(bad(format!("position of point {i} is not finite")));
    }
    let lens = point_vectors.iter().map(|(k, v)| (*k, v.len()));
    if let Some((k, l)) = lens
        .chain(point_scalars.iter().map(|(k, v)| (*k, v.len())))
        .find(|&(_, l)| l != n)
    {
        return Err(bad(format!("point array '{k}' has {l} values for {n} points")));
    }
    write_ascii(
        path,
        points,
        cell_type,
        nodes_per_cell,
        cells,
        &[],
        point_vectors,
        point_scalars,
    )
}

/// The ASCII `.vtu` body both writers share: `u8` point flags (node sets),
/// `Float64` vectors and scalars, points, then cells of one type. Inputs are
/// already validated.
#[allow(clippy::too_many_arguments)]
fn write_ascii(
    path: &Path,
    points: &[Vec3],
    cell_type: u8,
    nodes_per_cell: usize,
    cells: &[u32],
    flags: &[(String, Vec<u8>)],
    point_vectors: &[(&str, &[Vec3])],
    point_scalars: &[(&str, &[f64])],
) -> Result<(), MeshError> {
    let n = points.len();
    let ncells = cells.len() / nodes_per_cell.max(1);
    write_file(path, |w| {
        writeln!(w, "<?xml version=\"1.0\"?>")?;
        writeln!(
            w,
            "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">"
        )?;
        writeln!(w, "  <UnstructuredGrid>")?;
        writeln!(w, "    <Piece NumberOfPoints=\"{n}\" NumberOfCells=\"{ncells}\">")?;
        writeln!(w, "      <PointData>")?;
        for (name, values) in flags {
            let name = escape(name);
            writeln!(w, "        <DataArray type=\"Int32\" Name=\"{name}\" format=\"ascii\">")?;
            for v in values {
                writeln!(w, "{v}")?;
            }
            writeln!(w, "        </DataArray>")?;
        }
        for (name, v) in point_vectors {
            let name = escape(name);
            writeln!(
                w,
                "        <DataArray type=\"Float64\" Name=\"{name}\" NumberOfComponents=\"3\" format=\"ascii\">"
            )?;
            for x in *v {
                writeln!(w, "{} {} {}", x.x, x.y, x.z)?;
            }
            writeln!(w, "        </DataArray>")?;
        }
        for (name, v) in point_scalars {
            let name = escape(name);
            writeln!(
                w,
                "        <DataArray type=\"Float64\" Name=\"{name}\" format=\"ascii\">"
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
        for x in points {
            writeln!(w, "{} {} {}", x.x, x.y, x.z)?;
        }
        writeln!(w, "        </DataArray>")?;
        writeln!(w, "      </Points>")?;
        writeln!(w, "      <Cells>")?;
        writeln!(
            w,
            "        <DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">"
        )?;
        for c in cells.chunks(nodes_per_cell.max(1)) {
            for (k, i) in c.iter().enumerate() {
                if k > 0 {
                    write!(w, " ")?;
                }
                write!(w, "{i}")?;
            }
            writeln!(w)?;
        }
        writeln!(w, "        </DataArray>")?;
        writeln!(
            w,
            "        <DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">"
        )?;
        for k in 1..=ncells {
            writeln!(w, "{}", nodes_per_cell * k)?;
        }
        writeln!(w, "        </DataArray>")?;
        writeln!(w, "        <DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">")?;
        for _ in 0..ncells {
            writeln!(w, "{cell_type}")?;
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
///     let u = vec![nvtmm::math::Vec3::zeros(); mesh.num_nodes()];
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

    /// Writes step `len()` at `time` (seconds) as `<name>_NNNNNN.vtu` by
    /// calling `write` with that path (e.g. with [`write_vtu_cells`]),
    /// updates the `.pvd`, and returns the `.vtu` path.
    pub fn add_file(
        &mut self,
        time: f64,
        write: impl FnOnce(&Path) -> Result<(), MeshError>,
    ) -> Result<PathBuf, MeshError> {
        let file = format!("{}_{:06}.vtu", self.name, self.steps.len());
        let path = self.dir.join(&file);
        if !time.is_finite() {
            return Err(MeshError::InvalidData {
                path,
                what: format!("step time {time} is not finite"),
            });
        }
        write(&path)?;
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
