//! The `nvtmm` command line.
#![warn(clippy::undocumented_unsafe_blocks)]

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;

/// System allocator for ordinary threads; a fixed, prefaulted pool for the
/// RT threads (the haptic loop and the device I/O), which also counts any
/// system-allocator call they make after start (docs/PASSIVITY.md).
#[global_allocator]
static ALLOCATOR: nvtmm::rt::alloc::RtAllocator = nvtmm::rt::alloc::RtAllocator;

mod cli;

#[derive(Parser)]
#[command(
    name = "nvtmm",
    version,
    about = "Real-time nonlinear viscoelastic tensor-mass vessel simulator"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the haptic service: the 1 kHz loop on the reduced NVTMM model, the
    /// background full solve, the device; ends with a report.
    Run {
        /// Service configuration [default: rt-config/nvtmm.toml of the
        /// working directory, else of the source tree the binary was built from].
        config: Option<PathBuf>,
        /// Run length (s); default: the configuration's `seconds`.
        #[arg(long, allow_negative_numbers = true)]
        seconds: Option<f64>,
        /// Also write the report as JSON here.
        #[arg(long)]
        report_json: Option<PathBuf>,
        /// Record the state stream to this file (replay with `nvtmm replay`).
        #[arg(long)]
        record: Option<PathBuf>,
        /// No progress bar.
        #[arg(long)]
        quiet: bool,
    },
    /// Soak and fault campaign: the service on the simulated Touch X (behind
    /// the UDP bridge) with a random hand and faults injected at random
    /// times, every promise checked on every tick (docs/RELIABILITY.md).
    /// Exits non-zero if a check failed.
    Soak {
        /// Service configuration [default: as for `run`].
        config: Option<PathBuf>,
        /// Total length (min); a quarter of it (at least 10 s) at the stiffest material.
        #[arg(long, default_value_t = 1.0)]
        minutes: f64,
        /// Seed of the hand and the fault schedule.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Also write the result as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
        /// No progress lines.
        #[arg(long)]
        quiet: bool,
    },
    /// Audit this box for the real-time loop (PREEMPT_RT, limits, governor,
    /// isolated CPUs, C-states).
    CheckRt {
        /// Service configuration (for the loop's CPU).
        #[arg(long)]
        config: Option<PathBuf>,
        /// JSON output.
        #[arg(long)]
        json: bool,
    },
    /// Generate, inspect, convert and render tetrahedral meshes.
    #[command(subcommand)]
    Mesh(MeshCmd),
    /// Run a scene (the full model, implicit Euler) and write its outputs.
    Simulate {
        /// Scene file (TOML), e.g. rt-config/scenes/arch_press.toml.
        scene: PathBuf,
        /// Output directory (default: out/<scene name>).
        #[arg(long)]
        out: Option<PathBuf>,
        /// No progress bar.
        #[arg(long)]
        quiet: bool,
    },
    /// Benchmarks.
    #[command(subcommand)]
    Bench(BenchCmd),
    /// Reproduce the paper's experiments.
    #[command(subcommand)]
    Experiment(ExperimentCmd),
    /// Compute (or load from the cache) a scene's reduced basis (docs/REDUCED.md).
    Basis {
        /// Scene file (TOML) with a [reduced] table.
        scene: PathBuf,
        /// Basis size (overrides [reduced].r).
        #[arg(long)]
        r: Option<usize>,
        /// Recompute and overwrite the cache file.
        #[arg(long)]
        force: bool,
    },
    /// Replay a stream recording to UDP, or export it for ParaView (--vtu DIR).
    Replay(cli::stream::ReplayArgs),
    /// Serve the stream viewer (a web page on localhost) fed by the UDP stream.
    View(cli::stream::ViewArgs),
    /// Publish a synthetic stream (a dent pressed into the arch) for trying the viewer.
    StreamDemo(cli::stream::DemoArgs),
    /// Summarise a session file (written with `[task] session_dir`) and plot its forces.
    Session(cli::stream::SessionArgs),
}

