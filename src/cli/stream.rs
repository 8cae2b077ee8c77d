//! `nvtmm replay`, `nvtmm view` and `nvtmm stream-demo`: the state stream's
//! command-line side (format and code in `nvtmm::stream`, docs/STREAM.md).

use clap::Args;
use nvtmm::mesh::arch::{generate, ArchParams};
use nvtmm::rt::clock;
use nvtmm::stream::demo::Dent;
use nvtmm::stream::{decimate, record, viewer, Publisher, StreamConfig};
use std::net::SocketAddr;
use std::path::PathBuf;

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

/// `nvtmm replay`.
#[derive(Args)]
pub struct ReplayArgs {
    /// Recording (written by `--record` / `Publisher`).
    file: PathBuf,
    /// Send the datagrams to this UDP address at the recorded pace.
    #[arg(long, default_value = "127.0.0.1:7878")]
    to: SocketAddr,
    /// Replay speed factor (2 = twice as fast).
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
    /// Instead of sending, export a ParaView series (surface.pvd, tool.pvd) into DIR.
    #[arg(long, value_name = "DIR")]
    vtu: Option<PathBuf>,
    /// Instead of UDP, serve the recording over OpenIGTLink on this TCP
    /// address (e.g. 127.0.0.1:18944, for 3D Slicer's OpenIGTLinkIF).
    #[arg(long, value_name = "ADDR")]
    igtl: Option<SocketAddr>,
    /// With --igtl: how long to wait for a first client (s).
    #[arg(long, default_value_t = 60.0)]
    wait: f64,
    /// Instead of sending, print where each instrument's tip went: a row
    /// every --every seconds of simulation time and at each frame where a
    /// tip changed segment, named from the recorded run's scene file
    /// (its mesh's segment labels on the inner wall).
    #[arg(long, value_name = "SCENE")]
    tips: Option<PathBuf>,
    /// With --tips: seconds of simulation time between rows.
    #[arg(long, default_value_t = 0.5)]
    every: f64,
}

/// `nvtmm replay FILE --tips SCENE`: the tips' table.
fn tips(file: &std::path::Path, scene: &std::path::Path, every_s: f64) -> Result<()> {
    if !(every_s.is_finite() && every_s >= 0.0) {
        return Err(format!("--every {every_s}: must be a finite number of seconds, 0 or more").into());
    }
    let mesh = nvtmm::scene::Scene::load(scene)?.build_mesh()?;
    let map = match nvtmm::task::SegmentMap::from_mesh(&mesh, "inner_wall") {
        Ok(m) => Some(m),
        Err(e) => {
            eprintln!("note: {}: {e}; the tips are printed without segments", scene.display());
            None
        }
    };
    let segment_of = |p: nvtmm::math::Vec3| map.as_ref().and_then(|m| m.segment_at(p)).map(str::to_string);
    let (rows, stats) = record::tip_trace(file, every_s, &segment_of)?;
    println!("t (s), then per instrument: kind#id, tip x y z (mm), segment; * where a tip changed segment");
    for r in &rows {
        let mut line = format!("{}{:8.3}", if r.entered { '*' } else { ' ' }, r.time_s);
        for t in &r.tips {
            let kind = nvtmm::stream::instrument_kind(t.kind).unwrap_or("instrument");
            let p = t.tip_m * 1e3;
            line += &format!(
                "  {kind}#{} {:7.1} {:7.1} {:7.1} {}",
                t.id,
                p.x,
                p.y,
                p.z,
                t.segment.as_deref().unwrap_or("-")
            );
        }
        println!("{line}");
    }
    if stats.gaps > 0 || stats.total_rejected() > 0 {
        eprintln!(
            "note: {} messages missing, {} datagrams rejected",
            stats.gaps,
            stats.total_rejected()
        );
    }
    Ok(())
}

