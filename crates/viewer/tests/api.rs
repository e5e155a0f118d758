//! The viewer's HTTP API over a real socket, on a tiny trained run: renders of the asked size,
//! 400s that name the bad parameter (and a server that keeps serving), nothing served outside
//! the embedded page and the run's known files, the dataset views, ground truth and curves,
//! checkpoint reloading, and the camera-path export read back by the path reader.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::{Duration, Instant};
use viewer::{Viewer, ViewerConfig};

/// A reply: status, headers (lower-case names), body.
struct Reply {
    status: u16,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
}

impl Reply {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
    }
    fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
    fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body).unwrap_or_else(|e| panic!("{e}: {}", self.text()))
    }
    fn png_size(&self) -> (u32, u32) {
        assert_eq!(self.header("content-type"), Some("image/png"), "{}", self.text());
        let img = image::load_from_memory(&self.body).unwrap();
        (img.width(), img.height())
    }
}

/// One HTTP/1.1 request with a raw target (sent as is, so `..` reaches the server).
fn http(addr: SocketAddr, method: &str, target: &str, body: &[u8]) -> Reply {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    let head = format!("{method} {target} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Length: {}\r\n\r\n", body.len());
    s.write_all(head.as_bytes()).unwrap();
    s.write_all(body).unwrap();
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).unwrap();
    let split = raw.windows(4).position(|w| w == b"\r\n\r\n").expect("a header block");
    let head = String::from_utf8_lossy(&raw[..split]).into_owned();
    let mut lines = head.lines();
    let status = lines.next().unwrap().split(' ').nth(1).unwrap().parse().unwrap();
    let headers = lines.filter_map(|l| l.split_once(':')).map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string())).collect();
    Reply { status, headers, body: raw[split + 4..].to_vec() }
}

fn get(addr: SocketAddr, target: &str) -> Reply {
    http(addr, "GET", target, b"")
}

/// A trained run (30 steps of the tiny fast model on the analytic 16×16 dataset), shared by
/// the tests and kept for the process's life.
fn trained_run() -> &'static Path {
    static RUN: OnceLock<PathBuf> = OnceLock::new();
    RUN.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap().keep();
        let data = tmp.join("data");
        nerf::data::synthetic::write(&data, 16, [4, 1, 2], false).unwrap();
        let run = tmp.join("run");
        test_support::training::run_to_end(&mut nerf::train::Trainer::new(config(&data, 30), &run, false).unwrap());
        run
    })
}

fn config(data: &Path, steps: u64) -> nerf::train::TrainConfig {
    nerf::train::TrainConfig::new(data.into(), nerf::models::ModelConfig::Fast(test_support::training::tiny_fast(8, 4)), 128, 1e-2, 1e-3, 400)
        .with_seed(7)
        .with_steps(Some(steps))
        .with_log_interval_steps(10)
        .with_checkpoint_interval_steps(10)
        .with_val_interval_s(Some(1e9))
}

fn start(run: &Path) -> Viewer {
    let mut cfg = ViewerConfig::new(run.into());
    (cfg.threads, cfg.nice, cfg.poll) = (2, 0, Duration::from_millis(20));
    Viewer::start(cfg).unwrap()
}

const POSE: &str = "1,0,0,0,0,1,0,0,0,0,1,3";

fn render_target(w: u32, h: u32, mode: &str) -> String {
    format!("/api/render?w={w}&h={h}&fov=40&c2w={POSE},0,0,0,1&mode={mode}")
}

#[test]
fn render_returns_a_png_of_the_asked_size_in_every_mode() {
    let v = start(trained_run());
    for (mode, (w, h)) in [("rgb", (40, 24)), ("depth", (17, 31)), ("opacity", (1, 1))] {
        let r = get(v.addr(), &render_target(w, h, mode));
        assert_eq!(r.status, 200, "{mode}: {}", r.text());
        assert_eq!(r.png_size(), (w, h), "{mode}");
        assert_eq!(r.header("x-step"), Some("30"));
        assert!(r.header("x-render-ms").unwrap().parse::<f64>().unwrap() >= 0.0);
    }
    let page = get(v.addr(), "/");
    assert_eq!(page.status, 200);
    assert!(page.text().contains("viewer.js"), "{}", page.text());
    for asset in ["/viewer.js", "/viewer.css", "/index.html"] {
        assert_eq!(get(v.addr(), asset).status, 200, "{asset}");
    }
}

