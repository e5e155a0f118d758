//! `cargo xtask crosscheck <scene> [--spp S] [--res WxH] [--views N] [--out dir]`: renders a
//! scene with our path tracer and with Mitsuba 3 and compares them.
//!
//! Steps: load the scene as `render` does, place `N` cameras with the dataset rig, export the
//! scene exactly as loaded (`pathtracer::export::export_scene` → `<out>/export/`), render the
//! views with our renderer as independent groups to estimate per-pixel noise
//! (`pathtracer::export::render_reference` → `<out>/ours/`), then run the Python harness
//! `tests/mitsuba/crosscheck.py` with the repository's `.venv`, which renders the same views
//! with Mitsuba, compares, writes `<out>/crosscheck.{md,json}` and images, and exits non-zero
//! on failure.

use crate::render::{parse_resolution, repo_root, resolve_scene};
use anyhow::{Context, bail};
use pathtracer::accel::AccelParams;
use pathtracer::dataset_render::DatasetRenderConfig;
use pathtracer::dataset_render::Preset;
use pathtracer::export::{export_scene, reference_groups, render_reference, write_reference};
use pathtracer::import::{ImportOptions, load_gltf};
use pathtracer::render::{RenderSettings, Renderer};
use pathtracer::rig::build_rig;
use std::path::PathBuf;

/// Arguments of `crosscheck`.
#[derive(clap::Args, Clone, Debug)]
pub struct CrosscheckArgs {
    /// A `.gltf` / `.glb` file, or the name of a scene in `scenes/` (e.g. `cornell`).
    pub scene: String,
    /// Samples per pixel, on both sides (at least 2: split into independent groups).
    #[arg(long, default_value_t = 64)]
    pub spp: u32,
    /// Resolution, `W` (square) or `WxH`.
    #[arg(long, default_value = "64")]
    pub res: String,
    /// Number of views (the first views of the dataset rig's train split).
    #[arg(long, default_value_t = 1)]
    pub views: u32,
    /// Report folder (default `out/crosscheck/<scene>`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Maximum number of bounces (ours; Mitsuba's max_depth is one more).
    #[arg(long, default_value_t = 4)]
    pub max_bounces: u32,
    /// Constant environment radiance, linear R,G,B (shown by camera misses and lighting the
    /// scene); default 0.1,0.1,0.1, or 1,1,1 as the scale of --environment-map.
    #[arg(long)]
    pub environment: Option<String>,
    /// Equirectangular environment map (.exr or .hdr) lighting the scene on both sides
    /// (Mitsuba: `envmap`).
    #[arg(long, value_name = "FILE")]
    pub environment_map: Option<PathBuf>,
    /// Seed of our renderer (group g uses seed + g).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Most independent groups the spp are split into (the largest divisor of spp up to this).
    #[arg(long, default_value_t = 64)]
    pub max_groups: u32,
    /// Drop the scene's punctual lights (point, spot, directional) on both sides, e.g. to check
    /// an environment map alone.
    #[arg(long)]
    pub no_punctual_lights: bool,
    /// Mitsuba variant (scalar_rgb needs nothing else; llvm_ad_rgb needs a working libLLVM).
    #[arg(long, default_value = "scalar_rgb")]
    pub variant: String,
    /// Read glTF buffers and images that lie outside the scene file's folder (an absolute URI,
    /// `../`, a symbolic link leading out); refused by default.
    #[arg(long)]
    pub allow_outside: bool,
}

