//! The server: a `tiny_http` listener whose requests are answered on a small pool of
//! low-priority threads, and a watcher thread that reloads the run's newest checkpoint.
//!
//! Threads: the acceptor (receives requests, records each render's counter on arrival so stale
//! ones are dropped, hands them on), a few handler threads that answer them, a pool of
//! [`ViewerConfig::threads`] rayon threads that renders (only renders: a handler waits outside
//! it), and the watcher (polls the checkpoint folder every [`ViewerConfig::poll`]). All run at
//! `nice` [`ViewerConfig::nice`] (Linux: per thread), so a trainer on the same machine keeps
//! the cores while the viewer takes what is left (figures in `docs/viewer.md`).

use crate::error::ViewerError;
use crate::routes::{App, Reply, read_body};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

/// Threads that answer requests (renders wait for the model's lock one at a time, while the
/// others answer the status, curves and ground truth).
const HANDLERS: usize = 4;

/// How the viewer is served.
#[derive(Clone, Debug)]
pub struct ViewerConfig {
    /// The run folder.
    pub run_dir: PathBuf,
    /// Address to listen on (`127.0.0.1`: this machine only).
    pub host: String,
    /// Port (0: any free one).
    pub port: u16,
    /// Threads answering requests and rendering.
    pub threads: usize,
    /// Their niceness (0 to 19; 19 yields the most).
    pub nice: i32,
    /// How often the checkpoint folder is looked at.
    pub poll: Duration,
}

impl ViewerConfig {
    /// Serves `run_dir` on 127.0.0.1, any free port, on as many threads as there are cores
    /// at nice 19, looking for a new checkpoint every half second.
    pub fn new(run_dir: PathBuf) -> Self {
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        Self { run_dir, host: "127.0.0.1".into(), port: 0, threads, nice: 19, poll: Duration::from_millis(500) }
    }
}

/// A running viewer; dropping it stops it.
pub struct Viewer {
    addr: SocketAddr,
    app: Arc<App>,
    stop: Arc<AtomicBool>,
    server: Arc<tiny_http::Server>,
    threads: Vec<JoinHandle<()>>,
}

/// Lowers the calling thread's priority to `nice` (Linux's `setpriority` acts on one thread);
/// at 19 the thread also takes the `SCHED_IDLE` policy, which runs it only on a core nothing
/// else wants and lets a waking trainer thread preempt it at once (nice 19 alone still takes
/// its time slices: a trainer whose steps fork and join many times a second waited for them).
#[allow(unsafe_code)]
fn lower_priority(nice: i32) {
    #[cfg(target_os = "linux")]
    // SAFETY: `gettid`, `setpriority` and `sched_setscheduler` take plain integers and a
    // pointer to a local `sched_param` that outlives the call.
    unsafe {
        let tid = libc::gettid();
        if libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, nice) != 0 {
            tracing::debug!("cannot set the viewer thread's nice value to {nice}");
        }
        if nice >= 19 {
            let param = libc::sched_param { sched_priority: 0 };
            if libc::sched_setscheduler(tid, libc::SCHED_IDLE, &param) != 0 {
                tracing::debug!("cannot give the viewer thread the idle scheduling policy");
            }
        }
    }
}

fn respond(app: &App, mut req: tiny_http::Request) {
    let method = req.method().as_str().to_string();
    let url = req.url().to_string();
    let reply = match if method == "POST" { read_body(req.as_reader()) } else { Ok(Vec::new()) } {
        Ok(body) => app.handle(&method, &url, &body),
        Err(e) => Reply::error(&e),
    };
    let header = |k: &str, v: &str| tiny_http::Header::from_bytes(k.as_bytes(), v.as_bytes()).ok();
    let mut resp = tiny_http::Response::from_data(reply.body).with_status_code(reply.status);
    for h in [header("Content-Type", reply.content_type), header("Cache-Control", "no-store")].into_iter().flatten() {
        resp.add_header(h);
    }
    for (k, v) in &reply.headers {
        if let Some(h) = header(k, v) {
            resp.add_header(h);
        }
    }
    let _ = req.respond(resp); // the page may have gone (an aborted fetch): nothing to do
}

