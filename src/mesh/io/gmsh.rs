//! Gmsh `.msh`: reads 4.1 (ASCII and binary) and 2.x ASCII, writes 4.1 ASCII.
//!
//! Hand-written rather than through `mshio`: that crate unwraps parse results
//! on header values a file controls (it panics on an oversized data-size
//! field), ignores `$PhysicalNames`, and its errors carry no line numbers.
//! One reader serves ASCII and binary 4.1 because the two differ only in how a
//! number is encoded ([`Enc`]).
//!
//! Node sets: each named physical group (`$PhysicalNames`) becomes a set of
//! all nodes of the elements in it, whatever their dimension. The writer puts
//! each set in its own point entity as 1-node elements (type 15) carrying one
//! physical group named after the set.

use super::scan::{quote, Endian, Scan};
use super::{write_file, MeshError, RawMesh};
use crate::math::Vec3;
use crate::mesh::TetMesh;
use std::collections::{BTreeMap, HashMap};
use std::io::Write;
use std::path::Path;

/// Gmsh's linear tetrahedron.
const TET4: i64 = 4;
/// Gmsh's 1-node point element.
const POINT1: i64 = 15;

/// (node count, dimension, name) of a Gmsh element type.
fn element_info(ty: i64) -> Option<(usize, u8, &'static str)> {
    Some(match ty {
        1 => (2, 1, "2-node line"),
        2 => (3, 2, "3-node triangle"),
        3 => (4, 2, "4-node quadrangle"),
        4 => (4, 3, "4-node tetrahedron"),
        5 => (8, 3, "8-node hexahedron"),
        6 => (6, 3, "6-node prism"),
        7 => (5, 3, "5-node pyramid"),
        8 => (3, 1, "3-node line"),
        9 => (6, 2, "6-node triangle"),
        10 => (9, 2, "9-node quadrangle"),
        11 => (10, 3, "10-node tetrahedron"),
        12 => (27, 3, "27-node hexahedron"),
        13 => (18, 3, "18-node prism"),
        14 => (14, 3, "14-node pyramid"),
        15 => (1, 0, "1-node point"),
        16 => (8, 2, "8-node quadrangle"),
        17 => (20, 3, "20-node hexahedron"),
        18 => (15, 3, "15-node prism"),
        19 => (13, 3, "13-node pyramid"),
        20 => (9, 2, "9-node triangle"),
        21 => (10, 2, "10-node triangle"),
        22 => (12, 2, "12-node triangle"),
        23 => (15, 2, "15-node triangle"),
        24 => (15, 2, "15-node incomplete triangle"),
        25 => (21, 2, "21-node triangle"),
        26 => (4, 1, "4-node line"),
        27 => (5, 1, "5-node line"),
        28 => (6, 1, "6-node line"),
        29 => (20, 3, "20-node tetrahedron"),
        30 => (35, 3, "35-node tetrahedron"),
        31 => (56, 3, "56-node tetrahedron"),
        92 => (64, 3, "64-node hexahedron"),
        93 => (125, 3, "125-node hexahedron"),
        _ => return None,
    })
}

/// How numbers are encoded in the current file.
#[derive(Clone, Copy)]
enum Enc {
    Ascii,
    Binary { endian: Endian, size_t: usize },
}

/// A cursor that reads Gmsh's three number kinds in either encoding.
struct G<'a> {
    s: Scan<'a>,
    enc: Enc,
}

impl G<'_> {
    fn err(&self, msg: impl Into<String>) -> MeshError {
        match self.enc {
            Enc::Ascii => self.s.err(msg),
            Enc::Binary { .. } => self.s.bin_err(msg),
        }
    }
    /// Where an element error is: a line in text, a byte offset in binary.
    fn loc(&self) -> Loc {
        match self.enc {
            Enc::Ascii => Loc::Line(self.s.line()),
            Enc::Binary { .. } => Loc::Byte(self.s.pos()),
        }
    }
    fn size_t(&mut self, what: &str) -> Result<u64, MeshError> {
        match self.enc {
            Enc::Ascii => self.s.u64(what),
            Enc::Binary { endian, size_t } => Ok(endian.u64(self.s.bytes(size_t, what)?)),
        }
    }
    fn int(&mut self, what: &str) -> Result<i64, MeshError> {
        match self.enc {
            Enc::Ascii => self.s.i64(what),
            Enc::Binary { endian, .. } => Ok(endian.i64(self.s.bytes(4, what)?)),
        }
    }
    fn dbl(&mut self, what: &str) -> Result<f64, MeshError> {
        match self.enc {
            Enc::Ascii => self.s.f64(what),
            Enc::Binary { endian, .. } => Ok(endian.f64(self.s.bytes(8, what)?)),
        }
    }
    /// Smallest encoded size of a size_t, for capping header counts.
    fn min_size_t(&self) -> usize {
        match self.enc {
            Enc::Ascii => 2,
            Enc::Binary { size_t, .. } => size_t,
        }
    }
    /// Steps from binary data back to the text of an `$End…` line.
    fn end_section(&mut self, name: &str) -> Result<(), MeshError> {
        self.s.expect(&format!("$End{name}"))
    }
}

