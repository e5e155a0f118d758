//! A local web viewer of a training run: one page (HTML, JavaScript and CSS embedded in the
//! binary, no CDN) served over HTTP on 127.0.0.1 by default, that orbits the run's radiance
//! field, shows colour, depth and opacity, puts a dataset view's exact ground truth and error
//! heat map beside the NeRF, draws the loss and validation PSNR curves as they grow, and exports
//! keyframes as nerfstudio's `camera_path.json`.
//!
//! The viewer only reads the run folder and its dataset; it reloads the newest checkpoint when
//! the trainer writes one (readers keep the previous model until the new one is loaded), and it
//! renders on a small pool of low-priority threads so that a trainer on the same machine keeps
//! its speed. The HTTP API, the page and the measured figures are in `docs/viewer.md`.
//!
//! ```no_run
//! let cfg = viewer::ViewerConfig::new("runs/tabletop-fast".into());
//! let v = viewer::Viewer::start(cfg).unwrap();
//! println!("open {}", v.url());
//! v.wait();
//! ```

pub mod assets;
pub mod error;
pub mod export;
pub mod imaging;
pub mod metrics;
pub mod query;
pub mod request;
pub mod routes;
pub mod server;
pub mod views;
pub mod watch;

pub use error::ViewerError;
pub use server::{Viewer, ViewerConfig};
