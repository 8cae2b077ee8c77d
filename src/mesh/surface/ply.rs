//! Stanford PLY (Turk, "The PLY Polygon File Format", 1994): `ascii`,
//! `binary_little_endian` and `binary_big_endian`. The `vertex` element's
//! `x`, `y`, `z` (any scalar type) and the `face` element's list
//! `vertex_indices` (or `vertex_index`) are read; polygons are split into
//! fans. Every other element and property is skipped by its declared type.

use super::{fan, vertex_index, SurfaceMesh};
use crate::math::Vec3;
use crate::mesh::io::scan::{quote, Endian, Scan};
use crate::mesh::io::MeshError;
use std::path::Path;

/// A PLY scalar type.
#[derive(Clone, Copy, PartialEq)]
enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Ty {
    fn parse(t: &str) -> Option<Ty> {
        Some(match t {
            "char" | "int8" => Ty::I8,
            "uchar" | "uint8" => Ty::U8,
            "short" | "int16" => Ty::I16,
            "ushort" | "uint16" => Ty::U16,
            "int" | "int32" => Ty::I32,
            "uint" | "uint32" => Ty::U32,
            "float" | "float32" => Ty::F32,
            "double" | "float64" => Ty::F64,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Ty::I8 | Ty::U8 => 1,
            Ty::I16 | Ty::U16 => 2,
            Ty::I32 | Ty::U32 | Ty::F32 => 4,
            Ty::F64 => 8,
        }
    }
    fn is_float(self) -> bool {
        matches!(self, Ty::F32 | Ty::F64)
    }
}

enum Prop {
    Scalar { name: String, ty: Ty },
    List { name: String, count: Ty, item: Ty },
}

struct Element {
    name: String,
    count: u64,
    props: Vec<Prop>,
}

#[derive(Clone, Copy)]
enum Enc {
    Ascii,
    Binary(Endian),
}

/// One value read from the data, as a number.
#[derive(Clone, Copy)]
enum Val {
    Int(i64),
    Real(f64),
}

impl Val {
    fn real(self) -> f64 {
        match self {
            Val::Int(i) => i as f64,
            Val::Real(r) => r,
        }
    }
}

/// Reads values of the data section, ASCII or binary.
struct Data<'a, 'b> {
    s: &'b mut Scan<'a>,
    enc: Enc,
}

impl Data<'_, '_> {
    fn value(&mut self, ty: Ty, what: &str) -> Result<Val, MeshError> {
        match self.enc {
            Enc::Ascii => {
                if ty.is_float() {
                    self.s.f64(what).map(Val::Real)
                } else {
                    let v = self.s.i64(what)?;
                    let (lo, hi) = match ty {
                        Ty::I8 => (i8::MIN as i64, i8::MAX as i64),
                        Ty::U8 => (0, u8::MAX as i64),
                        Ty::I16 => (i16::MIN as i64, i16::MAX as i64),
                        Ty::U16 => (0, u16::MAX as i64),
                        Ty::I32 => (i32::MIN as i64, i32::MAX as i64),
                        _ => (0, u32::MAX as i64),
                    };
                    if v < lo || v > hi {
                        return Err(self.s.err(format!("{what}: {v} does not fit its type")));
                    }
                    Ok(Val::Int(v))
                }
            }
            Enc::Binary(e) => {
                let b = self.s.bytes(ty.size(), what)?;
                Ok(match ty {
                    Ty::F32 => Val::Real(e.f32(b)),
                    Ty::F64 => Val::Real(e.f64(b)),
                    Ty::U8 | Ty::U16 | Ty::U32 => Val::Int(e.u64(b) as i64),
                    _ => Val::Int(e.i64(b)),
                })
            }
        }
    }

    /// A list's length (an integer count type).
    fn count(&mut self, ty: Ty, what: &str) -> Result<u64, MeshError> {
        match self.value(ty, what)? {
            Val::Int(n) if n >= 0 => Ok(n as u64),
            Val::Int(n) => Err(self.err(format!("{what}: negative list length {n}"))),
            Val::Real(_) => Err(self.err(format!("{what}: a list length must be an integer"))),
        }
    }

    fn err(&self, msg: String) -> MeshError {
        match self.enc {
            Enc::Ascii => self.s.err(msg),
            Enc::Binary(_) => self.s.bin_err(msg),
        }
    }

    /// Skips `n` values of `ty`.
    fn skip(&mut self, n: u64, ty: Ty, what: &str) -> Result<(), MeshError> {
        match self.enc {
            Enc::Ascii => {
                for _ in 0..n {
                    self.s.token(what)?;
                }
                Ok(())
            }
            Enc::Binary(_) => {
                let bytes = n.checked_mul(ty.size() as u64).and_then(|b| usize::try_from(b).ok());
                match bytes {
                    Some(b) => self.s.bytes(b, what).map(|_| ()),
                    None => Err(self.s.bin_err(format!("{what}: {n} values cannot fit in the file"))),
                }
            }
        }
    }
}

/// The header: encoding, elements, and the byte offset where the data starts.
fn header(path: &Path, data: &[u8]) -> Result<(Enc, Vec<Element>, usize), MeshError> {
    let err = |line: usize, msg: String| MeshError::Parse {
        path: path.to_path_buf(),
        line,
        msg,
    };
    let mut pos = 0usize;
    let mut line = 0usize;
    let mut enc = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        line += 1;
        if pos >= data.len() {
            return Err(err(
                line,
                "unexpected end of file: the header has no 'end_header'".into(),
            ));
        }
        let end = data[pos..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(data.len(), |k| pos + k);
        let raw = &data[pos..end];
        pos = (end + 1).min(data.len());
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        let text =
            std::str::from_utf8(raw).map_err(|_| err(line, "a header line is not text (truncated header?)".into()))?;
        let mut tok = text.split_ascii_whitespace();
        let first = tok.next();
        if line == 1 {
            if first != Some("ply") || tok.next().is_some() {
                return Err(err(1, "not a PLY file (the first line must be 'ply')".into()));
            }
            continue;
        }
        match first {
            Some("format") => {
                let f = tok.next().unwrap_or("");
                enc = Some(match f {
                    "ascii" => Enc::Ascii,
                    "binary_little_endian" => Enc::Binary(Endian::Little),
                    "binary_big_endian" => Enc::Binary(Endian::Big),
                    f => return Err(err(line, format!("unknown PLY format '{}'", quote(f)))),
                });
                match tok.next() {
                    Some("1.0") | Some("1") => {}
                    v => {
                        return Err(err(
                            line,
                            format!("PLY version '{}' is not supported (1.0 is)", quote(v.unwrap_or(""))),
                        ))
                    }
                }
            }
            Some("comment") | Some("obj_info") | None => {}
            Some("element") => {
                let name = tok.next().unwrap_or("");
                let count = tok.next().and_then(|c| c.parse::<u64>().ok());
                let (false, Some(count)) = (name.is_empty(), count) else {
                    return Err(err(line, "expected 'element <name> <count>'".into()));
                };
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            Some("property") => {
                let Some(el) = elements.last_mut() else {
                    return Err(err(line, "a property before any element".into()));
                };
                let t = tok.next().unwrap_or("");
                let prop = if t == "list" {
                    let c = tok.next().unwrap_or("");
                    let i = tok.next().unwrap_or("");
                    let name = tok.next().unwrap_or("");
                    let (Some(count), Some(item)) = (Ty::parse(c), Ty::parse(i)) else {
                        return Err(err(
                            line,
                            format!(
                                "list property '{}': unknown type '{}' or '{}'",
                                quote(name),
                                quote(c),
                                quote(i)
                            ),
                        ));
                    };
                    if count.is_float() {
                        return Err(err(
                            line,
                            format!(
                                "list property '{}': the count type must be an integer type",
                                quote(name)
                            ),
                        ));
                    }
                    Prop::List {
                        name: name.to_string(),
                        count,
                        item,
                    }
                } else {
                    let name = tok.next().unwrap_or("");
                    let Some(ty) = Ty::parse(t) else {
                        return Err(err(
                            line,
                            format!("property '{}': unknown type '{}'", quote(name), quote(t)),
                        ));
                    };
                    Prop::Scalar {
                        name: name.to_string(),
                        ty,
                    }
                };
                el.props.push(prop);
            }
            Some("end_header") => break,
            Some(k) => return Err(err(line, format!("unknown header keyword '{}'", quote(k)))),
        }
    }
    let Some(enc) = enc else {
        return Err(err(2, "the header has no 'format' line".into()));
    };
    Ok((enc, elements, pos))
}

pub(super) fn read(path: &Path, data: &[u8]) -> Result<SurfaceMesh, MeshError> {
    let (enc, elements, start) = header(path, data)?;
    let mut s = Scan::new(path, data);
    // Past the header, so that lines and byte offsets count from the file's start.
    s.bytes(start, "the header")?;
    let herr = |msg: String| MeshError::Parse {
        path: path.to_path_buf(),
        line: 1,
        msg,
    };
    let Some(vel) = elements.iter().position(|e| e.name == "vertex") else {
        return Err(herr("the header declares no 'vertex' element".into()));
    };
    let Some(fel) = elements.iter().position(|e| e.name == "face") else {
        return Err(herr(
            "the header declares no 'face' element (a point cloud is not a surface)".into(),
        ));
    };
    let xyz: Vec<Option<usize>> = ["x", "y", "z"]
        .iter()
        .map(|a| {
            elements[vel]
                .props
                .iter()
                .position(|p| matches!(p, Prop::Scalar { name, .. } if name == a))
        })
        .collect();
    if let Some(k) = xyz.iter().position(Option::is_none) {
        return Err(herr(format!(
            "the 'vertex' element has no scalar property '{}'",
            ["x", "y", "z"][k]
        )));
    }
    let Some(fprop) = elements[fel]
        .props
        .iter()
        .position(|p| matches!(p, Prop::List { name, .. } if name == "vertex_indices" || name == "vertex_index"))
    else {
        return Err(herr(
            "the 'face' element has no list property 'vertex_indices' (or 'vertex_index')".into(),
        ));
    };
    let mut vertices: Vec<Vec3> = Vec::new();
    let mut triangles = Vec::new();
    let mut poly: Vec<u32> = Vec::new();
    let mut d = Data { s: &mut s, enc };
    let min_bytes = |el: &Element| match enc {
        Enc::Ascii => 2 * el.props.len().max(1),
        Enc::Binary(_) => el
            .props
            .iter()
            .map(|p| match p {
                Prop::Scalar { ty, .. } => ty.size(),
                Prop::List { count, .. } => count.size(),
            })
            .sum::<usize>()
            .max(1),
    };
    let nverts = elements[vel].count;
    for (ei, el) in elements.iter().enumerate() {
        if ei == vel {
            vertices.reserve(d.s.cap(el.count, min_bytes(el)));
        }
        for item in 0..el.count {
            let mut p = Vec3::zeros();
            for (pi, prop) in el.props.iter().enumerate() {
                match prop {
                    Prop::Scalar { name, ty } => {
                        if ei == vel {
                            if let Some(c) = xyz.iter().position(|&k| k == Some(pi)) {
                                let what = format!("vertex {item}: {name}");
                                let v = d.value(*ty, &what)?.real();
                                if !v.is_finite() {
                                    return Err(d.err(format!("vertex {item}: coordinate {name} is not finite ({v})")));
                                }
                                p[c] = v;
                                continue;
                            }
                        }
                        d.skip(1, *ty, &format!("{} {item}: property {name}", el.name))?;
                    }
                    Prop::List { name, count, item: ity } => {
                        let what = format!("{} {item}: list {name}", el.name);
                        let n = d.count(*count, &what)?;
                        if ei == fel && pi == fprop {
                            if n < 3 {
                                return Err(d.err(format!("face {item}: {n} vertices (at least 3 needed)")));
                            }
                            poly.clear();
                            for _ in 0..n {
                                let v = match d.value(*ity, &what)? {
                                    Val::Int(v) => v,
                                    Val::Real(r) if r.fract() == 0.0 && r.abs() < 9e15 => r as i64,
                                    Val::Real(r) => {
                                        return Err(d.err(format!("face {item}: vertex index {r} is not an integer")))
                                    }
                                };
                                let Some(v) = vertex_index(v, nverts.min(u32::MAX as u64) as usize) else {
                                    return Err(d.err(format!(
                                        "face {item}: vertex index {v} is out of range (the file has {nverts} vertices)"
                                    )));
                                };
                                poly.push(v);
                            }
                            fan(&poly, &mut triangles);
                        } else {
                            d.skip(n, *ity, &what)?;
                        }
                    }
                }
            }
            if ei == vel {
                vertices.push(p);
            }
        }
    }
    if matches!(enc, Enc::Ascii) && !d.s.at_eof() {
        return Err(d.s.err("more data than the header declares"));
    }
    Ok(SurfaceMesh { vertices, triangles })
}
