//! `nvtmm view`: receives the UDP stream and serves a self-contained web page
//! (HTML + JS compiled into the binary, no CDN) that draws it, fed over a
//! WebSocket on the same port.
//!
//! Threads only: one receives and decodes datagrams into the latest topology
//! and state; one accepts HTTP connections; each WebSocket client gets a
//! thread that waits for new frames and forwards them. A slow client only
//! delays itself (writes time out and drop it).
//!
//! `GET /snapshot` returns the latest topology and state messages (each
//! behind its u32 length) so the page draws at once on load.
//!
//! WebSocket messages (binary): a 12-byte header — kind u8 (1 topology, 2
//! state), 3 zero bytes, epoch u32, seq u32, little-endian — followed by the
//! message payload exactly as in `docs/STREAM.md`. After each state, a text
//! message with the decoder's counters as JSON.

use super::format::{self, KIND_STATE, KIND_TOPOLOGY, MAX_DATAGRAM};
use super::{Decoded, Decoder, DecoderStats, StreamError};
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream, UdpSocket};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::Duration;
use tungstenite::protocol::Role;
use tungstenite::{Bytes, Message, WebSocket};

/// The page, compiled in.
pub const PAGE: &str = include_str!("viewer.html");

const MAX_CLIENTS: usize = 32;
const MAX_REQUEST: usize = 16 * 1024;

#[derive(Debug, Default)]
struct Latest {
    topology: Option<Bytes>,
    topology_version: u64,
    state: Option<Bytes>,
    state_version: u64,
    stats: DecoderStats,
    clients: usize,
}