/// `nvtmm view`.
#[derive(Args)]
pub struct ViewArgs {
    /// Where to serve the page (open http://ADDR/ in a browser).
    #[arg(long, default_value = "127.0.0.1:8080")]
    listen: SocketAddr,
    /// UDP address to receive the stream on.
    #[arg(long, default_value = "127.0.0.1:7878")]
    stream: SocketAddr,
    /// Drive mode: the page becomes the device of the service configured by
    /// CONFIG (its `device.backend` must be "udp"; docs/DRIVING.md).
    #[arg(long, value_name = "CONFIG")]
    drive: Option<PathBuf>,
    /// The token a driving page must present (`?token=...`); needed to drive
    /// from anywhere but this machine. Also read from NVTMM_DRIVE_TOKEN.
    #[arg(long)]
    token: Option<String>,
    /// Allow --listen on an address other than loopback while driving (the
    /// page then controls a haptic device from the network; needs --token).
    #[arg(long)]
    allow_lan: bool,
}

/// `nvtmm session`.
#[derive(Args)]
pub struct SessionArgs {
    /// A session file (`[task] session_dir`).
    file: PathBuf,
    /// Where to write the force plot (PNG); default: FILE with `.png`.
    #[arg(long, value_name = "PNG")]
    plot: Option<PathBuf>,
}

/// Prints a session's summary and plots its forces over time.
pub fn session(a: SessionArgs) -> Result<()> {
    let s = nvtmm::task::Session::load(&a.file)?;
    print!("{}", s.render());
    let png = a.plot.unwrap_or_else(|| a.file.with_extension("png"));
    s.plot(&png)?;
    println!("forces over time: {}", png.display());
    Ok(())
}

/// The drive server's setup from a service configuration.
fn drive_setup(path: &std::path::Path, token: Option<String>) -> Result<(viewer::ViewOptions, String)> {
    let cfg = nvtmm::service::config::ServiceConfig::load(path)?;
    let drive = nvtmm::stream::drive::DriveSetup::from_service(&cfg, token)?;
    let task = match cfg.task.as_ref().map(|t| t.hud_target.as_str()) {
        Some(t) if !t.is_empty() => Some(t.parse()?),
        _ => None,
    };
    // The lumen for the X-ray view: the scene's inner wall at rest.
    let wall_set = cfg.guidewire.as_ref().map_or("inner_wall", |g| g.wall_set.as_str());
    let mesh = nvtmm::scene::Scene::load(&cfg.resolve(&cfg.scene))?.build_mesh()?;
    let wall = nvtmm::wire::coupling::InnerWall::from_mesh(&mesh, wall_set)?;
    let lumen = (
        wall.rest()
            .iter()
            .map(|x| [x.x as f32, x.y as f32, x.z as f32])
            .collect(),
        wall.triangles().to_vec(),
    );
    let what = format!(
        "driving the wire of {} through udp://{}{}",
        path.display(),
        drive.device,
        task.map(|t: SocketAddr| format!(", task figures on udp://{t}"))
            .unwrap_or_default()
    );
    Ok((
        viewer::ViewOptions {
            listen: "127.0.0.1:0".parse()?,
            stream: "127.0.0.1:0".parse()?,
            drive: Some(drive),
            task,
            lumen: Some(lumen),
        },
        what,
    ))
}

/// `nvtmm stream-demo`.
#[derive(Args)]
pub struct DemoArgs {
    /// UDP target.
    #[arg(long, default_value = "127.0.0.1:7878")]
    to: SocketAddr,
    /// Frames per second.
    #[arg(long, default_value_t = 60.0)]
    rate: f64,
    /// Stop after this many seconds (0: run until killed).
    #[arg(long, default_value_t = 0.0)]
    seconds: f64,
    /// Arch mesh size (nodes).
    #[arg(long, default_value_t = 5832)]
    nodes: usize,
    /// Target stream vertices (0: full surface).
    #[arg(long, default_value_t = 2000)]
    decimate: usize,
    /// Also record the datagrams to FILE.
    #[arg(long, value_name = "FILE")]
    record: Option<PathBuf>,
}

