//! `cargo xtask camera-path DATASET --orbit | --spiral | --through-views 0,5,9 --out path.json`:
//! writes a camera path in nerfstudio's `camera_path.json` format (`dataset::CameraPathFile`)
//! around or through a dataset, for `render --camera-path` and `render-nerf --camera-path`.

use anyhow::Context;
use std::path::PathBuf;

/// Arguments of `camera-path`.
#[derive(clap::Args, Clone, Debug)]
#[command(group(clap::ArgGroup::new("shape").required(true).args(["orbit", "spiral", "through_views"])))]
pub struct CameraPathArgs {
    /// The dataset folder (its train cameras and scene facts place the path).
    pub dataset: PathBuf,
    /// A circle around the scene centre (radius and elevation: the train cameras' mean).
    #[arg(long)]
    pub orbit: bool,
    /// A spiral: the orbit turned --turns times while the elevation sweeps ±--swing degrees.
    #[arg(long)]
    pub spiral: bool,
    /// A smooth path through these train views (indices, comma separated): each one's frame is
    /// its pose exactly.
    #[arg(long, value_delimiter = ',', value_name = "I,J,...")]
    pub through_views: Option<Vec<usize>>,
    /// Number of frames of an orbit or spiral (default 120); for --through-views, the frames
    /// from one view to the next (default 30).
    #[arg(long)]
    pub frames: Option<u32>,
    /// Frames per second of the video.
    #[arg(long, default_value_t = 30.0)]
    pub fps: f64,
    /// Distance from the scene centre, metres (default: the train cameras' mean).
    #[arg(long)]
    pub radius: Option<f64>,
    /// Elevation above the scene centre, degrees (default: the train cameras' mean).
    #[arg(long)]
    pub elevation: Option<f64>,
    /// Turns of a spiral.
    #[arg(long, default_value_t = 2.0)]
    pub turns: f64,
    /// Half the elevation sweep of a spiral, degrees.
    #[arg(long, default_value_t = 15.0)]
    pub swing: f64,
    /// Image width of the path's frames, pixels (default the dataset's; the height keeps the aspect).
    #[arg(long)]
    pub width: Option<u32>,
    /// Close a --through-views path back to its first view.
    #[arg(long)]
    pub cycle: bool,
    /// The camera path file to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Read dataset files that lie outside the dataset folder; refused by default.
    #[arg(long)]
    pub allow_outside: bool,
}

/// Writes the camera path.
pub fn run(args: CameraPathArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.fps.is_finite() && args.fps > 0.0 && args.fps <= 1000.0, "--fps {}: must be above 0 and at most 1000", args.fps);
    anyhow::ensure!(args.frames != Some(0), "--frames 0: at least one frame is needed");
    anyhow::ensure!(args.frames.is_none_or(|f| f <= 100_000), "--frames {}: at most 100000", args.frames.unwrap_or(0));
    anyhow::ensure!(args.turns.is_finite() && args.turns.abs() <= 1000.0, "--turns {}: must be finite, at most 1000", args.turns);
    anyhow::ensure!(args.swing.is_finite() && args.swing.abs() < 90.0, "--swing {}: must lie within ±90 degrees", args.swing);
    if let Some(w) = args.width {
        anyhow::ensure!((1..=dataset::MAX_PATH_SIZE).contains(&w), "--width {w}: must be 1 to {}", dataset::MAX_PATH_SIZE);
    }
    crate::guard::check_output_files("--out", &args.out, std::slice::from_ref(&args.out), &[])?;
    let load = dataset::LoadOptions { allow_outside: args.allow_outside };
    let ds = dataset::Dataset::load_with(&args.dataset, &load).with_context(|| format!("loading {}", args.dataset.display()))?;
    let mut template = ds.train.first().context("the dataset has no train views")?.camera;
    if let Some(w) = args.width {
        template = template.at_width(w);
    }
    let (frames, keys) = match &args.through_views {
        Some(views) => {
            let (frames, keys) = dataset::through_views(&ds, views, args.frames.unwrap_or(30), args.cycle).map_err(|e| anyhow::anyhow!("--through-views: {e}"))?;
            let resize = |c: dataset::Camera| if args.width.is_some() { dataset::Camera { intrinsics: template.intrinsics, ..c } } else { c };
            (frames.into_iter().map(resize).collect::<Vec<_>>(), keys.into_iter().map(resize).collect::<Vec<_>>())
        }
        None => {
            let d = dataset::OrbitDefaults::of(&ds);
            let spiral = args.spiral;
            let orbit = dataset::Orbit {
                centre: d.centre,
                radius: args.radius.unwrap_or(d.radius),
                elevation: args.elevation.unwrap_or(d.elevation),
                frames: args.frames.unwrap_or(120),
                turns: if spiral { args.turns } else { 1.0 },
                swing: if spiral { args.swing } else { 0.0 },
            };
            if let Some(e) = args.elevation {
                anyhow::ensure!(e.is_finite() && e.abs() < 90.0, "--elevation {e}: must lie within ±90 degrees");
            }
            let cams = dataset::orbit_cameras(&orbit, &template).map_err(|e| anyhow::anyhow!("{}: {e}", if spiral { "--spiral" } else { "--orbit" }))?;
            (cams, Vec::new())
        }
    };
    let file = dataset::CameraPathFile { is_cycle: args.through_views.is_none() || args.cycle, ..dataset::CameraPathFile::from_cameras(&frames, &keys, args.fps) };
    file.cameras(&args.out)?;
    file.write(&args.out)?;
    println!("camera path: {}", args.out.display());
    println!(
        "{} frames at {}x{}, {:.2} s at {} fps",
        frames.len(),
        file.render_width,
        file.render_height,
        file.seconds,
        args.fps
    );
    Ok(())
}