#[test]
fn bad_parameters_get_a_400_naming_them_and_the_server_keeps_serving() {
    let v = start(trained_run());
    let nan = "NaN,0,0,0,0,1,0,0,0,0,1,3,0,0,0,1";
    let flat = "1,0,0,0,0,1,0,0,0,0,0,3,0,0,0,1";
    let cases = [
        (render_target(4097, 8, "rgb"), "'w' = 4097"),
        (render_target(8, 0, "rgb"), "'h' = 0"),
        (render_target(8, 8, "normals"), "'mode' = 'normals'"),
        (format!("/api/render?w=8&h=8&fov=40&c2w={nan}"), "not finite"),
        (format!("/api/render?w=8&h=8&fov=40&c2w={flat}"), "rigid, invertible"),
        (format!("/api/render?w=8&h=8&fov=inf&c2w={POSE},0,0,0,1"), "'fov'"),
        ("/api/render?w=8&h=8&fov=40".into(), "missing query parameter 'c2w'"),
        ("/api/gt?view=x".into(), "'view' = 'x'"),
        ("/api/gt?view=0&kind=normal".into(), "'kind' = 'normal'"),
    ];
    for (target, want) in cases {
        let r = get(v.addr(), &target);
        assert_eq!(r.status, 400, "{target}: {}", r.text());
        assert!(r.text().contains(want), "{target}: {}", r.text());
    }
    let unknown = get(v.addr(), "/api/gt?view=99");
    assert_eq!(unknown.status, 404);
    assert!(unknown.text().contains("view 99: the dataset has 7 views"), "{}", unknown.text());
    assert_eq!(http(v.addr(), "POST", "/api/render", b"").status, 405);
    let r = get(v.addr(), &render_target(8, 8, "rgb"));
    assert_eq!((r.status, r.png_size()), (200, (8, 8)));
}

#[test]
fn nothing_outside_the_page_and_the_runs_known_files_is_served() {
    let v = start(trained_run());
    for target in [
        "/../../etc/passwd",
        "/%2e%2e/%2e%2e/etc/passwd",
        "/viewer.js/../../../../etc/passwd",
        "/..%2f..%2fetc%2fpasswd",
        "/api/gt?view=../../../../etc/passwd",
        "/config.json",
        "/checkpoints/step-00000030.ckpt",
        "//etc/passwd",
    ] {
        let r = get(v.addr(), target);
        assert!((400..500).contains(&r.status), "{target}: {} {}", r.status, r.text());
        assert!(!r.text().contains("root:"), "{target}");
    }
    assert_eq!(get(v.addr(), "/api/status").status, 200);
}

#[test]
fn views_ground_truth_error_and_curves() {
    let v = start(trained_run());
    let views = get(v.addr(), "/api/views").json();
    let list = views["views"].as_array().unwrap();
    assert_eq!(list.len(), 7);
    assert_eq!((list[0]["split"].as_str(), list[4]["split"].as_str(), list[6]["split"].as_str()), (Some("train"), Some("val"), Some("test")));
    assert_eq!(list[0]["c2w"].as_array().unwrap().len(), 16);
    assert_eq!(views["center"].as_array().unwrap().len(), 3);
    for target in ["/api/gt?view=5", "/api/gt?view=5&kind=depth", "/api/error?view=5"] {
        let r = get(v.addr(), target);
        assert_eq!(r.status, 200, "{target}: {}", r.text());
        assert_eq!(r.png_size(), (16, 16), "{target}");
    }
    let psnr: f64 = get(v.addr(), "/api/error?view=5").header("x-psnr").unwrap().parse().unwrap();
    assert!(psnr.is_finite() && psnr > 5.0, "{psnr}");
    // The NeRF rendered at a view's pose through /api/render is the picture the error compares.
    let c2w: Vec<String> = list[5]["c2w"].as_array().unwrap().iter().map(|x| x.to_string()).collect();
    let fov = list[5]["fov"].as_f64().unwrap();
    let r = get(v.addr(), &format!("/api/render?w=16&h=16&fov={fov}&c2w={}", c2w.join(",")));
    assert_eq!((r.status, r.png_size()), (200, (16, 16)));
    let m = get(v.addr(), "/api/metrics").json();
    assert_eq!(m["loss"].as_array().unwrap().len(), 3, "{m}");
    assert!(!m["val_psnr"].as_array().unwrap().is_empty(), "{m}");
}

