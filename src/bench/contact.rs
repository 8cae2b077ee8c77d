//! `nvtmm bench contact`: the haptic loop's contact-and-step time with
//! several patches pressed at once (contact anywhere: the residual
//! compliance in series with the penalty), against the number of patches.
//!
//! The service's arch and basis (r = 32 vibration modes here), the
//! residual compliance table, a probe plus `patches − 1` more contact
//! spheres ([`crate::haptics::servo::Servo::set_extra_spheres`]) held
//! 1 mm into the outer wall at random places; the time of
//! [`crate::haptics::servo::Servo::tick`] (contact, the coupled series
//! solve, the reduced implicit step) over `ticks` ticks after a warm-up.

use crate::experiment::contact::Setup;
use crate::haptics::device::DeviceSample;
use crate::reduced::compliance::ComplianceParams;
use crate::rt::stats::Percentiles;
use std::time::Instant;

/// What the benchmark measured.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ContactBench {
    /// Arch nodes.
    pub nodes: usize,
    /// Basis size.
    pub r: usize,
    /// Contact spheres pressed at once.
    pub patches: usize,
    /// Touched nodes on the last tick.
    pub touched_nodes: usize,
    /// On the last tick: surface nodes found by the grid query, deformed
    /// positions computed, triangles integrated and pressure samples
    /// evaluated (all patches together).
    pub candidates: usize,
    /// See `candidates`.
    pub positions: usize,
    /// See `candidates`.
    pub triangles: usize,
    /// See `candidates`.
    pub samples: usize,
    /// Newton iterations of the series solve on the last tick.
    pub iterations: usize,
    /// Ticks (of `ticks`) on which some sphere searched the grid for its
    /// triangles rather than reusing the ones it kept.
    pub search_ticks: usize,
    /// Tick time (µs): p50, p99, p99.9, max.
    pub tick_us: Percentiles,
    /// Building the residual compliance table (s).
    pub table_s: f64,
}

/// Runs it.
pub fn bench_contact(nodes: usize, patches: usize, ticks: usize) -> Result<ContactBench, String> {
    if !(1..=crate::haptics::contact::MAX_SPHERES).contains(&patches) {
        return Err(format!(
            "--patches {patches}: must be in 1..={}",
            crate::haptics::contact::MAX_SPHERES
        ));
    }
    let setup = Setup::new(nodes, 32, &ComplianceParams::default())?;
    let mesh = &setup.mesh;
    let normals = mesh.surface_vertex_normals();
    let outer: Vec<u32> = mesh
        .node_set("outer_wall")
        .unwrap_or(&[])
        .iter()
        .copied()
        .filter(|i| setup.fixed.binary_search(i).is_err())
        .collect();
    if outer.is_empty() {
        return Err("the mesh has no free outer-wall node".into());
    }
    let mut s = 0x9E37_79B9_7F4A_7C15u64;
    let mut centres = Vec::with_capacity(patches);
    for _ in 0..patches {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        let i = outer[((s >> 33) as usize) % outer.len()] as usize;
        centres.push(mesh.rest()[i] + normals[i] * (setup.cp.tool_radius_m - 1e-3));
    }
    let mut servo = setup.servo(true)?;
    servo.set_extra_spheres(&centres[1..]);
    let warm = 500;
    let mut us = Vec::with_capacity(ticks);
    let mut search_ticks = 0;
    for t in 1..=warm + ticks {
        let sample = DeviceSample::held_at(t as u64, t as f64 * 1e-3, centres[0]);
        let t0 = Instant::now();
        servo.tick(Some(&sample), t as f64 * 1e-3, 0);
        if t > warm {
            us.push(t0.elapsed().as_secs_f64() * 1e6);
            search_ticks += (servo.contact().searches > 0) as usize;
        }
    }
    Ok(ContactBench {
        nodes: mesh.num_nodes(),
        r: 32,
        patches,
        touched_nodes: servo.contact().nodes.len(),
        candidates: servo.contact().candidates,
        positions: servo.contact().positions,
        triangles: servo.contact().triangles,
        samples: servo.contact().samples,
        search_ticks,
        iterations: servo.contact().iterations,
        tick_us: Percentiles::of(&us),
        table_s: setup.stats.seconds,
    })
}