#[derive(Subcommand)]
enum ExperimentCmd {
    /// Contact anywhere: rendered vs full-model stiffness at random surface points (inner and outer wall), first tick and settled, with and without the residual compliance (docs/RESULTS.md).
    Contact(cli::reduced::ContactArgs),
    /// Linear vs exact cubic reduced StVK: precompute, µs per step, accuracy against the full NVTMM under a large load (docs/RESULTS.md).
    Cubic {
        /// Output directory.
        #[arg(long, default_value = "out/cubic")]
        out: PathBuf,
        /// 1458 nodes, r = 8 and 16 only, no 23k-node precompute rows.
        #[arg(long)]
        quick: bool,
    },
    /// Reduced vs full contact force and displacement over r, and the region-of-interest trade (docs/RESULTS.md).
    Reduced {
        /// Output directory.
        #[arg(long, default_value = "out/reduced")]
        out: PathBuf,
        /// 1458 nodes, r = 8 and 16 only.
        #[arg(long)]
        quick: bool,
    },
    /// Fig. 5: constant force from t = 3 s, TMM vs NVTMM (Prony), 10 s.
    Fig5 {
        /// Output directory.
        #[arg(long, default_value = "out/fig5")]
        out: PathBuf,
        /// Small mesh and short run (seconds), for tests.
        #[arg(long)]
        quick: bool,
    },
    /// Tables I and II: visual and haptic rates of MSM, FEM, NVTMM at 1458/5832/23328 nodes.
    Table {
        /// Output directory.
        #[arg(long, default_value = "out/table")]
        out: PathBuf,
        /// Only 1458 nodes, few frames.
        #[arg(long)]
        quick: bool,
    },
    /// Speed-for-accuracy trade: time per step against error, per knob.
    Trade {
        /// Output directory.
        #[arg(long, default_value = "out/trade")]
        out: PathBuf,
        /// A small mesh and fewer settings.
        #[arg(long)]
        quick: bool,
        /// Only the guidewire's knobs (segments, Newton iterations, contact
        /// stiffness, friction model), a few seconds.
        #[arg(long)]
        wire: bool,
        /// The speed the guidewire rows push the wire at (mm/s, above 0 and
        /// at most 100).
        #[arg(long, default_value_t = 50.0)]
        wire_speed: f64,
    },
}

