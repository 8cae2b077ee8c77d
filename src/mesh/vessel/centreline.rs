//! Segment labels for any lumen surface, from the tree its openings span.
//!
//! The geodesic distance d from the root opening (the largest, `opening_0`)
//! is computed over the surface's edges (Dijkstra). Its level sets are the
//! vessel's cross-section rings, ordered along the centreline; where the
//! vessel branches, a ring splits in two at the junction's saddle (the
//! carina). The vertices are swept by decreasing d, joining each to the
//! components of the vertices already swept (a union-find, the merge tree
//! of d): every other opening starts a component at its far ring, and a
//! vertex that joins two or more components that each hold an opening is a
//! junction, where a new segment (their parent vessel) starts. Components
//! without an opening (small bumps of d) take the segment of what they merge
//! into. Each vertex is labelled with the segment of the component it
//! joined, so the labels split at every junction: a Y-bifurcation gives
//! three segments, the trunk and one per branch.
//!
//! Segments are named after the opening they end at (`opening_<k>`, k as
//! in the wall's node sets), the root's segment `root` and a segment between
//! two junctions `inner_<i>`.

use crate::mesh::surface::CheckedSurface;
use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// Segment labels of a lumen surface.
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentLabels {
    /// Segment names (index = label).
    pub names: Vec<String>,
    /// The label of each vertex of the surface.
    pub labels: Vec<u8>,
    /// Geodesic distance of each vertex from the root opening (m).
    pub distance: Vec<f64>,
}

#[derive(PartialEq)]
struct Item(f64, u32);
impl Eq for Item {}
impl PartialOrd for Item {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Item {
    fn cmp(&self, o: &Self) -> Ordering {
        o.0.total_cmp(&self.0).then(o.1.cmp(&self.1))
    }
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let p = parent[parent[x as usize] as usize];
        parent[x as usize] = p;
        x = p;
    }
    x
}

/// Labels the vertices of `surface` by vessel segment (see the module
/// documentation). A surface with one opening, or none, is one segment,
/// `root`. More than 255 segments are merged into the last.
pub fn segment_labels(surface: &CheckedSurface) -> SegmentLabels {
    let m = &surface.mesh;
    let n = m.vertices.len();
    let loops = &surface.report.boundary_loops;
    let mut nb: Vec<Vec<u32>> = vec![Vec::new(); n];
    for t in &m.triangles {
        for k in 0..3 {
            nb[t[k] as usize].push(t[(k + 1) % 3]);
            nb[t[(k + 1) % 3] as usize].push(t[k]);
        }
    }
    for l in &mut nb {
        l.sort_unstable();
        l.dedup();
    }
    // Geodesic (edge-graph) distance from the root opening.
    let mut d = vec![f64::INFINITY; n];
    let mut heap = BinaryHeap::new();
    if let Some(root) = loops.first() {
        for &v in &root.vertices {
            d[v as usize] = 0.0;
            heap.push(Item(0.0, v));
        }
    } else if n > 0 {
        d[0] = 0.0;
        heap.push(Item(0.0, 0));
    }
    while let Some(Item(dv, v)) = heap.pop() {
        if dv > d[v as usize] {
            continue;
        }
        for &w in &nb[v as usize] {
            let nd = dv + (m.vertices[w as usize] - m.vertices[v as usize]).norm();
            if nd < d[w as usize] {
                d[w as usize] = nd;
                heap.push(Item(nd, w));
            }
        }
    }
    // Which opening (other than the root) each vertex is on.
    let mut opening = vec![u32::MAX; n];
    for (k, lp) in loops.iter().enumerate().skip(1) {
        for &v in &lp.vertices {
            opening[v as usize] = k as u32;
        }
    }
    let mut names: Vec<String> = Vec::new();
    // Per component root: its segment (or none yet) and whether it holds an
    // opening.
    let mut parent: Vec<u32> = (0..n as u32).collect();
    let mut seg: Vec<u32> = vec![u32::MAX; n];
    let mut significant = vec![false; n];
    let mut label_of = vec![u32::MAX; n];
    let mut order: Vec<u32> = (0..n as u32).collect();
    order.sort_by(|&a, &b| d[b as usize].total_cmp(&d[a as usize]).then(a.cmp(&b)));
    let mut done = vec![false; n];
    let mut pending: Vec<Vec<u32>> = vec![Vec::new(); n];
    // Each opening acts as one piece: its ring's vertices share a component
    // and a segment.
    let mut opening_rep: Vec<Option<u32>> = vec![None; loops.len()];
    let mut opening_seg: Vec<Option<u32>> = vec![None; loops.len()];
    for &v in &order {
        let vi = v as usize;
        let own = (opening[vi] != u32::MAX).then_some(opening[vi] as usize);
        let mut roots: Vec<u32> = nb[vi]
            .iter()
            .copied()
            .filter(|&w| done[w as usize])
            .chain(own.and_then(|k| opening_rep[k]))
            .collect::<Vec<u32>>()
            .into_iter()
            .map(|w| find(&mut parent, w))
            .collect();
        roots.sort_unstable();
        roots.dedup();
        let mut segs: Vec<u32> = roots
            .iter()
            .filter(|&&r| significant[r as usize])
            .map(|&r| seg[r as usize])
            .collect();
        segs.sort_unstable();
        segs.dedup();
        let segment = if let Some(k) = own {
            Some(*opening_seg[k].get_or_insert_with(|| {
                names.push(format!("opening_{k}"));
                (names.len() - 1) as u32
            }))
        } else if segs.len() >= 2 {
            // A junction: the parent vessel starts here.
            names.push(format!("inner_{}", names.len()));
            Some((names.len() - 1) as u32)
        } else {
            segs.first().copied()
        };
        if let Some(k) = own {
            opening_rep[k] = Some(v);
        }
        done[vi] = true;
        // Union everything into v's component.
        let mut merged_pending = Vec::new();
        for &r in &roots {
            parent[r as usize] = v;
            if !significant[r as usize] {
                merged_pending.append(&mut pending[r as usize]);
            }
        }
        significant[vi] = segment.is_some();
        match segment {
            Some(s) => {
                seg[vi] = s;
                label_of[vi] = s;
                for w in merged_pending {
                    label_of[w as usize] = s;
                }
            }
            None => {
                merged_pending.push(v);
                pending[vi] = merged_pending;
            }
        }
    }
    // Whatever never reached an opening (one opening only, or none) is the
    // root's segment, as is the segment the root opening closes.
    if names.is_empty() {
        names.push("root".to_string());
    }
    let mut labels: Vec<u8> = label_of
        .iter()
        .map(|&l| if l == u32::MAX { 0 } else { l.min(254) as u8 })
        .collect();
    if let Some(root) = loops.first() {
        // The segment holding the root opening is the root's.
        if let Some(&v) = root.vertices.first() {
            let s = labels[v as usize] as usize;
            if s < names.len() && names[s].starts_with("inner_") {
                names[s] = "root".to_string();
            }
        }
    }
    // Renumber the inner segments in order of appearance, after the rest.
    let mut k = 0;
    for nme in names.iter_mut() {
        if nme.starts_with("inner_") {
            *nme = format!("inner_{k}");
            k += 1;
        }
    }
    names.truncate(255);
    for l in labels.iter_mut() {
        *l = (*l).min((names.len() - 1) as u8);
    }
    SegmentLabels {
        names,
        labels,
        distance: d,
    }
}
