//! End to end, as a trainee drives it: the guidewire service on the UDP
//! bridge (the branched arch of the guidewire tests, about 2000 nodes),
//! `nvtmm view --drive` as its device, and the page in headless Chromium
//! steered by real keyboard events sent through the DevTools protocol
//! (`Input.dispatchKeyEvent`). The keys roll the angled tip, insert the wire
//! up the aorta, roll it toward the left subclavian and advance it; the
//! page's task panel must say "success" (the wire's last 20 mm in the left
//! subclavian, `[task]`). Then the X-ray view: the wire is darker than the
//! background, and the vessel shows only after a contrast injection.
//!
//! A second test measures key press → pose datagram latency on loopback:
//! the test owns the UDP socket the poses go to and times each key press
//! until the first pose that carries it (no bound asserted: a timing on a
//! shared machine; the figure goes to docs/DRIVING.md).
//!
//! Needs Chromium like `tests/viewer_shows_the_stream_in_chromium.rs`
//! (SKIPPED without one, failing under `CI=true`); `#[ignore]`d in the plain
//! run, `.ci/run` runs it with `-- --ignored`.

mod common;

use serde_json::{json, Value};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::chromium::{chromium, get, Killed};

fn free_tcp() -> String {
    TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .to_string()
}

fn free_udp() -> String {
    UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .to_string()
}

/// GET /json/list from Chromium's DevTools server, which keeps the
/// connection open: the body by its Content-Length.
fn json_list(addr: &str) -> Option<String> {
    let mut s = TcpStream::connect(addr).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).ok()?;
    write!(s, "GET /json/list HTTP/1.1\r\nHost: {addr}\r\n\r\n").ok()?;
    let mut buf = Vec::new();
    let mut chunk = [0u8; 4096];
    loop {
        let n = s.read(&mut chunk).ok()?;
        if n == 0 {
            return None;
        }
        buf.extend_from_slice(&chunk[..n]);
        let text = String::from_utf8_lossy(&buf).to_string();
        if let Some(h) = text.find("\r\n\r\n") {
            let len = text[..h]
                .lines()
                .find_map(|l| {
                    l.to_ascii_lowercase()
                        .strip_prefix("content-length:")
                        .map(|v| v.trim().to_string())
                })
                .and_then(|v| v.parse::<usize>().ok())?;
            if buf.len() >= h + 4 + len {
                return Some(String::from_utf8_lossy(&buf[h + 4..h + 4 + len]).to_string());
            }
        }
    }
}