impl std::fmt::Debug for Viewer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Viewer").field("addr", &self.addr).finish_non_exhaustive()
    }
}

impl Viewer {
    /// Loads the run's newest checkpoint if there is one, starts listening and answering.
    pub fn start(cfg: ViewerConfig) -> Result<Self, ViewerError> {
        let addr = format!("{}:{}", cfg.host, cfg.port);
        let server = Arc::new(tiny_http::Server::http(&addr).map_err(|e| ViewerError::Bind { addr: addr.clone(), message: e.to_string() })?);
        let local = server.server_addr().to_ip().ok_or_else(|| ViewerError::Bind { addr, message: "not an IP address".into() })?;
        let nice = cfg.nice;
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(cfg.threads.max(1))
            .thread_name(|i| format!("viewer-render-{i}"))
            .start_handler(move |_| lower_priority(nice))
            .build()
            .map_err(|e| ViewerError::Internal(format!("cannot start the viewer's threads: {e}")))?;
        let app = Arc::new(App::new(cfg.run_dir.clone(), Some(pool)));
        app.watch.poll();
        let stop = Arc::new(AtomicBool::new(false));
        let (tx, rx) = std::sync::mpsc::channel::<tiny_http::Request>();
        let rx = Arc::new(std::sync::Mutex::new(rx));
        let mut spawned = Vec::new();
        for k in 0..HANDLERS {
            let (app, rx) = (app.clone(), rx.clone());
            spawned.push(std::thread::Builder::new().name(format!("viewer-http-{k}")).spawn(move || {
                lower_priority(nice);
                loop {
                    let next = rx.lock().unwrap_or_else(|p| p.into_inner()).recv();
                    match next {
                        Ok(req) => respond(&app, req),
                        Err(_) => break, // the acceptor stopped
                    }
                }
            }));
        }
        let acceptor = {
            let (server, app, stop) = (server.clone(), app.clone(), stop.clone());
            std::thread::Builder::new().name("viewer-accept".into()).spawn(move || {
                while !stop.load(Ordering::SeqCst) {
                    match server.recv_timeout(Duration::from_millis(100)) {
                        Ok(Some(req)) => {
                            app.note_arrival(req.url());
                            if tx.send(req).is_err() {
                                break;
                            }
                        }
                        Ok(None) => {}
                        Err(e) => tracing::debug!("viewer: {e}"),
                    }
                }
            })
        };
        let watcher = {
            let (app, stop, every) = (app.clone(), stop.clone(), cfg.poll);
            std::thread::Builder::new().name("viewer-watch".into()).spawn(move || {
                lower_priority(nice);
                while !stop.load(Ordering::SeqCst) {
                    std::thread::sleep(every);
                    if app.watch.poll() {
                        tracing::info!("viewer: loaded {}", app.watch.current().map(|l| l.key.path.display().to_string()).unwrap_or_default());
                    }
                }
            })
        };
        let threads = spawned
            .into_iter()
            .chain([acceptor, watcher])
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| ViewerError::Internal(format!("cannot start the viewer's threads: {e}")))?;
        Ok(Self { addr: local, app, stop, server, threads })
    }

    /// The address it listens on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The page's URL.
    pub fn url(&self) -> String {
        format!("http://{}/", self.addr)
    }

    /// The state behind the requests (for benchmarks and tests).
    pub fn app(&self) -> &Arc<App> {
        &self.app
    }

    /// Serves until `stop` is set, then stops.
    pub fn run_until(self, stop: &AtomicBool) {
        while !stop.load(Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Serves until the process ends.
    pub fn wait(mut self) {
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

impl Drop for Viewer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        self.server.unblock();
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}
