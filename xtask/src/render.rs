//! `cargo xtask render <scene.gltf | scene name> --out <dir> [options]`: renders a glTF scene
//! into a posed train/val/test dataset with exact ground truth (see
//! `pathtracer::dataset_render`). This file parses the options, shows progress and prints the
//! result; the work is done by the library.

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use pathtracer::dataset_render::{
    Background, DatasetRenderConfig, Preset, ProgressEvent, RunOptions, parse_rgb, render_dataset,
};
use pathtracer::rig::RigKind;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

/// Arguments of `render`. Explicit options override the preset's values.
#[derive(clap::Args, Clone, Debug)]
pub struct RenderArgs {
    /// A `.gltf` / `.glb` file, or the name of a scene in `scenes/` (e.g. `tabletop`).
    pub scene: String,
    /// The dataset folder to write (created; an unfinished one with the same settings is resumed).
    #[arg(long)]
    pub out: PathBuf,
    /// Starting settings: quick (64x64, 20/4/4 views, 16 spp), standard (200x200, 100/10/20, 128 spp)
    /// or full (800x800, the Blender-synthetic size, 100/10/20, 128 spp).
    #[arg(long, default_value = "quick")]
    pub preset: Preset,
    /// Number of train views.
    #[arg(long)]
    pub train: Option<u32>,
    /// Number of val views.
    #[arg(long)]
    pub val: Option<u32>,
    /// Number of test views.
    #[arg(long)]
    pub test: Option<u32>,
    /// Resolution, `W` (square) or `WxH`.
    #[arg(long)]
    pub res: Option<String>,
    /// Samples per pixel.
    #[arg(long)]
    pub spp: Option<u32>,
    /// Seed of the camera jitter and path sampling.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Maximum number of bounces per path.
    #[arg(long)]
    pub max_bounces: Option<u32>,
    /// Camera rig: auto (glTF cameras if any, else hemisphere over a ground, else sphere), sphere, hemisphere, gltf.
    #[arg(long)]
    pub rig: Option<RigKind>,
    /// Horizontal field of view of the sphere rigs, radians (default 0.6911, as the Blender scenes).
    #[arg(long)]
    pub fov_x: Option<f64>,
    /// What missed rays show: transparent, environment, or a linear colour R,G,B.
    #[arg(long)]
    pub background: Option<Background>,
    /// Constant environment radiance lighting the scene, linear R,G,B; with --environment-map,
    /// the map's scale (default 1,1,1 then).
    #[arg(long)]
    pub environment: Option<String>,
    /// Equirectangular environment map lighting the scene (OpenEXR .exr or Radiance .hdr,
    /// linear; image top = +Y, image centre = -Z). Part of the dataset's identity on resume.
    #[arg(long, value_name = "FILE")]
    pub environment_map: Option<PathBuf>,
    /// Worker threads (default: all cores). Does not change the output.
    #[arg(long)]
    pub threads: Option<usize>,
    /// Replace a dataset in --out that was rendered with different settings.
    #[arg(long)]
    pub force: bool,
    /// Render only shard K of N (zero-based, e.g. 0/4) of the views, for `merge` to combine:
    /// every split's numbering stays the unsharded render's.
    #[arg(long, value_name = "K/N")]
    pub shard: Option<pathtracer::shard::Shard>,
    /// Read glTF buffers and images that lie outside the scene file's folder (an absolute URI,
    /// `../`, a symbolic link leading out); refused by default.
    #[arg(long)]
    pub allow_outside: bool,
    /// Render the frames of this camera path (nerfstudio's camera_path.json, from
    /// `cargo xtask camera-path`) as the dataset's train views, at the path's size and field of
    /// view, instead of a rig's views: the exact ground truth along the path.
    #[arg(long, value_name = "FILE")]
    pub camera_path: Option<PathBuf>,
}

