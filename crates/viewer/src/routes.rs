//! The HTTP API: one function from a request (method, target, body) to a reply, so the server
//! loop stays a loop and the tests can call the same code the network does.
//!
//! | request | reply |
//! |---|---|
//! | `GET /`, `/viewer.js`, `/viewer.css` | the embedded page |
//! | `GET /api/status` | the run, its newest checkpoint, the loaded one, a load error |
//! | `GET /api/views` | the dataset's views (size, vertical fov, pose) and the scene's centre |
//! | `GET /api/render?w&h&c2w&fov&mode&client&seq` | a PNG ([`crate::request`]) |
//! | `GET /api/gt?view&kind=rgb\|depth` | the view's exact ground truth as a PNG |
//! | `GET /api/error?view` | the NeRF's error against it, a heat map PNG (PSNR in `X-PSNR`) |
//! | `GET /api/metrics` | loss and validation PSNR series ([`crate::metrics`]) |
//! | `POST /api/camera_path` | the checked `camera_path.json` ([`crate::export`]) |
//!
//! Anything else is a 404; a bad parameter a 400 with one sentence naming it; a run without a
//! checkpoint a 503 that says so. Renders report their time (`X-Render-Ms`) and the step of
//! the model that drew them (`X-Step`).

use crate::error::{ViewerError, bad};
use crate::query::Target;
use crate::request::{Mode, RenderRequest};
use crate::views::GtKind;
use crate::watch::RunWatch;
use crate::{assets, export, imaging, metrics, views};
use serde_json::json;
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Mutex;
use std::time::{Instant, UNIX_EPOCH};

/// The largest request body read (a camera path's keyframes), bytes.
pub const MAX_BODY: usize = 1 << 20;

/// An answer to a request.
#[derive(Clone, Debug)]
pub struct Reply {
    /// HTTP status.
    pub status: u16,
    /// `Content-Type`.
    pub content_type: &'static str,
    /// Extra headers.
    pub headers: Vec<(&'static str, String)>,
    /// The body.
    pub body: Vec<u8>,
}

impl Reply {
    fn json(v: &serde_json::Value) -> Self {
        Self { status: 200, content_type: "application/json", headers: Vec::new(), body: v.to_string().into_bytes() }
    }

    fn png(body: Vec<u8>) -> Self {
        Self { status: 200, content_type: "image/png", headers: Vec::new(), body }
    }

    /// The reply for an error: its status and its message as plain text.
    pub fn error(e: &ViewerError) -> Self {
        Self { status: e.status(), content_type: "text/plain; charset=utf-8", headers: Vec::new(), body: format!("{e}\n").into_bytes() }
    }
}

/// A rendered picture and how it was made.
#[derive(Clone, Debug)]
pub struct Rendered {
    /// The PNG.
    pub png: Vec<u8>,
    /// Rendering and encoding time, milliseconds.
    pub ms: f64,
    /// Training step of the model that drew it.
    pub step: u64,
}

/// The viewer's state behind every request.
#[derive(Debug)]
pub struct App {
    /// The run.
    pub watch: RunWatch,
    newest: Mutex<HashMap<String, u64>>,
    pool: Option<rayon::ThreadPool>,
}

impl App {
    /// An app viewing `run_dir` (nothing loaded until its watch polls) that renders on `pool`
    /// (the global one when `None`). The request handlers must not be jobs of that pool: a
    /// worker waiting inside a render could pick up another request's job and wait for the
    /// model's lock it holds itself.
    pub fn new(run_dir: PathBuf, pool: Option<rayon::ThreadPool>) -> Self {
        Self { watch: RunWatch::new(run_dir), newest: Mutex::new(HashMap::new()), pool }
    }

    /// Renders `camera` with the loaded model on the render pool; `order` (the page and its
    /// counter) is checked again once the model's lock is held, since a newer request may have
    /// arrived while this one waited.
    fn render_view(&self, l: &crate::watch::Loaded, camera: &dataset::Camera, order: Option<&(String, u64)>) -> Result<nerf::render::RenderedView, ViewerError> {
        l.render(self.pool.as_ref(), camera, || order.map_or(Ok(()), |o| self.check_order(o)))
    }