#[test]
fn a_run_without_a_checkpoint_waits_then_newer_checkpoints_are_loaded() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().join("run");
    std::fs::create_dir_all(&run).unwrap();
    let v = start(&run);
    let status = get(v.addr(), "/api/status").json();
    assert!(status["message"].as_str().unwrap().contains("waiting for training to start"), "{status}");
    let r = get(v.addr(), &render_target(8, 8, "rgb"));
    assert_eq!(r.status, 503);
    assert!(r.text().contains("no checkpoint yet"), "{}", r.text());
    // A copy of a trained run's folder appears: its checkpoint is picked up.
    let src = trained_run();
    for rel in ["config.json", "metrics.jsonl"] {
        std::fs::copy(src.join(rel), run.join(rel)).unwrap();
    }
    std::fs::create_dir_all(run.join("checkpoints")).unwrap();
    let ckpt = std::fs::read(src.join("checkpoints/step-00000030.ckpt")).unwrap();
    std::fs::write(run.join("checkpoints/step-00000030.ckpt"), &ckpt).unwrap();
    let step_of = |v: &Viewer| get(v.addr(), &render_target(8, 8, "rgb")).header("x-step").map(str::to_string);
    let wait_for = |want: &str| {
        let t0 = Instant::now();
        while step_of(&v).as_deref() != Some(want) {
            assert!(t0.elapsed() < Duration::from_secs(30), "checkpoint {want} never loaded: {}", get(v.addr(), "/api/status").text());
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    wait_for("30");
    // A newer one replaces it; a damaged newer one is reported and the last good one kept.
    std::fs::write(run.join("checkpoints/step-00000040.ckpt"), &ckpt).unwrap();
    wait_for("40");
    std::fs::write(run.join("checkpoints/step-00000050.ckpt"), b"not a checkpoint").unwrap();
    let t0 = Instant::now();
    while get(v.addr(), "/api/status").json()["error"].is_null() {
        assert!(t0.elapsed() < Duration::from_secs(30), "the damaged checkpoint was never reported");
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(step_of(&v).as_deref(), Some("40"));
}

/// The page's export request, built as `viewer.js` builds it: two keyframes from the current
/// camera (the c2w the page sends to `/api/render`, row by row, and its vertical fov).
#[test]
fn camera_path_export_is_read_back_by_the_render_commands_reader() {
    let v = start(trained_run());
    let k0 = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 3.0, 0.0, 0.0, 0.0, 1.0];
    let (s, c) = (0.6f64.sin(), 0.6f64.cos());
    let k1 = [c, 0.0, s, 3.0 * s, 0.0, 1.0, 0.0, 0.5, -s, 0.0, c, 3.0 * c, 0.0, 0.0, 0.0, 1.0];
    let body = serde_json::json!({
        "keyframes": [{"c2w": k0, "fov": 40.0}, {"c2w": k1, "fov": 50.0}],
        "render_width": 64, "render_height": 48, "fps": 10.0, "seconds": 2.0, "is_cycle": false,
    });
    let r = http(v.addr(), "POST", "/api/camera_path", body.to_string().as_bytes());
    assert_eq!(r.status, 200, "{}", r.text());
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("camera_path.json");
    std::fs::write(&path, &r.body).unwrap();
    let file = dataset::CameraPathFile::read(&path).unwrap();
    let cams = file.cameras(&path).unwrap();
    assert_eq!(cams.len(), 21);
    assert_eq!((file.render_width, file.render_height, file.keyframes.len()), (64, 48, 2));
    assert_eq!(file.camera_path[0].camera_to_world, k0.to_vec());
    assert!((file.camera_path[20].fov - 50.0).abs() < 1e-9 && (file.camera_path[0].fov - 40.0).abs() < 1e-9);
    assert!((cams[20].origin() - glam::DVec3::new(3.0 * s, 0.5, 3.0 * c)).length() < 1e-9);
    for (bad, want) in [
        (serde_json::json!({"keyframes": [], "render_width": 64, "render_height": 48, "fps": 10.0, "seconds": 2.0}), "keyframes: 0 given"),
        (serde_json::json!({"keyframes": [{"c2w": [1.0, 2.0], "fov": 40.0}], "render_width": 64, "render_height": 48, "fps": 10.0, "seconds": 2.0}), "2 numbers"),
        (serde_json::json!({"keyframes": [{"c2w": k0, "fov": 40.0}], "render_width": 0, "render_height": 48, "fps": 10.0, "seconds": 2.0}), "render_width 0"),
    ] {
        let r = http(v.addr(), "POST", "/api/camera_path", bad.to_string().as_bytes());
        assert_eq!(r.status, 400, "{bad}");
        assert!(r.text().contains(want), "{}", r.text());
    }
    assert_eq!(http(v.addr(), "POST", "/api/camera_path", b"{").status, 400);
}

/// Many pages asking at once (a dragged camera's previews, several tabs): every request is
/// answered, a render or a 409 for one replaced by its page's newer request. A handler that
/// waited for the model inside the render pool could be handed another request by that pool
/// and wait for itself.
#[test]
fn concurrent_requests_are_all_answered() {
    let v = start(trained_run());
    let addr = v.addr();
    let clients: Vec<_> = (0..6)
        .map(|c| {
            std::thread::spawn(move || {
                (0..4)
                    .map(|k| {
                        let t = format!("{}&client=c{}&seq={k}", render_target(96 + k, 64, "rgb"), c % 3);
                        get(addr, &t).status
                    })
                    .collect::<Vec<u16>>()
            })
        })
        .collect();
    for c in clients {
        for status in c.join().unwrap() {
            assert!(status == 200 || status == 409, "{status}");
        }
    }
}

/// An IPv6 host (`--host ::1`) is bracketed in the address listened on and in the URL.
#[test]
fn an_ipv6_host_is_served() {
    if std::net::TcpListener::bind("[::1]:0").is_err() {
        return; // no IPv6 loopback on this machine
    }
    let mut cfg = ViewerConfig::new(trained_run().into());
    cfg.host = "::1".into();
    let v = Viewer::start(cfg).unwrap();
    assert!(v.url().starts_with("http://[::1]:"), "{}", v.url());
    assert_eq!(get(v.addr(), "/api/status").status, 200);
}