fn wait_for(what: &str, secs: u64, mut ok: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !ok() {
        assert!(t0.elapsed() < Duration::from_secs(secs), "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn skip_without_chromium(name: &str) -> Option<PathBuf> {
    let bin = chromium();
    if bin.is_none() {
        assert!(
            std::env::var("CI").map_or(true, |v| v != "true"),
            "CI=true but no Chromium: .ci/run installs Debian's chromium"
        );
        eprintln!("SKIPPED {name}: no chromium on PATH (install Debian's `chromium`, or set NVTMM_CHROMIUM)");
    }
    bin
}

/// A page in headless Chromium, driven over the DevTools protocol.
struct Page {
    _chrome: Killed,
    ws: tungstenite::WebSocket<TcpStream>,
    id: u64,
}

impl Page {
    fn open(bin: &Path, url: &str, profile: &Path) -> Page {
        let mut c = Command::new(bin)
            .args([
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--hide-scrollbars",
                "--no-first-run",
                "--window-size=900,650",
                "--remote-debugging-port=0",
                "--remote-allow-origins=*",
                url,
            ])
            .arg(format!("--user-data-dir={}", profile.display()))
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start chromium");
        let err = c.stderr.take().expect("stderr");
        let chrome = Killed(c);
        // Read stderr to the end on a thread (a full pipe would stall
        // Chromium); the DevTools address comes back on a channel.
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(err).lines().map_while(Result::ok) {
                if let Some(rest) = line.split("DevTools listening on ws://").nth(1) {
                    let _ = tx.send(rest.split('/').next().unwrap_or("").to_string());
                }
            }
        });
        let devtools = rx
            .recv_timeout(Duration::from_secs(60))
            .expect("chromium printed its DevTools address");
        let mut target = None;
        wait_for("the page target", 30, || {
            let body = json_list(&devtools).unwrap_or_default();
            let v: Value = serde_json::from_str(&body).unwrap_or(Value::Null);
            target = v.as_array().and_then(|a| {
                a.iter()
                    .find(|t| t["type"] == "page")
                    .and_then(|t| t["webSocketDebuggerUrl"].as_str().map(String::from))
            });
            target.is_some()
        });
        let url = target.unwrap();
        let tcp = TcpStream::connect(&devtools).unwrap();
        tcp.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
        let (ws, _) = tungstenite::client(url.as_str(), tcp).expect("DevTools WebSocket");
        let mut p = Page {
            _chrome: chrome,
            ws,
            id: 0,
        };
        p.call("Page.bringToFront", json!({}));
        p
    }

    fn call(&mut self, method: &str, params: Value) -> Value {
        self.id += 1;
        let id = self.id;
        self.ws
            .send(tungstenite::Message::text(
                json!({"id": id, "method": method, "params": params}).to_string(),
            ))
            .expect("DevTools send");
        loop {
            let m = self.ws.read().expect("DevTools reply");
            if let tungstenite::Message::Text(t) = m {
                let v: Value = serde_json::from_str(t.as_str()).unwrap_or(Value::Null);
                if v["id"] == id {
                    assert!(v.get("error").is_none(), "{method}: {v}");
                    return v["result"].clone();
                }
            }
        }
    }

    fn eval(&mut self, expr: &str) -> Value {
        let r = self.call("Runtime.evaluate", json!({"expression": expr, "returnByValue": true}));
        r["result"]["value"].clone()
    }

    fn key(&mut self, key: &str, down: bool) {
        let (code, vk) = match key {
            "ArrowUp" => ("ArrowUp".to_string(), 38),
            "ArrowDown" => ("ArrowDown".to_string(), 40),
            "ArrowLeft" => ("ArrowLeft".to_string(), 37),
            "ArrowRight" => ("ArrowRight".to_string(), 39),
            k => {
                let c = k.chars().next().unwrap_or(' ').to_ascii_uppercase();
                if c.is_ascii_digit() {
                    (format!("Digit{c}"), c as i64)
                } else {
                    (format!("Key{c}"), c as i64)
                }
            }
        };
        let mut p = json!({
            "type": if down { "keyDown" } else { "keyUp" },
            "key": key, "code": code, "windowsVirtualKeyCode": vk,
        });
        if down && key.len() == 1 {
            p["text"] = json!(key);
        }
        self.call("Input.dispatchKeyEvent", p);
    }

    fn press(&mut self, key: &str) {
        self.key(key, true);
        self.key(key, false);
    }

    /// The drive status the page shows (inserted m, roll rad).
    fn drive(&mut self) -> (f64, f64) {
        let v = self.eval("drive.status ? [drive.status.inserted_m, drive.status.roll_rad] : null");
        match v.as_array() {
            Some(a) => (a[0].as_f64().unwrap_or(0.0), a[1].as_f64().unwrap_or(0.0)),
            None => (f64::NAN, f64::NAN),
        }
    }

    /// Holds `key` until `done(inserted, roll)`.
    fn hold_until(&mut self, key: &str, what: &str, done: impl Fn(f64, f64) -> bool) {
        self.key(key, true);
        let t0 = Instant::now();
        loop {
            let (i, r) = self.drive();
            if done(i, r) {
                break;
            }
            assert!(t0.elapsed() < Duration::from_secs(60), "{what}: at {i} m, {r} rad");
            std::thread::sleep(Duration::from_millis(20));
        }
        self.key(key, false);
        let (i, r) = self.drive();
        println!("{what}: inserted {:.1} mm, roll {:.2} rad", i * 1e3, r);
    }

    fn screenshot(&mut self) -> (Vec<u8>, usize, usize) {
        let r = self.call("Page.captureScreenshot", json!({"format": "png"}));
        let bytes = base64_decode(r["data"].as_str().expect("screenshot data"));
        let dec = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut rd = dec.read_info().unwrap();
        let mut buf = vec![0; rd.output_buffer_size().unwrap()];
        let info = rd.next_frame(&mut buf).unwrap();
        let ch = info.color_type.samples();
        let (w, h) = (info.width as usize, info.height as usize);
        let grey = buf[..info.buffer_size()]
            .chunks(ch)
            .map(|p| ((p[0] as u32 + p[1] as u32 + p[2] as u32) / 3) as u8)
            .collect();
        (grey, w, h)
    }
}