    fn check_order(&self, (client, seq): &(String, u64)) -> Result<(), ViewerError> {
        let newest = self.newest.lock().unwrap_or_else(|p| p.into_inner()).get(client).copied().unwrap_or(0);
        if *seq < newest {
            return Err(ViewerError::Stale(format!("render {seq} replaced by {newest}")));
        }
        Ok(())
    }

    /// Records a render request's counter when it arrives, so that older requests of the same
    /// page still waiting are dropped (latest request wins).
    pub fn note_arrival(&self, url: &str) {
        let Ok(t) = Target::parse(url) else { return };
        if t.path != "/api/render" {
            return;
        }
        let (Some(seq), client) = (t.get("seq").and_then(|s| s.parse::<u64>().ok()), t.get("client").unwrap_or("")) else { return };
        let mut m = self.newest.lock().unwrap_or_else(|p| p.into_inner());
        if m.len() > 256 {
            m.clear();
        }
        let e = m.entry(client.to_string()).or_insert(seq);
        *e = (*e).max(seq);
    }

    /// Answers one request.
    pub fn handle(&self, method: &str, url: &str, body: &[u8]) -> Reply {
        match Target::parse(url).and_then(|t| self.route(method, &t, body)) {
            Ok(r) => r,
            Err(e) => Reply::error(&e),
        }
    }

    fn route(&self, method: &str, t: &Target, body: &[u8]) -> Result<Reply, ViewerError> {
        let post = t.path == "/api/camera_path";
        match (method, post) {
            ("GET" | "HEAD", false) | ("POST", true) => {}
            _ => return Err(ViewerError::Method(format!("{method} {}: not allowed", t.path))),
        }
        if let Some((ct, bytes)) = assets::asset(&t.path) {
            return Ok(Reply { status: 200, content_type: ct, headers: Vec::new(), body: bytes.to_vec() });
        }
        match t.path.as_str() {
            "/api/status" => Ok(Reply::json(&self.status())),
            "/api/views" => {
                let bounds = self.watch.config()?.bounds;
                Ok(Reply::json(&views::views_json(&*self.watch.dataset()?, bounds.as_ref())))
            }
            "/api/metrics" => Ok(Reply::json(&metrics::curves(self.watch.run_dir())?)),
            "/api/render" => {
                let r = self.render(&RenderRequest::parse(t)?)?;
                let mut reply = Reply::png(r.png);
                reply.headers = vec![("X-Render-Ms", format!("{:.1}", r.ms)), ("X-Step", r.step.to_string())];
                Ok(reply)
            }
            "/api/gt" => self.ground_truth(t),
            "/api/error" => self.error_map(t),
            "/api/camera_path" => {
                let file = export::camera_path(body)?;
                let text = serde_json::to_string_pretty(&file).map_err(|e| ViewerError::Internal(e.to_string()))?;
                Ok(Reply { status: 200, content_type: "application/json", headers: Vec::new(), body: text.into_bytes() })
            }
            p => Err(ViewerError::NotFound(format!("{p}: no such page or endpoint"))),
        }
    }

    fn loaded(&self) -> Result<std::sync::Arc<crate::watch::Loaded>, ViewerError> {
        self.watch.current().ok_or_else(|| match self.watch.failure() {
            Some((k, m)) => ViewerError::Unavailable(format!("the newest checkpoint {} does not load: {m}", k.path.display())),
            None => ViewerError::Unavailable(format!("{}: no checkpoint yet; the viewer loads the first one the trainer writes", self.watch.run_dir().display())),
        })
    }

    /// Renders a checked request with the model in use, as a PNG; a request older than its
    /// page's newest is dropped (409) before rendering.
    pub fn render(&self, req: &RenderRequest) -> Result<Rendered, ViewerError> {
        if let Some(o) = &req.order {
            self.check_order(o)?;
        }
        let l = self.loaded()?;
        let t0 = Instant::now();
        let cam = &req.camera;
        let v = self.render_view(&l, cam, req.order.as_ref())?;
        let rgb = match req.mode {
            Mode::Rgb => imaging::colour(&v.rgb),
            Mode::Opacity => imaging::opacity(&v.opacity),
            Mode::Depth => {
                let (lo, hi) = views::depth_range(cam, l.config.bounds.as_ref());
                imaging::depth(&v.depth, Some(&v.opacity), lo, hi)
            }
        };
        let png = imaging::png(v.width, v.height, &rgb);
        Ok(Rendered { png, ms: t0.elapsed().as_secs_f64() * 1e3, step: l.key.step })
    }