/// Everything the sections give before the mesh is assembled.
#[derive(Default)]
struct Parsed {
    /// (dimension, physical tag) → name.
    names: HashMap<(i64, i64), String>,
    /// (dimension, entity tag) → physical tags (4.1 only).
    entity_phys: HashMap<(i64, i64), Vec<i64>>,
    nodes: Vec<Vec3>,
    node_of_tag: HashMap<u64, u32>,
    have_nodes: bool,
    tets: Vec<[u32; 4]>,
    /// (dimension, physical tag) → node indices of its elements.
    group_nodes: HashMap<(i64, i64), Vec<u32>>,
    have_elements: bool,
}

impl Parsed {
    /// The index of node `tag`, used by element `element` found at `loc`.
    fn node(&self, path: &Path, loc: Loc, element: u64, tag: u64) -> Result<u32, MeshError> {
        self.node_of_tag
            .get(&tag)
            .copied()
            .ok_or_else(|| element_err(path, loc, element, format!("node tag {tag} is not in $Nodes")))
    }

    /// Registers a node; the tag must be new.
    fn add_node(&mut self, tag: u64, x: Vec3) -> Result<(), String> {
        let idx = u32::try_from(self.nodes.len()).map_err(|_| format!("more than {} nodes", u32::MAX))?;
        if self.node_of_tag.insert(tag, idx).is_some() {
            return Err(format!("node tag {tag} appears twice"));
        }
        self.nodes.push(x);
        Ok(())
    }
}

/// Where in the file an element error is.
#[derive(Clone, Copy)]
enum Loc {
    Line(usize),
    Byte(usize),
}

fn element_err(path: &Path, loc: Loc, element: u64, msg: String) -> MeshError {
    match loc {
        Loc::Line(line) => MeshError::Element {
            path: path.to_path_buf(),
            line,
            kind: "element",
            element,
            msg,
        },
        Loc::Byte(offset) => MeshError::Binary {
            path: path.to_path_buf(),
            offset,
            msg: format!("element {element}: {msg}"),
        },
    }
}