/// Standard base64 (the DevTools screenshot), no external crate.
fn base64_decode(s: &str) -> Vec<u8> {
    let val = |c: u8| match c {
        b'A'..=b'Z' => Some(c - b'A'),
        b'a'..=b'z' => Some(c - b'a' + 26),
        b'0'..=b'9' => Some(c - b'0' + 52),
        b'+' => Some(62),
        b'/' => Some(63),
        _ => None,
    };
    let mut out = Vec::with_capacity(s.len() * 3 / 4);
    let (mut acc, mut bits) = (0u32, 0);
    for v in s.bytes().filter_map(val) {
        acc = (acc << 6) | v as u32;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
        }
    }
    out
}

fn mean_at(img: &(Vec<u8>, usize, usize), pts: &[(f64, f64)]) -> f64 {
    let (g, w, h) = img;
    let vals: Vec<f64> = pts
        .iter()
        .filter(|(x, y)| *x >= 0.0 && *y >= 0.0 && (*x as usize) < *w && (*y as usize) < *h)
        .map(|(x, y)| g[(*y as usize) * w + *x as usize] as f64)
        .collect();
    assert!(!vals.is_empty(), "no probe point on the screenshot");
    vals.iter().sum::<f64>() / vals.len() as f64
}

fn points(v: &Value) -> Vec<(f64, f64)> {
    v.as_array()
        .map(|a| {
            a.iter()
                .filter_map(|p| Some((p[0].as_f64()?, p[1].as_f64()?)))
                .collect()
        })
        .unwrap_or_default()
}