/// Arguments of `merge`.
#[derive(clap::Args, Clone, Debug)]
pub struct MergeArgs {
    /// The shard folders (from `render --shard K/N`), every shard exactly once.
    #[arg(required = true)]
    pub shards: Vec<PathBuf>,
    /// The dataset folder to write (must not exist or be empty).
    #[arg(long)]
    pub out: PathBuf,
    /// The scene file the shards were rendered from, or the name of a scene in `scenes/`
    /// (default: the path they recorded).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Read glTF buffers and images that lie outside the scene file's folder (an absolute URI,
    /// `../`, a symbolic link leading out); refused by default.
    #[arg(long)]
    pub allow_outside: bool,
}

/// Merges shard folders into one dataset folder.
pub fn run_merge(args: MergeArgs) -> anyhow::Result<()> {
    crate::check_out_folder("--out", &args.out)?;
    crate::guard::check_output_folder("--out", &args.out, false)?;
    let _lock = crate::lock_folder(&args.out)?;
    let scene = resolve_scene_option(args.scene.as_deref())?;
    let import = pathtracer::import::ImportOptions { allow_outside: args.allow_outside, ..Default::default() };
    let sum = pathtracer::shard::merge_shards_with(&args.shards, &args.out, scene.as_deref(), &import)
        .with_context(|| format!("merging {} shards into {}", args.shards.len(), args.out.display()))?;
    println!("dataset: {}", sum.out.display());
    println!("{} views merged from {} shards; near {:.3}, far {:.3}", sum.views_total, args.shards.len(), sum.facts.near, sum.facts.far);
    Ok(())
}

impl RenderArgs {
    /// The arguments `cargo xtask demo` renders with: `scene` at `preset`, every other option
    /// at the preset's value.
    pub fn for_demo(scene: &str, out: &Path, preset: Preset) -> Self {
        Self {
            scene: scene.to_string(),
            out: out.to_path_buf(),
            preset,
            train: None,
            val: None,
            test: None,
            res: None,
            spp: None,
            seed: None,
            max_bounces: None,
            rig: None,
            fov_x: None,
            background: None,
            environment: None,
            environment_map: None,
            threads: None,
            force: false,
            shard: None,
            allow_outside: false,
            camera_path: None,
        }
    }
}

/// The repository root: the source tree this xtask was built from (the parent of `xtask/`)
/// while it still has `scenes/`; otherwise (a binary kept after its build tree was removed,
/// e.g. an older build for a before/after comparison) the nearest ancestor of the current
/// directory that has both `scenes/` and `xtask/`; else the build tree's path, so errors
/// name where scenes were expected.
pub fn repo_root() -> PathBuf {
    let built = Path::new(env!("CARGO_MANIFEST_DIR")).parent().map(Path::to_path_buf).unwrap_or_else(|| PathBuf::from("."));
    root_from(built, std::env::current_dir().ok().as_deref())
}

/// [`repo_root`] for a given build tree and current directory.
fn root_from(built: PathBuf, cwd: Option<&Path>) -> PathBuf {
    if built.join("scenes").is_dir() {
        return built;
    }
    cwd.and_then(|cwd| cwd.ancestors().find(|d| d.join("scenes").is_dir() && d.join("xtask").is_dir()).map(Path::to_path_buf)).unwrap_or(built)
}

/// Resolves the scene argument: an existing file, or a name `NAME` meaning
/// `<repo>/scenes/NAME.gltf` (or `.glb`).
pub fn resolve_scene(scene: &str) -> anyhow::Result<PathBuf> {
    let p = Path::new(scene);
    if p.is_file() {
        return Ok(p.to_path_buf());
    }
    let is_name = p.extension().is_none() && p.components().count() == 1;
    if is_name {
        let dir = repo_root().join("scenes");
        for ext in ["gltf", "glb"] {
            let f = dir.join(format!("{scene}.{ext}"));
            if f.is_file() {
                return Ok(f);
            }
        }
        let mut known: Vec<String> = std::fs::read_dir(&dir)
            .map(|d| {
                d.flatten()
                    .filter_map(|e| {
                        let path = e.path();
                        let ext = path.extension()?.to_str()?;
                        (ext == "gltf" || ext == "glb").then(|| path.file_stem()?.to_str().map(str::to_string))?
                    })
                    .collect()
            })
            .unwrap_or_default();
        known.sort();
        bail!(
            "scene '{scene}' is neither a file nor a scene in {} (known: {}; `cargo xtask gen-scenes` writes them)",
            dir.display(),
            if known.is_empty() { "none".to_string() } else { known.join(", ") }
        );
    }
    if p.is_dir() {
        bail!("scene {} is a folder, not a glTF file (.gltf or .glb)", p.display());
    }
    bail!("scene file {} does not exist", p.display())
}