pub(crate) fn read(path: &Path, data: &[u8]) -> Result<RawMesh, MeshError> {
    let mut s = Scan::new(path, data);
    let first = s.token("'$MeshFormat'")?;
    if first != "$MeshFormat" {
        return Err(s.err(format!(
            "expected '$MeshFormat' at the start of a Gmsh file, found '{}'",
            quote(first)
        )));
    }
    let version = s.token("the format version")?;
    let file_type = s.u64("the file type (0 = ASCII, 1 = binary)")?;
    let data_size = s.u64("the data size")?;
    let v2 = match version {
        "4.1" => false,
        v if v.starts_with("2.") && v.len() <= 4 => true,
        v => {
            return Err(s.err(format!(
                "Gmsh format version '{}' is not supported (reads 4.1 ASCII/binary and 2.2 ASCII)",
                quote(v)
            )))
        }
    };
    let enc = match file_type {
        0 => Enc::Ascii,
        1 if v2 => {
            return Err(s.err("binary Gmsh 2.x is not supported; save as 4.1 (binary or ASCII) or 2.2 ASCII"));
        }
        1 => {
            let size_t = match data_size {
                4 | 8 => data_size as usize,
                d => return Err(s.err(format!("data size {d} is not supported (expected 4 or 8)"))),
            };
            s.rest_of_line();
            let one = s.bytes(4, "the endianness marker")?;
            let endian = if one == [1, 0, 0, 0] {
                Endian::Little
            } else if one == [0, 0, 0, 1] {
                Endian::Big
            } else {
                return Err(s.bin_err("the binary endianness marker is not the integer 1"));
            };
            Enc::Binary { endian, size_t }
        }
        t => return Err(s.err(format!("file type {t} is not 0 (ASCII) or 1 (binary)"))),
    };
    let mut g = G { s, enc };
    g.end_section("MeshFormat")?;

    let mut p = Parsed::default();
    while !g.s.at_eof() {
        let line = g.s.line();
        let head = g.s.token("a section header")?;
        let Some(name) = head.strip_prefix('$') else {
            return Err(g.s.err(format!(
                "expected a section header such as $Nodes, found '{}'",
                quote(head)
            )));
        };
        if matches!(g.enc, Enc::Binary { .. }) {
            // Binary data starts right after the header's newline.
            g.s.rest_of_line();
        }
        match name {
            "PhysicalNames" => physical_names(&mut g.s, &mut p)?,
            "Entities" if !v2 => entities(&mut g, &mut p)?,
            "Nodes" | "Elements" if (name == "Nodes" && p.have_nodes) || (name == "Elements" && p.have_elements) => {
                return Err(g
                    .s
                    .err_at(line, format!("a second ${name} section (only one is supported)")));
            }
            "Nodes" if v2 => nodes_v2(&mut g.s, &mut p)?,
            "Nodes" => nodes_v4(&mut g, &mut p)?,
            "Elements" if !p.have_nodes => {
                return Err(g.s.err_at(line, "$Elements comes before $Nodes"));
            }
            "Elements" if v2 => elements_v2(&mut g.s, &mut p)?,
            "Elements" => elements_v4(&mut g, &mut p)?,
            other => {
                // Unknown or unused section ($NodeData, $Periodic, …): may hold
                // binary data, so search for its end marker byte-wise.
                let end = format!("$End{other}");
                if !g.s.skip_past(end.as_bytes()) {
                    return Err(g
                        .s
                        .err_at(line, format!("section ${} has no '{}'", quote(other), quote(&end))));
                }
                continue;
            }
        }
        g.end_section(name)?;
    }
    if !p.have_nodes {
        return Err(g.s.err("no $Nodes section"));
    }
    if !p.have_elements {
        return Err(g.s.err("no $Elements section"));
    }
    let mut sets: BTreeMap<String, Vec<u32>> = BTreeMap::new();
    for (key, name) in &p.names {
        let set = sets.entry(name.clone()).or_default();
        if let Some(ids) = p.group_nodes.get(key) {
            set.extend_from_slice(ids);
        }
    }
    Ok(RawMesh {
        nodes: p.nodes,
        tets: p.tets,
        sets,
    })
}

/// `$PhysicalNames` (always text): `dim tag "name"` per line.
fn physical_names(s: &mut Scan, p: &mut Parsed) -> Result<(), MeshError> {
    let n = s.u64("the number of physical names")?;
    s.rest_of_line();
    for _ in 0..n {
        let dim = s.i64("a physical group's dimension")?;
        let tag = s.i64("a physical group's tag")?;
        let line = s.line();
        let rest = s.rest_of_line();
        let rest = std::str::from_utf8(rest).map_err(|_| s.err_at(line, "a physical name is not UTF-8 text"))?;
        let rest = rest.trim();
        let name = match (rest.find('"'), rest.rfind('"')) {
            (Some(a), Some(b)) if b > a => &rest[a + 1..b],
            _ => rest,
        };
        if name.is_empty() {
            return Err(s.err_at(line, format!("physical group ({dim}, {tag}) has an empty name")));
        }
        p.names.insert((dim, tag), name.to_string());
    }
    Ok(())
}

/// 4.1 `$Entities`: only the physical tags of each entity are kept.
fn entities(g: &mut G, p: &mut Parsed) -> Result<(), MeshError> {
    let mut counts = [0u64; 4];
    for (d, c) in counts.iter_mut().enumerate() {
        *c = g.size_t(&format!("the number of {}-D entities", d))?;
    }
    for (dim, &count) in counts.iter().enumerate() {
        for _ in 0..count {
            let tag = g.int("an entity tag")?;
            for _ in 0..if dim == 0 { 3 } else { 6 } {
                g.dbl("an entity coordinate")?;
            }
            let nphys = g.size_t("the number of physical tags")?;
            let mut phys = Vec::with_capacity(g.s.cap(nphys, 2));
            for _ in 0..nphys {
                phys.push(g.int("a physical tag")?);
            }
            if dim > 0 {
                let nb = g.size_t("the number of bounding entities")?;
                for _ in 0..nb {
                    g.int("a bounding entity tag")?;
                }
            }
            p.entity_phys.insert((dim as i64, tag), phys);
        }
    }
    Ok(())
}

fn nodes_v2(s: &mut Scan, p: &mut Parsed) -> Result<(), MeshError> {
    p.have_nodes = true;
    let n = s.u64("the number of nodes")?;
    p.nodes.reserve(s.cap(n, 8));
    for _ in 0..n {
        let tag = s.u64("a node tag")?;
        let x = Vec3::new(
            s.finite("node x coordinate")?,
            s.finite("node y coordinate")?,
            s.finite("node z coordinate")?,
        );
        p.add_node(tag, x).map_err(|m| s.err(m))?;
    }
    Ok(())
}