#[test]
#[ignore = "needs Chromium: cargo test --release --test browser_drives_the_wire_in_chromium -- --ignored (CI runs it)"]
fn keys_drive_the_wire_into_the_left_subclavian_and_the_xray_shows_it() {
    let Some(bin) = skip_without_chromium("keys_drive_the_wire_into_the_left_subclavian") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (http, stream, device, hud) = (free_tcp(), free_udp(), free_udp(), free_udp());
    let cfg = common::guidewire::write_udp(dir.path(), &device, &stream, &hud);
    let nvtmm = env!("CARGO_BIN_EXE_nvtmm");
    let _view = Killed(
        Command::new(nvtmm)
            .args(["view", "--listen", &http, "--stream", &stream, "--drive"])
            .arg(&cfg)
            .stdout(Stdio::null())
            .spawn()
            .unwrap(),
    );
    wait_for("the viewer", 120, || {
        get(&http, "/drive/info").is_some_and(|r| r.contains("\"enabled\":true"))
    });
    let _service = Killed(
        Command::new(nvtmm)
            .args(["run", cfg.to_str().unwrap(), "--seconds", "300", "--quiet"])
            .stdout(Stdio::null())
            .spawn()
            .unwrap(),
    );
    wait_for("frames at the viewer", 300, || {
        get(&http, "/stats").is_some_and(|s| !s.contains("\"frames\":0,"))
    });
    let mut page = Page::open(&bin, &format!("http://{http}/"), &dir.path().join("profile"));
    wait_for("the page to drive", 30, || {
        let (i, _) = page.drive();
        i.is_finite()
    });
    // The shipped script's moves, by keys: roll half a turn for the climb,
    // insert to 150 mm, roll back toward the ostium, advance into the branch.
    page.hold_until("ArrowRight", "roll for the climb", |_, r| r >= 3.05);
    page.hold_until("ArrowUp", "up the aorta", |i, _| i >= 0.148);
    page.hold_until("ArrowLeft", "roll toward the ostium", |_, r| r <= 0.05);
    let mut success = false;
    let mut target = 0.18;
    let t0 = Instant::now();
    while !success && target <= 0.23 {
        page.hold_until("ArrowUp", "advance", |i, _| i >= target);
        let t1 = Instant::now();
        while t1.elapsed() < Duration::from_secs(8) {
            let task = page.eval("document.getElementById('task').textContent");
            if task.as_str().is_some_and(|t| t.contains("success")) {
                success = true;
                println!("task panel: {}", task.as_str().unwrap());
                break;
            }
            std::thread::sleep(Duration::from_millis(200));
        }
        target += 0.01;
    }
    let task = page.eval("document.getElementById('task').textContent");
    assert!(success, "no success on the page after {:?}: {task}", t0.elapsed());

    // The X-ray view: fluoroscopy on (f), straight AP.
    page.press("1");
    page.press("f");
    std::thread::sleep(Duration::from_millis(800));
    // The pixel checks read the X-ray image itself: the text panels over it
    // (HUD, task, drive, key legend) are hidden for them, so that neither
    // the background's median nor a wire sample falls on a panel.
    page.eval(
        "['hud','task','drive','legend','help'].forEach(i => { const e = document.getElementById(i); if (e) e.style.visibility = 'hidden'; }); 1",
    );
    std::thread::sleep(Duration::from_millis(100));
    let before = page.screenshot();
    let probe = page.eval("JSON.stringify(xr.probe)");
    let probe: Value = serde_json::from_str(probe.as_str().expect("probe")).unwrap();
    let (wire, lumen) = (points(&probe["wire"]), points(&probe["lumen"]));
    assert!(wire.len() > 5 && lumen.len() > 10, "probe: {probe}");
    let mut sorted = before.0.clone();
    sorted.sort_unstable();
    let median = sorted[sorted.len() / 2] as f64;
    let wire_v = mean_at(&before, &wire);
    println!("X-ray: wire {wire_v:.0}, median {median:.0}");
    assert!(
        wire_v < median - 25.0,
        "the wire ({wire_v:.0}) is not darker than the background ({median:.0})"
    );
    // Away from the vessel: the corners of the body, which no lumen pixel reaches.
    let (w, h) = (before.1 as f64, before.2 as f64);
    let far: Vec<(f64, f64)> = [(0.1, 0.1), (0.9, 0.1), (0.1, 0.9), (0.9, 0.9), (0.5, 0.05)]
        .iter()
        .flat_map(|(fx, fy)| (0..5).map(move |k| (fx * w + k as f64 * 3.0, fy * h)))
        .collect();
    let lumen_before = mean_at(&before, &lumen);
    let far_before = mean_at(&before, &far);
    page.press("c");
    std::thread::sleep(Duration::from_millis(1200));
    let after = page.screenshot();
    let lumen_after = mean_at(&after, &lumen);
    let far_after = mean_at(&after, &far);
    println!(
        "X-ray: lumen {lumen_before:.0} → {lumen_after:.0} with contrast, far from it {far_before:.0} → {far_after:.0}"
    );
    assert!(
        lumen_after < lumen_before - 25.0,
        "the vessel did not appear with the injection: {lumen_before:.0} → {lumen_after:.0}"
    );
    assert!(
        (far_after - far_before).abs() < 10.0,
        "pixels away from the vessel changed: {far_before:.0} → {far_after:.0}"
    );
    if std::env::var_os("NVTMM_UPDATE_SCREENSHOT").is_some() {
        let r = page.call("Page.captureScreenshot", json!({"format": "png"}));
        let to = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/img/xray.png");
        std::fs::write(to, base64_decode(r["data"].as_str().unwrap())).unwrap();
    }
}