    fn view_index(t: &Target) -> Result<usize, ViewerError> {
        t.number::<usize>("view", None)
    }

    fn ground_truth(&self, t: &Target) -> Result<Reply, ViewerError> {
        let kind = GtKind::parse(t.get("kind").unwrap_or("rgb"))?;
        let k = Self::view_index(t)?;
        let cfg = self.watch.config()?;
        let ds = self.watch.dataset()?;
        let f = views::frame(&ds, k)?;
        let truth = views::truth(f, cfg.background.eval_color())?;
        let rgb = match (kind, &truth.gt) {
            (GtKind::Rgb, _) => imaging::colour(&truth.gt_rgb),
            (GtKind::Depth, Some(g)) => {
                let (lo, hi) = views::depth_range(&f.camera, cfg.bounds.as_ref());
                imaging::depth(&g.depth, None, lo, hi)
            }
            (GtKind::Depth, None) => return Err(ViewerError::NotFound(format!("view {k} ({}): the dataset has no depth ground truth", f.name))),
        };
        Ok(Reply::png(imaging::png(truth.width as u32, truth.height as u32, &rgb)))
    }

    fn error_map(&self, t: &Target) -> Result<Reply, ViewerError> {
        let k = Self::view_index(t)?;
        let l = self.loaded()?;
        let ds = self.watch.dataset()?;
        let f = views::frame(&ds, k)?;
        let bg = l.config.background.eval_color();
        let truth = views::truth(f, bg)?;
        let v = self.render_view(&l, &f.camera, None)?;
        let mse = v.rgb.iter().zip(&truth.gt_rgb).map(|(a, b)| f64::from(a - b).powi(2)).sum::<f64>() / v.rgb.len().max(1) as f64;
        let mut reply = Reply::png(imaging::png(v.width, v.height, &imaging::error_heat(&v.rgb, &truth.gt_rgb)));
        reply.headers = vec![("X-PSNR", format!("{:.2}", -10.0 * mse.max(1e-12).log10())), ("X-Step", l.key.step.to_string())];
        Ok(reply)
    }

    /// The `GET /api/status` body.
    pub fn status(&self) -> serde_json::Value {
        let run = self.watch.run_dir();
        let newest = crate::watch::CheckpointKey::newest(run);
        let secs = |k: &crate::watch::CheckpointKey| k.modified.and_then(|m| m.duration_since(UNIX_EPOCH).ok()).map(|d| d.as_secs_f64());
        let loaded = self.watch.current();
        let failure = self.watch.failure();
        let has_config = run.join(nerf::train::CONFIG_FILE).is_file();
        let message = match (&loaded, &failure, has_config) {
            (Some(l), _, _) => format!("step {} ({})", l.key.step, l.key.path.file_name().unwrap_or_default().to_string_lossy()),
            (None, Some((k, m)), _) => format!("the newest checkpoint {} does not load: {m}", k.path.display()),
            (None, None, false) => "no config.json in the run folder yet: waiting for training to start".into(),
            (None, None, true) => "no checkpoint yet: waiting for the trainer to write one".into(),
        };
        json!({
            "run": run.display().to_string(),
            "config": has_config,
            "newest": newest.as_ref().map(|k| json!({ "step": k.step, "modified_s": secs(k) })),
            "loaded": loaded.as_ref().map(|l| json!({ "step": l.key.step, "modified_s": secs(&l.key) })),
            "error": failure.map(|(_, m)| m),
            "message": message,
        })
    }
}

/// The body of a POST, read up to [`MAX_BODY`] bytes; more is a 400.
pub fn read_body(reader: impl std::io::Read) -> Result<Vec<u8>, ViewerError> {
    use std::io::Read;
    let mut body = Vec::new();
    reader.take(MAX_BODY as u64 + 1).read_to_end(&mut body).map_err(|e| bad(format!("reading the request body: {e}")))?;
    if body.len() > MAX_BODY {
        return Err(bad(format!("request body over {MAX_BODY} bytes")));
    }
    Ok(body)
}