fn nodes_v4(g: &mut G, p: &mut Parsed) -> Result<(), MeshError> {
    p.have_nodes = true;
    let nblocks = g.size_t("the number of node blocks")?;
    let total = g.size_t("the number of nodes")?;
    g.size_t("the minimum node tag")?;
    g.size_t("the maximum node tag")?;
    p.nodes.reserve(g.s.cap(total, 3 * g.min_size_t()));
    let mut found = 0u64;
    for _ in 0..nblocks {
        let dim = g.int("a node block's entity dimension")?;
        g.int("a node block's entity tag")?;
        let parametric = g.int("a node block's parametric flag")?;
        let n = g.size_t("the number of nodes in the block")?;
        let mut tags = Vec::with_capacity(g.s.cap(n, g.min_size_t()));
        for _ in 0..n {
            tags.push(g.size_t("a node tag")?);
        }
        // Parametric nodes carry u (curves) or u v (surfaces) after x y z.
        let extra = if parametric != 0 { dim.clamp(0, 2) } else { 0 };
        for tag in tags {
            let mut x = Vec3::zeros();
            for (k, axis) in ["x", "y", "z"].iter().enumerate() {
                x[k] = g.dbl(&format!("node {tag}'s {axis} coordinate"))?;
                if !x[k].is_finite() {
                    return Err(g.err(format!("node {tag}: {axis} coordinate is not finite ({})", x[k])));
                }
            }
            for _ in 0..extra {
                g.dbl("a parametric coordinate")?;
            }
            p.add_node(tag, x).map_err(|m| g.err(m))?;
            found += 1;
        }
    }
    if found != total {
        return Err(g.err(format!(
            "the $Nodes header declares {total} nodes but its blocks hold {found}"
        )));
    }
    Ok(())
}

/// The error for a 3-D element that is not a linear tet, or an unknown type.
fn bad_element(path: &Path, loc: Loc, element: u64, ty: i64) -> MeshError {
    let msg = match element_info(ty) {
        Some((_, _, name)) => format!(
            "type {ty} ({name}) is a 3-D element other than the linear tetrahedron (type 4); \
             only linear tets are supported"
        ),
        None => format!("unknown element type {ty}"),
    };
    element_err(path, loc, element, msg)
}

fn elements_v2(s: &mut Scan, p: &mut Parsed) -> Result<(), MeshError> {
    p.have_elements = true;
    let n = s.u64("the number of elements")?;
    for _ in 0..n {
        let tag = s.u64("an element tag")?;
        let ty = s.i64("an element type")?;
        let ntags = s.u64("the number of element tags")?;
        let mut phys = 0;
        for k in 0..ntags {
            let t = s.i64("an element tag value")?;
            if k == 0 {
                phys = t;
            }
        }
        let Some((nn, dim, _)) = element_info(ty).filter(|&(_, d, _)| d < 3 || ty == TET4) else {
            return Err(bad_element(s.path(), Loc::Line(s.line()), tag, ty));
        };
        let mut ids = [0u32; 4];
        let key = (dim as i64, phys);
        let named = phys != 0 && p.names.contains_key(&key);
        // Not an iterator over `ids`: non-tet elements have more than 4 nodes.
        #[allow(clippy::needless_range_loop)]
        for k in 0..nn {
            let t = s.u64("an element's node tag")?;
            let i = p.node(s.path(), Loc::Line(s.line()), tag, t)?;
            if let Some(slot) = ids.get_mut(k).filter(|_| ty == TET4) {
                *slot = i;
            }
            if named {
                p.group_nodes.entry(key).or_default().push(i);
            }
        }
        if ty == TET4 {
            p.tets.push(ids);
        }
    }
    Ok(())
}