#[test]
#[ignore = "needs Chromium: cargo test --release --test browser_drives_the_wire_in_chromium -- --ignored (CI runs it)"]
fn key_press_to_pose_latency_on_loopback() {
    use nvtmm::haptics::udp::decode_pose;
    let Some(bin) = skip_without_chromium("key_press_to_pose_latency_on_loopback") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (http, stream, hud) = (free_tcp(), free_udp(), free_udp());
    // The test is the service's bridge: it owns the socket the poses go to.
    let bridge = UdpSocket::bind("127.0.0.1:0").unwrap();
    bridge.set_read_timeout(Some(Duration::from_millis(100))).unwrap();
    let cfg = common::guidewire::write_udp(dir.path(), &bridge.local_addr().unwrap().to_string(), &stream, &hud);
    let nvtmm = env!("CARGO_BIN_EXE_nvtmm");
    let _view = Killed(
        Command::new(nvtmm)
            .args(["view", "--listen", &http, "--stream", &stream, "--drive"])
            .arg(&cfg)
            .stdout(Stdio::null())
            .spawn()
            .unwrap(),
    );
    wait_for("the viewer", 120, || {
        get(&http, "/drive/info").is_some_and(|r| r.contains("\"enabled\":true"))
    });
    let mut page = Page::open(&bin, &format!("http://{http}/"), &dir.path().join("profile"));
    let mut buf = [0u8; 256];
    fn drain(bridge: &UdpSocket) -> Option<nvtmm::haptics::udp::PoseDatagram> {
        let mut buf = [0u8; 256];
        let mut last = None;
        bridge.set_nonblocking(true).unwrap();
        while let Ok(n) = bridge.recv(&mut buf) {
            last = decode_pose(&buf[..n]).ok();
        }
        bridge.set_nonblocking(false).unwrap();
        last
    }
    wait_for("poses", 30, || {
        std::thread::sleep(Duration::from_millis(50));
        drain(&bridge).is_some()
    });
    let mut lat_ms = Vec::new();
    for k in 0..60 {
        std::thread::sleep(Duration::from_millis(120));
        let _ = drain(&bridge);
        // The instrument switch (i) is button 0 in the very next message.
        let t0 = Instant::now();
        page.key("i", true);
        let mut got = None;
        while t0.elapsed() < Duration::from_secs(2) {
            if let Ok(n) = bridge.recv(&mut buf) {
                if decode_pose(&buf[..n]).is_ok_and(|p| p.buttons & 1 != 0) {
                    got = Some(t0.elapsed());
                    break;
                }
            }
        }
        page.key("i", false);
        if let Some(d) = got {
            lat_ms.push(d.as_secs_f64() * 1e3);
        } else {
            println!("press {k}: no pose with the button within 2 s");
        }
        // Let the 300 ms pulse end before the next press.
        std::thread::sleep(Duration::from_millis(350));
    }
    assert!(lat_ms.len() >= 50, "{} of 60 presses arrived", lat_ms.len());
    lat_ms.sort_by(f64::total_cmp);
    let q = |p: f64| lat_ms[((lat_ms.len() - 1) as f64 * p).round() as usize];
    println!(
        "key press → pose datagram on loopback over {} presses: p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms",
        lat_ms.len(),
        q(0.5),
        q(0.99),
        lat_ms[lat_ms.len() - 1]
    );
}