#[derive(Subcommand)]
enum BenchCmd {
    /// Contact anywhere: the loop's tick (contact, coupled series solve, reduced step) with several patches pressed at once.
    Contact {
        /// Arch nodes.
        #[arg(long, default_value_t = 5832)]
        nodes: usize,
        /// Contact spheres pressed at once (1..=32).
        #[arg(long, default_value_t = 8)]
        patches: usize,
        /// Ticks timed (after 500 of warm-up).
        #[arg(long, default_value_t = 20000)]
        ticks: usize,
        /// JSON output.
        #[arg(long)]
        json: bool,
    },
    /// Time the reduced model: step_with_contact, one refresh, the basis (docs/BENCHMARKS.md).
    Reduced {
        /// Basis size (1..=64).
        #[arg(long)]
        r: usize,
        /// Arch size (nodes).
        #[arg(long, default_value_t = 5832)]
        nodes: usize,
        /// Steps to time (after 100 warm-up steps).
        #[arg(long, default_value_t = 20000)]
        steps: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Time full implicit steps on the built-in arch under the standard load.
    Step {
        /// Model: msm, tmm, nvtmm, fem.
        #[arg(long, default_value = "nvtmm")]
        model: String,
        /// Law: stvk or neo_hookean.
        #[arg(long, default_value = "stvk")]
        law: String,
        /// Arch size (nodes).
        #[arg(long, default_value_t = 1458)]
        nodes: usize,
        /// Steps to time (after 5 warm-up steps).
        #[arg(long, default_value_t = 50)]
        steps: usize,
        /// Add one Prony term (α = 0.5, τ = 0.58 s).
        #[arg(long)]
        prony: bool,
        /// Linear solver: cholesky, cholesky-pcg[:N] (CG on a Cholesky factor refreshed every N solves, default 10), cholesky-pcg32[:N] (the same with an f32 factor), cg-none, cg-jacobi, cg-block_jacobi, cg-block_ssor, cg-block_ic0. The default is the fastest exact setting measured (docs/BENCHMARKS.md).
        #[arg(long, default_value = "cholesky-pcg32:3")]
        linear: String,
        /// Re-assemble the tangent and rebuild the preconditioner/factor
        /// every K steps (1: exact Newton; see docs/SOLVERS.md).
        #[arg(long, default_value_t = 1)]
        stiffness_every: usize,
        /// Skip the residual re-evaluation after the last Newton update (one
        /// force evaluation less per step; same state, no final residual).
        #[arg(long)]
        no_final_residual: bool,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Stability sweep over extreme parameters (prints a Markdown table).
    Extremes {
        /// A representative subset.
        #[arg(long)]
        quick: bool,
        /// Retry a failed step with up to this many halvings of dt
        /// (`[integrator] max_halvings`; 0: off).
        #[arg(long, default_value_t = 0)]
        halvings: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Time the guidewire's step against its node count, in free space and on a wall (docs/WIRE.md).
    Wire {
        /// Only this node count (default: 32, 64, 128, 256, 512).
        #[arg(long)]
        nodes: Option<usize>,
        /// Steps to time per row (after 200 warm-up steps).
        #[arg(long, default_value_t = 2000)]
        steps: usize,
        /// Newton iterations per step at most (the wire's `newton_iterations`; with --tick, default: the configuration's).
        #[arg(long)]
        iterations: Option<usize>,
        /// With --tick: evaluations of the wire's potential per step at most (the wire's `max_evaluations`; default: the configuration's).
        #[arg(long)]
        evaluations: Option<usize>,
        /// Time the whole tick instead: the wire (default 128 nodes) in the branched arch's lumen, its wall loads on the reduced model, the reduced step and the passivity QP, in one thread.
        #[arg(long)]
        tick: bool,
        /// With --tick: the service configuration whose scene, basis and wire it runs (default: rt-config/guidewire.toml here, else the source tree's).
        #[arg(long)]
        config: Option<PathBuf>,
        /// With --tick: sideways load pressing the wire onto the wall (N/m).
        #[arg(long, default_value_t = 3.0)]
        line_load: f64,
        /// With --tick: rebuild the lumen from the reduced model's deformed wall, as the service does (without the dent of the wire's own loads, docs/WIRE.md "The wall under the wire"), instead of the rest wall.
        #[arg(long)]
        follow_wall: bool,
        /// With --tick: run the ticks as the service's wire thread does, on this CPU at SCHED_FIFO priority 80 with memory locked, one tick a period (the wire's `dt_s`) instead of back to back; where the OS refuses, the output says so.
        #[arg(long, value_name = "CPU")]
        rt: Option<usize>,
        /// Time the coupled step of a wire inside a catheter instead: both of --nodes nodes (default 128) in a curved tube, the hubs moving in and out out of phase and rolling; per-step percentiles and each rod's Newton iterations (docs/CATHETER.md). With --tick: the whole tick with the pair in the branched arch (default config: rt-config/cannulate_left_subclavian.toml), both rods' wall loads on the reduced model.
        #[arg(long)]
        coaxial: bool,
        /// With --tick --coaxial: couple the pair lagged (the catheter under the wire's contact forces of the period before, docs/CATHETER.md "The lagged coupling"), both rods in one thread.
        #[arg(long)]
        lagged: bool,
        /// With --tick --coaxial: couple the pair lagged and step the catheter on a second thread pinned to this CPU while the ticks' thread steps the wire (with --rt: at the same SCHED_FIFO priority, its CPU kept awake).
        #[arg(long, value_name = "CPU")]
        parallel: Option<usize>,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Subcommand)]
enum MeshCmd {
    /// Generate the built-in aortic arch wall mesh.
    Arch {
        /// Target number of nodes (the unbranched arch is within 0.75 %, the branched one within 1 %).
        #[arg(long, default_value_t = 5832)]
        nodes: usize,
        /// Output file; the format comes from the extension (.msh .vtk .vtu .node .ply .obj .stl).
        #[arg(long)]
        out: PathBuf,
        /// `none`: the unbranched tube (structured grid); `three`: the arch with the brachiocephalic
        /// trunk, left common carotid and left subclavian, meshed by the vessel pipeline (docs/VESSEL.md).
        #[arg(long, default_value = "none")]
        branches: String,
        /// Arch type of the branched arch (I, II or III: how far the brachiocephalic origin sits below
        /// the arch top).
        #[arg(long, default_value = "I")]
        arch_type: String,
        /// Element layers through the wall of the branched arch.
        #[arg(long, default_value_t = 1)]
        layers: usize,
    },
    /// Build a tetrahedral vessel wall from a lumen surface (.stl .obj .ply .vtk .vtp): openings from
    /// boundary loops, planar caps or --cut planes; the wall offset outward (docs/VESSEL.md).
    Vessel {
        /// Lumen surface (normals are made to point out of the lumen).
        surface: PathBuf,
        /// Output mesh; the format comes from the extension (.msh .vtk .vtu .node).
        #[arg(long)]
        out: PathBuf,
        /// Wall thickness (m); the default is 1.5 mm.
        #[arg(long, conflicts_with = "wall_ratio")]
        wall_thickness: Option<f64>,
        /// Wall thickness as a fraction of the local lumen radius.
        #[arg(long)]
        wall_ratio: Option<f64>,
        /// Element layers through the wall.
        #[arg(long, default_value_t = 1)]
        layers: usize,
        /// Multiply the surface's coordinates by this factor (e.g. 0.001 for millimetres).
        #[arg(long, default_value_t = 1.0)]
        scale: f64,
        /// Cut the surface with a plane (point and normal, in the surface's unit times --scale = m),
        /// removing the side the normal points to; repeatable.
        #[arg(long, value_name = "PX,PY,PZ,NX,NY,NZ", allow_hyphen_values = true)]
        cut: Vec<String>,
        /// Remesh the lumen so the wall has this many nodes (within 2 %); every vessel keeps at
        /// least 8 nodes around.
        #[arg(long, conflicts_with = "edge_length")]
        nodes: Option<usize>,
        /// Remesh the lumen to this edge length (m), finer where a vessel is thin (8 nodes around).
        #[arg(long)]
        edge_length: Option<f64>,
    },
    /// Print a mesh's size, volume and element quality; for a surface file,
    /// its openings and the `mesh vessel` command that makes a wall of it.
    Info {
        /// Mesh file (.msh .vtk .vtu .node/.ele), or a surface (.stl .obj .ply .vtk .vtp).
        file: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Multiply coordinates by this factor on reading (e.g. 0.001 for millimetres).
        #[arg(long, default_value_t = 1.0)]
        scale: f64,
    },
    /// Convert a mesh between formats (by extension).
    Convert {
        /// Input mesh.
        input: PathBuf,
        /// Output mesh.
        output: PathBuf,
        /// Multiply coordinates by this factor on reading (e.g. 0.001 for millimetres).
        #[arg(long, default_value_t = 1.0)]
        scale: f64,
    },
    /// Render a mesh's surface to a PNG picture.
    Render {
        /// Mesh file, or `arch:N` for the built-in arch with N nodes.
        input: String,
        /// Output PNG.
        #[arg(long)]
        out: PathBuf,
        /// Image width (pixels).
        #[arg(long, default_value_t = 900)]
        width: u32,
        /// Image height (pixels).
        #[arg(long, default_value_t = 700)]
        height: u32,
        /// Camera azimuth about the vertical axis (degrees).
        #[arg(long, default_value_t = 125.0, allow_hyphen_values = true)]
        azimuth: f64,
        /// Camera elevation (degrees).
        #[arg(long, default_value_t = 20.0, allow_hyphen_values = true)]
        elevation: f64,
    },
}

fn main() -> ExitCode {
    // Behave like other Unix tools when stdout is closed early
    // (`nvtmm mesh info x.msh | head`): exit quietly instead of panicking.
    // SAFETY: called first thing, before any other thread exists; restoring
    // the default disposition of SIGPIPE has no other effect.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Run {
            config,
            seconds,
            report_json,
            record,
            quiet,
        } => cli::run::run(config.as_deref(), seconds, report_json.as_deref(), record, quiet),
        Command::Soak {
            config,
            minutes,
            seed,
            json,
            quiet,
        } => cli::run::soak(config, minutes, seed, json.as_deref(), quiet),
        Command::CheckRt { config, json } => cli::run::check_rt(config.as_ref(), json),
        Command::Mesh(cmd) => match cmd {
            MeshCmd::Arch {
                nodes,
                out,
                branches,
                arch_type,
                layers,
            } => match branches.as_str() {
                "none" => cli::mesh::arch(nodes, &out),
                "three" => cli::mesh::branched_arch(nodes, &out, &arch_type, layers),
                other => Err(format!("--branches {other}: expected none or three").into()),
            },
            MeshCmd::Vessel {
                surface,
                out,
                wall_thickness,
                wall_ratio,
                layers,
                scale,
                cut,
                nodes,
                edge_length,
            } => {
                use nvtmm::mesh::vessel::pipeline::SurfaceSize;
                let size = match (nodes, edge_length) {
                    (Some(n), _) => SurfaceSize::Nodes(n),
                    (None, Some(e)) => SurfaceSize::EdgeLength(e),
                    (None, None) => SurfaceSize::Input,
                };
                cli::mesh::vessel(&surface, &out, (wall_thickness, wall_ratio), layers, scale, &cut, size)
            }
            MeshCmd::Info { file, json, scale } => cli::mesh::info(&file, json, scale),
            MeshCmd::Convert { input, output, scale } => cli::mesh::convert(&input, &output, scale),
            MeshCmd::Render {
                input,
                out,
                width,
                height,
                azimuth,
                elevation,
            } => cli::mesh::render(&input, &out, width, height, azimuth, elevation),
        },
        Command::Simulate { scene, out, quiet } => cli::sim::simulate(&scene, out.as_deref(), quiet),
        Command::Basis { scene, r, force } => cli::reduced::basis(&scene, r, force),
        Command::Bench(b) => match b {
            BenchCmd::Contact {
                nodes,
                patches,
                ticks,
                json,
            } => cli::reduced::bench_contact_cmd(nodes, patches, ticks, json),
            BenchCmd::Reduced { r, nodes, steps, json } => cli::reduced::bench_reduced_cmd(r, nodes, steps, json),
            BenchCmd::Step {
                model,
                law,
                nodes,
                steps,
                prony,
                linear,
                stiffness_every,
                no_final_residual,
                json,
            } => cli::sim::bench_step_cmd(
                &model,
                &law,
                nodes,
                steps,
                prony,
                &linear,
                stiffness_every,
                no_final_residual,
                json,
            ),
            BenchCmd::Extremes { quick, halvings, json } => cli::sim::bench_extremes(quick, halvings, json),
            BenchCmd::Wire {
                nodes,
                steps,
                iterations,
                evaluations,
                tick,
                config,
                line_load,
                follow_wall,
                rt,
                coaxial,
                lagged,
                parallel,
                json,
            } => {
                if (lagged || parallel.is_some()) && !(coaxial && tick) {
                    Err("--lagged and --parallel: only with --tick --coaxial".into())
                } else if coaxial && tick {
                    cli::wire::bench_coaxial_tick_cmd(
                        &config.unwrap_or_else(cli::wire::default_coaxial_config),
                        &nvtmm::bench::coaxial_tick::CoaxialTickOptions {
                            nodes: nodes.unwrap_or(128),
                            ticks: steps,
                            line_load,
                            follow_wall,
                            rt_cpu: rt,
                            lagged,
                            parallel,
                        },
                        json,
                    )
                } else if coaxial {
                    cli::wire::bench_coaxial_cmd(nodes.unwrap_or(128), steps, json)
                } else if tick {
                    cli::wire::bench_wire_tick_cmd(
                        &config.unwrap_or_else(cli::wire::default_guidewire_config),
                        &nvtmm::bench::wire_tick::WireTickOptions {
                            nodes: nodes.unwrap_or(128),
                            ticks: steps,
                            iterations,
                            evaluations,
                            line_load,
                            follow_wall,
                            rt_cpu: rt,
                        },
                        json,
                    )
                } else {
                    cli::wire::bench_wire_cmd(nodes, steps, iterations.unwrap_or(3), json)
                }
            }
        },
        Command::Experiment(e) => match e {
            ExperimentCmd::Contact(a) => cli::reduced::experiment_contact(&a),
            ExperimentCmd::Cubic { out, quick } => cli::cubic::experiment_cubic(&out, quick),
            ExperimentCmd::Reduced { out, quick } => cli::reduced::experiment_reduced(&out, quick),
            ExperimentCmd::Fig5 { out, quick } => cli::sim::experiment_fig5(&out, quick),
            ExperimentCmd::Table { out, quick } => cli::sim::experiment_table(&out, quick),
            ExperimentCmd::Trade {
                out,
                quick,
                wire,
                wire_speed,
            } => cli::sim::experiment_trade(&out, quick, wire, wire_speed * 1e-3),
        },
        Command::Replay(a) => cli::stream::replay(a),
        Command::View(a) => cli::stream::view(a),
        Command::StreamDemo(a) => cli::stream::demo(a),
        Command::Session(a) => cli::stream::session(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