#[derive(Debug, Default)]
struct Shared {
    latest: Mutex<Latest>,
    changed: Condvar,
    connections: AtomicUsize,
    /// The browser as a device (`nvtmm view --drive`).
    drive: Option<Arc<super::drive::DriveServer>>,
    /// The newest task summary (JSON) from the service (`[task] hud_target`).
    task: Mutex<Option<String>>,
    /// The lumen for the X-ray view (JSON), if known.
    lumen: Option<String>,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Latest> {
        // A panicking holder cannot leave `Latest` half-updated in a way that
        // matters (every field is replaced whole), so keep serving.
        self.latest.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// A running viewer (threads keep running for the process lifetime).
#[derive(Debug)]
pub struct Viewer {
    http: SocketAddr,
    stream: SocketAddr,
    shared: Arc<Shared>,
}

/// The viewer's counters.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ViewerStats {
    /// Decoder counters of the UDP stream.
    pub decoder: DecoderStats,
    /// WebSocket clients connected now.
    pub clients: usize,
}

fn ws_message(kind: u8, epoch: u32, seq: u32, payload: impl FnOnce(&mut Vec<u8>)) -> Bytes {
    let mut m = Vec::new();
    m.push(kind);
    m.extend_from_slice(&[0, 0, 0]);
    m.extend_from_slice(&epoch.to_le_bytes());
    m.extend_from_slice(&seq.to_le_bytes());
    payload(&mut m);
    Bytes::from(m)
}

fn stats_json(s: &DecoderStats, clients: usize) -> String {
    let mut v = serde_json::json!({
        "datagrams": s.datagrams,
        "topologies": s.topologies,
        "frames": s.states,
        "gaps": s.gaps,
        "reordered": s.reordered,
        "stale": s.stale,
        "incomplete": s.incomplete,
        "duplicates": s.duplicates,
        "awaiting_topology": s.awaiting_topology,
        "rejected": s.total_rejected(),
        "clients": clients,
    });
    for r in format::RejectReason::ALL {
        v[format!("rejected_{}", r.name())] = s.rejected_for(r).into();
    }
    v.to_string()
}

/// Binds the HTTP listener at `listen` and the UDP receiver at `stream`, and
/// starts the threads. Returns once both are bound.
pub fn start(listen: SocketAddr, stream: SocketAddr) -> Result<Viewer, StreamError> {
    start_with(ViewOptions {
        listen,
        stream,
        drive: None,
        task: None,
        lumen: None,
    })
}

/// A lumen surface: vertex positions (m) and triangles.
pub type Lumen = (Vec<[f32; 3]>, Vec<[u32; 3]>);

/// What [`start_with`] serves.
#[derive(Debug, Clone)]
pub struct ViewOptions {
    /// Where to serve the page.
    pub listen: SocketAddr,
    /// Where the stream is received.
    pub stream: SocketAddr,
    /// The browser as a device: the drive server's setup (None: view only).
    pub drive: Option<super::drive::DriveSetup>,
    /// Where task summaries from the service are received (`[task]
    /// hud_target`); None: none.
    pub task: Option<SocketAddr>,
    /// The vessel's lumen for the X-ray view's contrast (its wall's rest
    /// positions, m, and triangles whose normals point into the lumen);
    /// None: the page uses the streamed surface.
    pub lumen: Option<Lumen>,
}

/// Starts a named viewer thread; a refusal names the thread.
fn spawn_named(name: &str, f: impl FnOnce() + Send + 'static) -> Result<(), StreamError> {
    std::thread::Builder::new()
        .name(name.into())
        .spawn(f)
        .map(|_| ())
        .map_err(|source| StreamError::Io {
            path: format!("(thread {name})").into(),
            source,
        })
}

/// [`start`] with a drive server and a task receiver.
pub fn start_with(opts: ViewOptions) -> Result<Viewer, StreamError> {
    let ViewOptions {
        listen,
        stream,
        drive,
        task,
        lumen,
    } = opts;
    let lumen = lumen.map(|(p, t)| {
        serde_json::json!({
            "positions": p.iter().flatten().collect::<Vec<_>>(),
            "triangles": t.iter().flatten().collect::<Vec<_>>(),
        })
        .to_string()
    });
    let drive = match drive {
        Some(d) => {
            let device = d.device;
            Some(Arc::new(super::drive::DriveServer::start(d).map_err(|source| {
                StreamError::Socket {
                    what: "open the drive socket toward",
                    addr: device.to_string(),
                    source,
                }
            })?))
        }
        None => None,
    };
    let task_sock = match task {
        Some(a) => Some(UdpSocket::bind(a).map_err(|source| StreamError::Socket {
            what: "bind the task receiver at",
            addr: a.to_string(),
            source,
        })?),
        None => None,
    };
    let udp = UdpSocket::bind(stream).map_err(|source| StreamError::Socket {
        what: "bind UDP stream receiver at",
        addr: stream.to_string(),
        source,
    })?;
    let http = TcpListener::bind(listen).map_err(|source| StreamError::Socket {
        what: "bind HTTP viewer at",
        addr: listen.to_string(),
        source,
    })?;
    let addrs = (http.local_addr(), udp.local_addr());
    let (Ok(http_addr), Ok(udp_addr)) = addrs else {
        return Err(StreamError::Invalid {
            what: "viewer sockets",
            msg: "no local address".into(),
        });
    };
    let shared = Arc::new(Shared {
        drive,
        lumen,
        ..Shared::default()
    });
    if let Some(sock) = task_sock {
        let sh = shared.clone();
        spawn_named("view-task", move || receive_task(sock, &sh))?;
    }
    let sh = shared.clone();
    spawn_named("view-udp", move || receive(udp, &sh))?;
    let sh = shared.clone();
    spawn_named("view-http", move || {
        for conn in http.incoming().flatten() {
            let sh = sh.clone();
            if sh.connections.fetch_add(1, Ordering::SeqCst) >= MAX_CLIENTS {
                sh.connections.fetch_sub(1, Ordering::SeqCst);
                let _ = respond(conn, "503 Service Unavailable", "text/plain", b"too many connections\n");
                continue;
            }
            let spawned = std::thread::Builder::new().name("view-conn".into()).spawn({
                let sh = sh.clone();
                move || {
                    serve(conn, &sh);
                    sh.connections.fetch_sub(1, Ordering::SeqCst);
                }
            });
            if spawned.is_err() {
                sh.connections.fetch_sub(1, Ordering::SeqCst);
            }
        }
    })?;
    Ok(Viewer {
        http: http_addr,
        stream: udp_addr,
        shared,
    })
}

impl Viewer {
    /// The page's address.
    pub fn http_addr(&self) -> SocketAddr {
        self.http
    }

    /// The UDP address the stream is received on.
    pub fn stream_addr(&self) -> SocketAddr {
        self.stream
    }

    /// The drive server (with `--drive`).
    pub fn drive(&self) -> Option<&Arc<super::drive::DriveServer>> {
        self.shared.drive.as_ref()
    }

