//! After construction, the reduced model's `step` — and the RT-path helpers
//! around it, `project_nodal` and `displacement_at` — allocate nothing over
//! 1000 steps: the haptic loop can run it without touching the allocator.

use nvtmm::material::Material;
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::mesh::Vec3;
use nvtmm::model::tmm::Tmm;
use nvtmm::reduced::{DynamicsParams, ModalBasis, ReducedDynamics};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

struct Counting;
static COUNT: AtomicUsize = AtomicUsize::new(0);
thread_local! {
    // Per thread: only the test thread's allocations count (the test harness
    // itself may allocate on its own threads meanwhile).
    static ON: Cell<bool> = const { Cell::new(false) };
}

fn counting() -> bool {
    ON.try_with(|c| c.get()).unwrap_or(false)
}

// SAFETY: forwards to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if counting() {
            COUNT.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        if counting() {
            COUNT.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc_zeroed(l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        if counting() {
            COUNT.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn reduced_step_allocates_nothing() {
    let arch = generate(&ArchParams::default(), 300).expect("arch");
    let mesh = &arch.mesh;
    let mat = Material::aorta();
    let model = Tmm::new(mesh, &mat);
    let mass = mesh.lumped_mass(mat.density);
    let mut fixed = mesh.node_set("inlet").expect("inlet").to_vec();
    fixed.extend_from_slice(mesh.node_set("outlet_descending").expect("outlet"));
    let u0 = vec![Vec3::zeros(); mesh.num_nodes()];
    let node = arch.node(arch.top_ring, 0, arch.grid.layers - 1) as u32;
    let basis = ModalBasis::compute_augmented(mesh, &model, &u0, &mass, &fixed, 8, &[node], None).expect("basis");
    let params = DynamicsParams {
        dt: 1e-3,
        alpha: 5.0,
        beta: 1e-4,
    };
    // Boxed: the capacity-16 matrices are moved once here, not per step.
    let mut d = Box::new(ReducedDynamics::<16>::new(&basis, &params).expect("model"));
    let mut moved = 0.0;

    // The counter itself works: one box is one allocation.
    COUNT.store(0, Ordering::Relaxed);
    ON.with(|c| c.set(true));
    drop(std::hint::black_box(Box::new(1u8)));
    ON.with(|c| c.set(false));
    assert_eq!(COUNT.load(Ordering::Relaxed), 1);

    COUNT.store(0, Ordering::Relaxed);
    ON.with(|c| c.set(true));
    for i in 0..1000 {
        let t = i as f64 * 1e-3;
        let force = Vec3::new(0.0, 0.02 * (40.0 * t).sin(), -0.05);
        let f = match d.project_nodal(&[(node, force)]) {
            Ok(f) => f,
            Err(_) => break,
        };
        d.step(&f);
        moved += d.displacement_at(node).map_or(0.0, |x| x.norm());
    }
    ON.with(|c| c.set(false));
    let count = COUNT.load(Ordering::Relaxed);

    assert!(moved > 0.0, "the loaded node did not move");
    assert_eq!(count, 0, "{count} allocations in 1000 reduced steps");
}