/// [`resolve_scene`] for an optional `--scene` path option: a file, or the name of a scene in
/// `scenes/`, as `render` takes it.
pub fn resolve_scene_option(scene: Option<&Path>) -> anyhow::Result<Option<PathBuf>> {
    scene.map(|s| resolve_scene(&s.to_string_lossy())).transpose()
}

/// Parses `W` or `WxH`.
pub fn parse_resolution(s: &str) -> anyhow::Result<(u32, u32)> {
    let parse = |v: &str| v.trim().parse::<u32>().with_context(|| format!("--res {s}: '{v}' is not a whole number"));
    match s.split_once(['x', 'X']) {
        Some((w, h)) => Ok((parse(w)?, parse(h)?)),
        None => {
            let w = parse(s)?;
            Ok((w, w))
        }
    }
}

/// The render settings: the preset's, overridden by every option given. Checks them.
pub fn build_config(args: &RenderArgs) -> anyhow::Result<DatasetRenderConfig> {
    let mut cfg = DatasetRenderConfig::preset(args.preset);
    if let Some(res) = &args.res {
        (cfg.width, cfg.height) = parse_resolution(res)?;
    }
    cfg.train = args.train.unwrap_or(cfg.train);
    cfg.val = args.val.unwrap_or(cfg.val);
    cfg.test = args.test.unwrap_or(cfg.test);
    cfg.spp = args.spp.unwrap_or(cfg.spp);
    cfg.seed = args.seed.unwrap_or(cfg.seed);
    cfg.max_bounces = args.max_bounces.unwrap_or(cfg.max_bounces);
    cfg.rig = args.rig.unwrap_or(cfg.rig);
    cfg.fov_x = args.fov_x.unwrap_or(cfg.fov_x);
    cfg.background = args.background.unwrap_or(cfg.background);
    cfg.environment_map = args.environment_map.clone();
    match &args.environment {
        Some(env) => cfg.environment = parse_rgb(env).map_err(|m| anyhow::anyhow!("--environment {env}: {m}"))?,
        None if cfg.environment_map.is_some() => cfg.environment = [1.0; 3],
        None => {}
    }
    if let Some(map) = &cfg.environment_map {
        pathtracer::render::check_environment_map_path(map).with_context(|| format!("--environment-map {}", map.display()))?;
    }
    if let Some(path) = &args.camera_path {
        let given = [("--res", args.res.is_some()), ("--train", args.train.is_some()), ("--val", args.val.is_some()), ("--test", args.test.is_some()), ("--rig", args.rig.is_some()), ("--fov-x", args.fov_x.is_some())];
        if let Some((option, _)) = given.iter().find(|(_, g)| *g) {
            bail!("{option} with --camera-path: the path's file sets the views, their size and field of view");
        }
        let cams = dataset::CameraPathFile::read(path)?.cameras(path)?;
        (cfg.width, cfg.height) = (cams[0].intrinsics.width, cams[0].intrinsics.height);
        anyhow::ensure!(cams.len() < 1 << 24, "--camera-path {}: {} frames, at most 16777215", path.display(), cams.len());
        (cfg.train, cfg.val, cfg.test) = (cams.len() as u32, 0, 0);
        cfg.camera_path = Some(path.clone());
    }
    cfg.validate()?;
    Ok(cfg)
}

/// The process-wide stop flag (Ctrl-C, SIGTERM, SIGHUP): see [`crate::stop_flag`].
pub fn cancel_flag() -> &'static AtomicBool {
    crate::stop_flag()
}