    /// Counters now.
    pub fn stats(&self) -> ViewerStats {
        let l = self.shared.lock();
        ViewerStats {
            decoder: l.stats.clone(),
            clients: l.clients,
        }
    }
}

fn receive(udp: UdpSocket, sh: &Shared) {
    let mut dec = Decoder::new();
    let mut buf = vec![0u8; MAX_DATAGRAM + 1];
    loop {
        let n = match udp.recv(&mut buf) {
            Ok(n) => n,
            Err(_) => {
                std::thread::sleep(Duration::from_millis(10));
                continue;
            }
        };
        let got = dec.push(&buf[..n]);
        let mut l = sh.lock();
        match got {
            Ok(Some(Decoded::Topology(t))) => {
                // Re-sends of the same topology do not wake the clients.
                let m = ws_message(KIND_TOPOLOGY, t.epoch, 0, |m| format::encode_topology(&t, m));
                if l.topology.as_ref() != Some(&m) {
                    l.topology = Some(m);
                    l.topology_version += 1;
                }
            }
            Ok(Some(Decoded::State(s))) => {
                if let Some(d) = &sh.drive {
                    // The drive follows the first guidewire on the stream.
                    let wire = s
                        .instruments
                        .iter()
                        .find(|l| super::instrument_kind(l.kind) == Some("guidewire"));
                    d.note_stream_inserted(wire.map_or(0.0, |l| polyline_length(&l.points)));
                }
                l.state = Some(ws_message(KIND_STATE, s.epoch, s.seq, |m| {
                    format::encode_state(&s.as_frame(&s.lines()), m)
                }));
                l.state_version += 1;
            }
            _ => {}
        }
        l.stats = dec.stats().clone();
        drop(l);
        sh.changed.notify_all();
    }
}

/// Arc length (m) of a polyline.
fn polyline_length(p: &[[f32; 3]]) -> f64 {
    p.windows(2)
        .map(|w| {
            let d = [0, 1, 2].map(|k| f64::from(w[1][k] - w[0][k]));
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
        })
        .sum()
}

/// Most bytes of one task datagram.
const MAX_TASK_DATAGRAM: usize = 4096;

/// Keeps the newest task summary (a JSON object) the service sends.
fn receive_task(udp: UdpSocket, sh: &Shared) {
    let mut buf = vec![0u8; MAX_TASK_DATAGRAM + 1];
    loop {
        let n = match udp.recv(&mut buf) {
            Ok(n) => n,
            Err(_) => {
                std::thread::sleep(Duration::from_millis(10));
                continue;
            }
        };
        if n > MAX_TASK_DATAGRAM {
            continue;
        }
        let ok = std::str::from_utf8(&buf[..n])
            .ok()
            .and_then(|t| serde_json::from_str::<crate::task::TaskSummary>(t).ok());
        if let Some(summary) = ok {
            if let Ok(text) = serde_json::to_string(&summary) {
                *sh.task.lock().unwrap_or_else(|e| e.into_inner()) = Some(text);
            }
        }
    }
}

fn respond(mut s: TcpStream, status: &str, ctype: &str, body: &[u8]) -> std::io::Result<()> {
    write!(
        s,
        "HTTP/1.1 {status}\r\nContent-Type: {ctype}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n",
        body.len()
    )?;
    s.write_all(body)?;
    s.flush()
}

/// Reads the request head (up to the blank line).
fn read_head(s: &mut TcpStream) -> Option<String> {
    let mut head = Vec::new();
    let mut b = [0u8; 1024];
    while !head.windows(4).any(|w| w == b"\r\n\r\n") {
        let n = s.read(&mut b).ok()?;
        if n == 0 || head.len() + n > MAX_REQUEST {
            return None;
        }
        head.extend_from_slice(&b[..n]);
    }
    String::from_utf8(head).ok()
}

fn serve(mut s: TcpStream, sh: &Shared) {
    let _ = s.set_read_timeout(Some(Duration::from_secs(5)));
    let _ = s.set_write_timeout(Some(Duration::from_secs(5)));
    let Some(head) = read_head(&mut s) else { return };
    let mut lines = head.split("\r\n");
    let req: Vec<&str> = lines.next().unwrap_or("").split(' ').collect();
    let header = |name: &str| {
        head.split("\r\n").skip(1).find_map(|l| {
            let (k, v) = l.split_once(':')?;
            k.trim().eq_ignore_ascii_case(name).then(|| v.trim().to_string())
        })
    };
    let target = req.get(1).copied().unwrap_or("");
    let (path, query) = target.split_once('?').unwrap_or((target, ""));
    if req.first() != Some(&"GET") {
        let _ = respond(s, "405 Method Not Allowed", "text/plain", b"GET only\n");
        return;
    }
    match path {
        "/" | "/index.html" => {
            let _ = respond(s, "200 OK", "text/html; charset=utf-8", PAGE.as_bytes());
        }
        "/stats" => {
            let body = {
                let l = sh.lock();
                stats_json(&l.stats, l.clients)
            };
            let _ = respond(s, "200 OK", "application/json", body.as_bytes());
        }
        "/snapshot" => {
            let body = snapshot(sh);
            let _ = respond(s, "200 OK", "application/octet-stream", &body);
        }
        "/xray/lumen" => match &sh.lumen {
            Some(body) => {
                let _ = respond(s, "200 OK", "application/json", body.as_bytes());
            }
            None => {
                let _ = respond(
                    s,
                    "404 Not Found",
                    "text/plain",
                    b"no lumen: the X-ray view uses the streamed surface\n",
                );
            }
        },
        "/drive/info" => {
            let body = match &sh.drive {
                Some(d) => format!("{{\"enabled\":true,\"token_required\":{}}}", !d.authorized(None)),
                None => "{\"enabled\":false}".to_string(),
            };
            let _ = respond(s, "200 OK", "application/json", body.as_bytes());
        }
        "/drive" => {
            let Some(d) = sh.drive.clone() else {
                let _ = respond(
                    s,
                    "404 Not Found",
                    "text/plain",
                    b"not driving: start nvtmm view with --drive CONFIG\n",
                );
                return;
            };
            let token = query.split('&').find_map(|kv| kv.strip_prefix("token="));
            if !d.authorized(token) {
                d.count_unauthorized();
                let _ = respond(
                    s,
                    "403 Forbidden",
                    "text/plain",
                    b"a drive token is required: /drive?token=...\n",
                );
                return;
            }
            let Some(key) = header("Sec-WebSocket-Key") else {
                let _ = respond(s, "400 Bad Request", "text/plain", b"WebSocket upgrade expected\n");
                return;
            };
            if !d.connect() {
                let _ = respond(s, "409 Conflict", "text/plain", b"another page is driving\n");
                return;
            }
            let accept = tungstenite::handshake::derive_accept_key(key.as_bytes());
            let ok = write!(
                s,
                "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Accept: {accept}\r\n\r\n"
            );
            if ok.is_ok() {
                let _ = s.set_read_timeout(Some(Duration::from_millis(20)));
                drive_session(WebSocket::from_raw_socket(s, Role::Server, None), &d);
            }
            d.disconnect();
        }
        "/ws" => match header("Sec-WebSocket-Key") {
            Some(key) if header("Upgrade").is_some_and(|u| u.eq_ignore_ascii_case("websocket")) => {
                let accept = tungstenite::handshake::derive_accept_key(key.as_bytes());
                let ok = write!(
                    s,
                    "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Accept: {accept}\r\n\r\n"
                );
                if ok.is_ok() {
                    let _ = s.set_read_timeout(None);
                    sh.lock().clients += 1;
                    forward(WebSocket::from_raw_socket(s, Role::Server, None), sh);
                    sh.lock().clients -= 1;
                }
            }
            _ => {
                let _ = respond(s, "400 Bad Request", "text/plain", b"WebSocket upgrade expected\n");
            }
        },
        _ => {
            let _ = respond(s, "404 Not Found", "text/plain", b"not found\n");
        }
    }
}

/// The latest topology and state messages, each behind its u32 length
/// (waits up to 5 s for both to exist; empty if they do not), so a page
/// draws at once on load, before its WebSocket delivers anything.
fn snapshot(sh: &Shared) -> Vec<u8> {
    let l = sh.lock();
    let (l, _) = sh
        .changed
        .wait_timeout_while(l, Duration::from_secs(5), |l| l.topology.is_none() || l.state.is_none())
        .unwrap_or_else(|e| e.into_inner());
    let mut out = Vec::new();
    if let (Some(t), Some(s)) = (&l.topology, &l.state) {
        for m in [t, s] {
            out.extend_from_slice(&(m.len() as u32).to_le_bytes());
            out.extend_from_slice(m);
        }
    }
    out
}

/// One driving page: its commands in, its status out (every 100 ms),
/// until it goes away.
fn drive_session(mut ws: WebSocket<TcpStream>, d: &super::drive::DriveServer) {
    let mut last_status = std::time::Instant::now() - Duration::from_secs(1);
    loop {
        match ws.read() {
            Ok(Message::Text(t)) => {
                let _ = d.handle_text(t.as_str());
            }
            Ok(Message::Binary(_)) => {
                d.handle_binary();
            }
            Ok(Message::Close(_)) => return,
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
            Err(_) => return,
        }
        if last_status.elapsed() >= Duration::from_millis(100) {
            last_status = std::time::Instant::now();
            let body = serde_json::json!({ "drive": d.status() }).to_string();
            match ws.send(Message::text(body)) {
                Ok(()) => {}
                Err(tungstenite::Error::Io(e))
                    if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
                Err(_) => return,
            }
        }
    }
}

/// Sends the latest topology and state to one client until it goes away.
fn forward(mut ws: WebSocket<TcpStream>, sh: &Shared) {
    let (mut topo_v, mut state_v) = (0u64, 0u64);
    loop {
        let (topo, state, stats) = {
            let l = sh.lock();
            let (l, _) = sh
                .changed
                .wait_timeout_while(l, Duration::from_millis(1000), |l| {
                    l.topology_version == topo_v && l.state_version == state_v
                })
                .unwrap_or_else(|e| e.into_inner());
            let topo = (l.topology_version != topo_v).then(|| l.topology.clone()).flatten();
            let state = (l.state_version != state_v).then(|| l.state.clone()).flatten();
            topo_v = l.topology_version;
            state_v = l.state_version;
            (topo, state, stats_json(&l.stats, l.clients))
        };
        let task = sh.task.lock().unwrap_or_else(|e| e.into_inner()).clone();
        let stats = match task {
            Some(t) => format!("{{\"task\":{t},{}", &stats[1..]),
            None => stats,
        };
        let mut send = |m: Message| ws.send(m).is_ok();
        if let Some(t) = topo {
            if !send(Message::Binary(t)) {
                return;
            }
        }
        if let Some(s) = state {
            if !send(Message::Binary(s)) {
                return;
            }
        }
        if !send(Message::text(stats)) {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stream::{Publisher, StateFrame, StreamConfig, Topology};

    #[test]
    fn page_and_frames_reach_a_websocket_client() {
        let v = start("127.0.0.1:0".parse().unwrap(), "127.0.0.1:0".parse().unwrap()).unwrap();
        let mut s = TcpStream::connect(v.http_addr()).unwrap();
        write!(s, "GET / HTTP/1.1\r\nHost: x\r\n\r\n").unwrap();
        let mut page = String::new();
        s.read_to_string(&mut page).unwrap();
        assert!(page.starts_with("HTTP/1.1 200"));
        assert!(page.contains("<canvas"));
        let tcp = TcpStream::connect(v.http_addr()).unwrap();
        tcp.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        let (mut ws, _) = tungstenite::client(format!("ws://{}/ws", v.http_addr()), tcp).unwrap();
        let topo = Topology {
            epoch: 2,
            rest_positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            triangles: vec![[0, 1, 2]],
            node_ids: vec![0, 1, 2],
        };
        let cfg = StreamConfig {
            target: v.stream_addr().to_string(),
            ..StreamConfig::default()
        };
        let mut p = Publisher::new(cfg, topo.clone(), None).unwrap();
        let pos = topo.rest_positions.clone();
        let (mut kinds, mut texts) = (Vec::new(), 0);
        for k in 0..200 {
            let f = StateFrame {
                time_s: k as f64 * 0.01,
                positions: &pos,
                tool_position: [0.0; 3],
                tool_radius: 0.01,
                force: [0.0; 3],
                flags: 0,
                loop_rate_hz: 1000.0,
                tick_p99_us: 10.0,
                instruments: &[],
            };
            p.publish(&f).unwrap();
            match ws.read().unwrap() {
                Message::Binary(b) => kinds.push(b[0]),
                Message::Text(_) => texts += 1,
                _ => {}
            }
            if kinds.contains(&KIND_TOPOLOGY) && kinds.contains(&KIND_STATE) && texts > 0 {
                return;
            }
        }
        panic!("got kinds {kinds:?}, {texts} texts");
    }
}