fn elements_v4(g: &mut G, p: &mut Parsed) -> Result<(), MeshError> {
    p.have_elements = true;
    let nblocks = g.size_t("the number of element blocks")?;
    let total = g.size_t("the number of elements")?;
    g.size_t("the minimum element tag")?;
    g.size_t("the maximum element tag")?;
    let mut found = 0u64;
    for _ in 0..nblocks {
        let dim = g.int("an element block's entity dimension")?;
        let etag = g.int("an element block's entity tag")?;
        let ty = g.int("an element block's element type")?;
        let n = g.size_t("the number of elements in the block")?;
        if n == 0 {
            continue;
        }
        let info = element_info(ty);
        let nn = match info {
            Some((nn, d, _)) if d < 3 || ty == TET4 => nn,
            _ => {
                let first = g.size_t("an element tag")?;
                return Err(bad_element(g.s.path(), g.loc(), first, ty));
            }
        };
        // Physical groups this block's nodes go to (only named ones).
        let groups: Vec<(i64, i64)> = p
            .entity_phys
            .get(&(dim, etag))
            .map(|ph| {
                ph.iter()
                    .map(|&t| (dim, t.abs()))
                    .filter(|k| p.names.contains_key(k))
                    .collect()
            })
            .unwrap_or_default();
        if ty == TET4 {
            p.tets.reserve(g.s.cap(n, 5 * g.min_size_t()));
        }
        for _ in 0..n {
            let tag = g.size_t("an element tag")?;
            let mut ids = [0u32; 4];
            // Not an iterator over `ids`: non-tet elements have more than 4 nodes.
            #[allow(clippy::needless_range_loop)]
            for k in 0..nn {
                let t = g.size_t("an element's node tag")?;
                let i = p.node(g.s.path(), g.loc(), tag, t)?;
                if let Some(slot) = ids.get_mut(k).filter(|_| ty == TET4) {
                    *slot = i;
                }
                for key in &groups {
                    p.group_nodes.entry(*key).or_default().push(i);
                }
            }
            if ty == TET4 {
                p.tets.push(ids);
            }
            found += 1;
        }
    }
    if found != total {
        return Err(g.err(format!(
            "the $Elements header declares {total} elements but its blocks hold {found}"
        )));
    }
    Ok(())
}

/// A physical name as Gmsh can quote it.
fn gmsh_name(name: &str) -> String {
    name.chars()
        .map(|c| if c == '"' || c.is_control() { '_' } else { c })
        .collect()
}

/// Writes Gmsh 4.1 ASCII: all nodes in one volume entity (tag 1, in an
/// unnamed physical group 1), the tets in it, and each node set as a point entity of 1-node elements with a physical
/// group named after the set (tags 1, 2, … in name order).
pub fn write_gmsh(mesh: &TetMesh, path: &Path) -> Result<(), MeshError> {
    let nodes = mesh.rest();
    let tets = mesh.tets();
    let sets = mesh.node_sets();
    write_file(path, |w| {
        writeln!(w, "$MeshFormat\n4.1 0 8\n$EndMeshFormat")?;
        if !sets.is_empty() {
            writeln!(w, "$PhysicalNames\n{}", sets.len())?;
            for (k, name) in sets.keys().enumerate() {
                writeln!(w, "0 {} \"{}\"", k + 1, gmsh_name(name))?;
            }
            writeln!(w, "$EndPhysicalNames")?;
        }
        let (lo, hi) = mesh.bbox();
        writeln!(w, "$Entities\n{} 0 0 1", sets.len())?;
        for (k, ids) in sets.values().enumerate() {
            // A point entity needs a position: its first node's (or the origin).
            let x = ids.first().map_or(Vec3::zeros(), |&i| nodes[i as usize]);
            writeln!(w, "{} {} {} {} 1 {}", k + 1, x.x, x.y, x.z, k + 1)?;
        }
        // The volume carries an unnamed physical group (3, 1): readers such as
        // meshio expect every element block to have one; ours ignores unnamed groups.
        writeln!(
            w,
            "1 {} {} {} {} {} {} 1 1 0\n$EndEntities",
            lo.x, lo.y, lo.z, hi.x, hi.y, hi.z
        )?;
        let n = nodes.len();
        writeln!(w, "$Nodes\n1 {n} 1 {n}\n3 1 0 {n}")?;
        for i in 1..=n {
            writeln!(w, "{i}")?;
        }
        for x in nodes {
            writeln!(w, "{} {} {}", x.x, x.y, x.z)?;
        }
        writeln!(w, "$EndNodes")?;
        let nset: usize = sets.values().map(Vec::len).sum();
        let total = tets.len() + nset;
        let blocks = 1 + sets.len();
        writeln!(w, "$Elements\n{blocks} {total} 1 {total}\n3 1 {TET4} {}", tets.len())?;
        let mut tag = 0usize;
        for t in tets {
            tag += 1;
            writeln!(w, "{tag} {} {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1, t[3] + 1)?;
        }
        for (k, ids) in sets.values().enumerate() {
            writeln!(w, "0 {} {POINT1} {}", k + 1, ids.len())?;
            for &i in ids {
                tag += 1;
                writeln!(w, "{tag} {}", i + 1)?;
            }
        }
        writeln!(w, "$EndElements")
    })
}