/// The renderer named in the dataset folder `dir`'s render record when it is not this one
/// (`None` without a readable record, or when it is this renderer's).
pub fn older_renderer(dir: &Path) -> Option<String> {
    let bytes = std::fs::read(dir.join(pathtracer::dataset_render::RENDER_CONFIG_FILE)).ok()?;
    let renderer = serde_json::from_slice::<serde_json::Value>(&bytes).ok()?["renderer"].as_str()?.to_string();
    (renderer != pathtracer::version::renderer_version()).then_some(renderer)
}

/// Renders a dataset; returns its folder.
pub fn run(args: RenderArgs) -> anyhow::Result<PathBuf> {
    crate::check_out_folder("--out", &args.out)?;
    crate::guard::check_output_folder("--out", &args.out, true)?;
    let _lock = crate::lock_folder(&args.out)?;
    let cfg = build_config(&args)?;
    let scene = resolve_scene(&args.scene)?;
    let opts = RunOptions { threads: args.threads, force: args.force, allow_outside: args.allow_outside };
    let cancel = cancel_flag();

    let bar = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr());
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} views  {msg}  ETA {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    bar.set_message(format!("loading {}", scene.display()));
    let start = std::time::Instant::now();
    let mut samples = 0u64;
    let mut done_here = 0u64;
    let mut progress = |e: ProgressEvent| match e {
        ProgressEvent::Started { total, reused, rig } => {
            bar.set_length(total);
            bar.set_position(reused);
            bar.reset_eta();
            bar.set_message(format!("rig {}{}", rig.name(), if reused > 0 { format!(", {reused} kept") } else { String::new() }));
        }
        ProgressEvent::ViewRendered { samples: s, .. } => {
            samples += s;
            done_here += 1;
            let rate = samples as f64 / start.elapsed().as_secs_f64().max(1e-9);
            bar.set_message(format!("{:.2} Msamples/s", rate * 1e-6));
            bar.inc(1);
        }
    };
    let result = match args.shard {
        Some(shard) => pathtracer::shard::render_shard(&scene, &args.out, &cfg, &opts, shard, &mut progress, cancel),
        None => render_dataset(&scene, &args.out, &cfg, &opts, &mut progress, cancel),
    };
    bar.finish_and_clear();
    match result {
        Ok(sum) if args.shard.is_some() => {
            println!("shard: {}", sum.out.display());
            println!(
                "shard {} ({} views: {} rendered, {} kept) in {:.1} s; combine every shard with `cargo xtask merge`",
                args.shard.map_or(String::new(), |s| s.to_string()),
                sum.views_total,
                sum.views_rendered,
                sum.views_reused,
                sum.seconds
            );
            Ok(sum.out)
        }
        Ok(sum) => {
            let rate = sum.samples as f64 / sum.seconds.max(1e-9);
            println!("dataset: {}", sum.out.display());
            println!(
                "{} views ({} rendered, {} kept; {}x{}, {} spp, rig {}) in {:.1} s, {:.2} Msamples/s; near {:.3}, far {:.3}",
                sum.views_total,
                sum.views_rendered,
                sum.views_reused,
                cfg.width,
                cfg.height,
                cfg.spp,
                sum.rig.name(),
                sum.seconds,
                rate * 1e-6,
                sum.facts.near,
                sum.facts.far,
            );
            Ok(sum.out)
        }
        Err(pathtracer::PathTracerError::Interrupted) => Err(crate::exit::Stopped(format!(
            "interrupted after {done_here} new views; finished views are kept in {} — re-run the same command to resume",
            args.out.display()
        ))
        .into()),
        Err(e) => Err(e).with_context(|| format!("rendering {} into {}", scene.display(), args.out.display())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        args: RenderArgs,
    }

    fn parse(cmd: &[&str]) -> RenderArgs {
        Cli::try_parse_from(std::iter::once("render").chain(cmd.iter().copied())).unwrap().args
    }

    #[test]
    fn repo_root_falls_back_to_the_checkout_around_the_current_directory() {
        let tmp = tempfile::tempdir().unwrap();
        let (built, checkout) = (tmp.path().join("build-tree"), tmp.path().join("checkout"));
        for d in [checkout.join("scenes"), checkout.join("xtask"), checkout.join("out/bench"), built.join("xtask")] {
            std::fs::create_dir_all(d).unwrap();
        }
        let inside = checkout.join("out/bench");
        // The build tree has no scenes (removed): the checkout around the current directory.
        assert_eq!(root_from(built.clone(), Some(&inside)), checkout);
        assert_eq!(root_from(built.clone(), Some(&checkout)), checkout);
        // Nothing around the current directory either: the build tree, named in errors.
        assert_eq!(root_from(built.clone(), Some(tmp.path())), built);
        assert_eq!(root_from(built.clone(), None), built);
        // A build tree that still has its scenes wins wherever the command runs.
        std::fs::create_dir_all(built.join("scenes")).unwrap();
        assert_eq!(root_from(built.clone(), Some(&inside)), built);
        // The real one has the committed scenes.
        assert!(repo_root().join("scenes/tabletop.gltf").is_file());
    }

    #[test]
    fn options_override_the_preset() {
        let a = parse(&["x.gltf", "--out", "o", "--preset", "standard", "--res", "32x16", "--spp", "3", "--rig", "sphere", "--background", "1,1,1"]);
        let c = build_config(&a).unwrap();
        assert_eq!((c.width, c.height, c.spp, c.train, c.val, c.test), (32, 16, 3, 100, 10, 20));
        assert_eq!(c.rig, RigKind::Sphere);
        assert_eq!(c.background, Background::Color([1.0; 3]));
        assert_eq!(build_config(&parse(&["x", "--out", "o", "--res", "48"])).unwrap().height, 48);
        for bad in [["--res", "0"], ["--spp", "0"], ["--train", "0"], ["--res", "4y4"], ["--environment", "1,2"]] {
            let mut cmd = vec!["x", "--out", "o"];
            cmd.extend(bad);
            assert!(build_config(&parse(&cmd)).is_err(), "{bad:?} accepted");
        }
        assert!(Cli::try_parse_from(["render", "x", "--out", "o", "--rig", "cube"]).is_err());
    }

    #[test]
    fn environment_map_option_is_checked_and_defaults_the_scale_to_one() {
        let dir = std::env::temp_dir().join(format!("xtask_envmap_option_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let missing = dir.join("missing.hdr");
        let e = format!("{:#}", build_config(&parse(&["x", "--out", "o", "--environment-map", missing.to_str().unwrap()])).unwrap_err());
        assert!(e.contains("--environment-map") && e.contains("missing.hdr") && e.contains("does not exist"), "{e}");
        let txt = dir.join("sky.txt");
        std::fs::write(&txt, "not a map").unwrap();
        let e = format!("{:#}", build_config(&parse(&["x", "--out", "o", "--environment-map", txt.to_str().unwrap()])).unwrap_err());
        assert!(e.contains("sky.txt") && e.contains(".hdr"), "{e}");
        let sky = dir.join("sky.hdr");
        std::fs::write(&sky, b"#?RADIANCE\n").unwrap();
        let c = build_config(&parse(&["x", "--out", "o", "--environment-map", sky.to_str().unwrap()])).unwrap();
        assert_eq!((c.environment, c.environment_map.as_deref()), ([1.0; 3], Some(sky.as_path())));
        let c = build_config(&parse(&["x", "--out", "o", "--environment-map", sky.to_str().unwrap(), "--environment", "2,2,2"])).unwrap();
        assert_eq!(c.environment, [2.0; 3]);
        assert_eq!(build_config(&parse(&["x", "--out", "o"])).unwrap().environment_map, None);
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn unknown_scene_names_list_the_known_ones() {
        let e = resolve_scene("no_such_scene_name").unwrap_err().to_string();
        assert!(e.contains("no_such_scene_name") && e.contains("known"), "{e}");
        assert!(resolve_scene("missing/file.gltf").unwrap_err().to_string().contains("does not exist"));
    }
}