/// Runs the cross-check; fails when the harness reports a failed criterion.
pub fn run(args: CrosscheckArgs) -> anyhow::Result<()> {
    if args.max_groups < 2 {
        bail!("--max-groups {}: at least 2 groups are needed (the noise is estimated from independent groups)", args.max_groups);
    }
    // The harness compares RGB images: Mitsuba's RGB variants, on the CPU or a CUDA GPU. Checked
    // here, before anything is written (an unknown variant used to fail only in the harness,
    // after the export).
    const VARIANTS: [&str; 5] = ["scalar_rgb", "llvm_rgb", "llvm_ad_rgb", "cuda_rgb", "cuda_ad_rgb"];
    if !VARIANTS.contains(&args.variant.as_str()) {
        bail!("--variant {}: the cross-check needs one of Mitsuba's RGB variants: {}", args.variant, VARIANTS.join(", "));
    }
    if let Some(out) = &args.out {
        crate::check_out_folder("--out", out)?;
        crate::guard::check_output_folder("--out", out, false)?;
    }
    let root = repo_root();
    let python = root.join(".venv/bin/python");
    if !python.is_file() {
        bail!(
            "{} not found: the Mitsuba cross-check needs a Python virtual environment; create it with\n  \
             python3 -m venv .venv && .venv/bin/pip install -r tests/mitsuba/requirements.txt\n(in {})",
            python.display(),
            root.display()
        );
    }
    let harness = root.join("tests/mitsuba/crosscheck.py");
    if args.spp < 2 {
        bail!("--spp {}: at least 2 samples per pixel are needed (the noise is estimated from independent groups)", args.spp);
    }
    if args.views == 0 {
        bail!("--views 0: at least one view is needed");
    }
    let scene_path = resolve_scene(&args.scene)?;
    let name = scene_path.file_stem().and_then(|s| s.to_str()).unwrap_or("scene").to_string();
    let out = args.out.clone().unwrap_or_else(|| root.join("out/crosscheck").join(&name));
    crate::guard::check_output_folder("--out", &out, false)?;

    let mut cfg = DatasetRenderConfig::preset(Preset::Quick);
    (cfg.width, cfg.height) = parse_resolution(&args.res)?;
    cfg.train = args.views;
    cfg.spp = args.spp;
    cfg.max_bounces = args.max_bounces;
    cfg.seed = args.seed;
    let default_env = if args.environment_map.is_some() { "1,1,1" } else { "0.1,0.1,0.1" };
    let env = args.environment.as_deref().unwrap_or(default_env);
    cfg.environment = pathtracer::dataset_render::parse_rgb(env).map_err(|m| anyhow::anyhow!("--environment {env}: {m}"))?;
    if let Some(map) = &args.environment_map {
        pathtracer::render::check_environment_map_path(map).with_context(|| format!("--environment-map {}", map.display()))?;
    }
    cfg.validate()?;

    let mut scene = load_gltf(&scene_path, &ImportOptions { allow_outside: args.allow_outside, ..ImportOptions::default() }).with_context(|| format!("loading {}", scene_path.display()))?;
    if args.no_punctual_lights {
        scene.lights.clear();
    }
    let rig = build_rig(&scene, &cfg.rig_config())?;
    let cameras: Vec<_> = rig.split(dataset::SplitKind::Train).to_vec();
    let settings = RenderSettings {
        spp: cfg.spp,
        max_bounces: cfg.max_bounces,
        seed: cfg.seed,
        environment: cfg.environment,
        transparent_background: false,
        environment_map: args.environment_map.clone(),
    };
    settings.validate()?;
    let groups = reference_groups(settings.spp, args.max_groups);
    if groups < 2 {
        bail!("--spp {} is prime above --max-groups {}: choose an spp with a divisor between 2 and {}", args.spp, args.max_groups, args.max_groups);
    }

    let export_dir = out.join("export");
    let ours_dir = out.join("ours");
    export_scene(&scene, &cameras, &settings, &export_dir).with_context(|| format!("exporting to {}", export_dir.display()))?;
    println!("exported {} ({} triangles, {} views, rig {}) to {}", name, scene.mesh.indices.len(), cameras.len(), rig.kind.name(), export_dir.display());

    let mut renderer = Renderer::new(scene, &AccelParams::medium_build())?;
    renderer.load_environment_map(&settings)?;
    let start = std::time::Instant::now();
    for (k, cam) in cameras.iter().enumerate() {
        let v = render_reference(&renderer, cam, k as u32, &settings, groups)?;
        if v.nonfinite_samples > 0 {
            tracing::warn!("view {k}: {} non-finite radiance samples replaced by zero", v.nonfinite_samples);
        }
        write_reference(&ours_dir, &format!("view_{k}"), &v)?;
    }
    println!(
        "ours: {} view(s) at {}x{}, {} spp in {groups} groups, {:.1} s",
        cameras.len(),
        cfg.width,
        cfg.height,
        settings.spp,
        start.elapsed().as_secs_f64()
    );

    let status = std::process::Command::new(&python)
        .arg(&harness)
        .arg("--export")
        .arg(&export_dir)
        .arg("--ours")
        .arg(&ours_dir)
        .arg("--out")
        .arg(&out)
        .arg("--groups")
        .arg(groups.to_string())
        .arg("--variant")
        .arg(&args.variant)
        .status()
        .with_context(|| format!("running {} {}", python.display(), harness.display()))?;
    match status.code() {
        Some(0) => {
            println!("cross-check passed: {}", out.join("crosscheck.md").display());
            Ok(())
        }
        Some(1) => bail!("cross-check FAILED: see {}", out.join("crosscheck.md").display()),
        Some(2) => bail!("the scene uses a feature the Mitsuba cross-check cannot reproduce (message above)"),
        _ => bail!("the Mitsuba harness failed ({status})"),
    }
}