/// Replays a recording to UDP or exports it for ParaView.
pub fn replay(a: ReplayArgs) -> Result<()> {
    if let Some(scene) = &a.tips {
        return tips(&a.file, scene, a.every);
    }
    if let Some(dir) = a.vtu {
        let s = record::export_vtu(&a.file, &dir)?;
        println!(
            "wrote {} frames ({:.2} s recorded) to {} and {}",
            s.frames_written,
            s.duration_s,
            dir.join("surface.pvd").display(),
            dir.join("tool.pvd").display()
        );
        if s.decoder.gaps > 0 || s.decoder.total_rejected() > 0 {
            eprintln!(
                "note: {} messages missing, {} datagrams rejected",
                s.decoder.gaps,
                s.decoder.total_rejected()
            );
        }
        return Ok(());
    }
    if let Some(addr) = a.igtl {
        println!(
            "serving {} over OpenIGTLink on {addr} at {}x (waiting up to {} s for a client)",
            a.file.display(),
            a.speed,
            a.wait
        );
        let s = record::replay_igtl(&a.file, addr, a.speed, a.wait)?;
        println!(
            "served {} frames ({:.2} s recorded) from {} datagrams",
            s.frames_written, s.duration_s, s.datagrams
        );
        return Ok(());
    }
    println!("replaying {} to udp://{} at {}x", a.file.display(), a.to, a.speed);
    let s = record::replay_udp(&a.file, a.to, a.speed)?;
    println!(
        "sent {} datagrams ({:.2} s recorded), {} send errors",
        s.datagrams, s.duration_s, s.send_errors
    );
    Ok(())
}

/// Runs the viewer until killed.
pub fn view(mut a: ViewArgs) -> Result<()> {
    if a.token.is_none() {
        a.token = std::env::var("NVTMM_DRIVE_TOKEN").ok().filter(|t| !t.is_empty());
    }
    let v = match &a.drive {
        None => viewer::start(a.listen, a.stream)?,
        Some(path) => {
            let lan_ok = a.allow_lan && a.token.as_deref().is_some_and(|t| t.len() >= 8);
            if !(a.listen.ip().is_loopback() || lan_ok) {
                return Err(format!(
                    "--listen {}: driving from the network needs --allow-lan and a --token of at least 8 characters",
                    a.listen
                )
                .into());
            }
            let (mut opts, what) = drive_setup(path, a.token.clone())?;
            opts.listen = a.listen;
            opts.stream = a.stream;
            let v = viewer::start_with(opts)?;
            println!("nvtmm view: {what}");
            v
        }
    };
    let token = a.token.as_deref().map(|t| format!("?token={t}")).unwrap_or_default();
    println!(
        "nvtmm view: open http://{}/{token} (stream on udp://{})",
        v.http_addr(),
        v.stream_addr()
    );
    let mut last = None;
    loop {
        std::thread::sleep(std::time::Duration::from_secs(5));
        let s = v.stats();
        let now = (s.decoder.states, s.decoder.gaps, s.decoder.total_rejected(), s.clients);
        if last != Some(now) {
            println!(
                "frames {}  gaps {}  rejected {}  clients {}",
                now.0, now.1, now.2, now.3
            );
            last = Some(now);
        }
    }
}

/// Publishes the synthetic dent on the built-in arch.
pub fn demo(a: DemoArgs) -> Result<()> {
    let cfg = StreamConfig {
        rate_hz: a.rate,
        target: a.to.to_string(),
        decimate_vertices: a.decimate,
        ..StreamConfig::default()
    };
    let mesh = generate(&ArchParams::default(), a.nodes)?.mesh;
    let topo = decimate::surface(&mesh, cfg.decimate_vertices);
    println!(
        "stream-demo: {} vertices, {} triangles to udp://{} at {} Hz",
        topo.num_vertices(),
        topo.triangles.len(),
        a.to,
        a.rate
    );
    let mut dent = Dent::new(&mesh, &topo);
    let mut p = Publisher::new(cfg, topo, a.record.as_deref())?;
    let period = (p.period_s() * 1e9) as clock::Nanos;
    let start = clock::now_ns();
    let mut k: i64 = 0;
    loop {
        let t = k as f64 * p.period_s();
        if a.seconds > 0.0 && t > a.seconds {
            break;
        }
        clock::sleep_until(start + k * period);
        dent.with_frame(t, |f| p.publish(f))?;
        k += 1;
    }
    let s = p.finish()?;
    println!(
        "published {} frames, {} datagrams, {} send errors",
        s.frames,
        s.datagrams,
        s.send_errors + s.would_block
    );
    Ok(())
}
