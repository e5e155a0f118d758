//! `cargo xtask bench render|nerf`: performance figures, printed.

/// Arguments of `bench`.
#[derive(clap::Args)]
pub struct BenchArgs {
    /// What to measure.
    #[arg(value_enum)]
    pub what: BenchWhat,
    /// Options of `bench auto`.
    #[command(flatten)]
    pub auto: crate::bench_auto::AutoBenchArgs,
}

/// Benchmarks.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum BenchWhat {
    /// Path tracer: BVH build, primary rays, path samples per scene.
    Render,
    /// NeRF training throughput for both models.
    Nerf,
    /// `--model auto` against fixed fast sizes and paper on every scene (train, eval, compare).
    Auto,
}

/// Runs a benchmark.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    match args.what {
        BenchWhat::Render => bench_render(),
        BenchWhat::Nerf => crate::bench_nerf::run(),
        BenchWhat::Auto => crate::bench_auto::run(args.auto),
    }
}

/// Repetitions per figure; the median is reported.
const RENDER_RUNS: usize = 5;

/// Median of a non-empty list.
fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        0.0
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// `cargo xtask bench render`: per scene in `scenes/`, the BVH build time (obvhs medium
/// preset), primary-ray throughput (pixel-centre closest hits, 256×256 from the quick rig's
/// first train camera) and path-tracing throughput at the quick preset (64×64, 16 spp, 4
/// bounces) and at the standard preset's 128 spp and 8 bounces at 32×32; medians over
/// [`RENDER_RUNS`] runs, all cores. Then the same quick renders with Mitsuba 3
/// (`tests/mitsuba/bench.py`, from an export of each scene with that camera and settings;
/// `llvm_ad_rgb` where LLVM works, else `scalar_rgb`) and our samples/s divided by Mitsuba's,
/// for each scene twice: as authored (Mitsuba runs our glTF BRDF as its Python BSDF plugin) and
/// with every material made exactly Lambertian (ours `Diffuse`, Mitsuba's native `diffuse`);
/// without the Python environment a note says how to create it.
fn bench_render() -> anyhow::Result<()> {
    use anyhow::Context;
    use pathtracer::accel::{Accel, AccelParams};
    use pathtracer::dataset_render::{DatasetRenderConfig, Preset};
    use pathtracer::render::{RenderSettings, Renderer};

    let dir = crate::render::repo_root().join("scenes");
    let mut scenes: Vec<std::path::PathBuf> = std::fs::read_dir(&dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "gltf" || e == "glb"))
        .collect();
    scenes.sort();
    if scenes.is_empty() {
        anyhow::bail!("no scenes in {} (`cargo xtask gen-scenes` writes them)", dir.display());
    }
    println!(
        "bench render: medians of {RENDER_RUNS} runs, {} threads; BVH = obvhs medium_build; primary = 256x256 \
         pixel-centre closest hits; quick = 64x64 16 spp 4 bounces; std-spp = 32x32 128 spp 8 bounces",
        std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
    );
    println!(
        "{:<12} {:>9} {:>10} {:>9} {:>15} {:>16} {:>18}",
        "scene", "triangles", "rig", "BVH ms", "primary Mray/s", "quick Msample/s", "std-spp Msample/s"
    );
    let export_root = crate::render::repo_root().join("out/bench/mitsuba");
    let mut ours_quick: Vec<OursQuick> = Vec::new();
    for path in scenes {
        let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let scene = pathtracer::import::load_gltf(&path, &pathtracer::import::ImportOptions::default())?;
        let scene_for_export = scene.clone();
        let params = AccelParams::medium_build();
        let build_ms = median(
            (0..RENDER_RUNS)
                .map(|_| Accel::build(&scene, &params).map(|a| a.build_time().as_secs_f64() * 1e3))
                .collect::<Result<Vec<_>, _>>()?,
        );
        let triangles = scene.mesh.indices.len();
        let renderer = Renderer::new(scene, &params)?;
        let quick = DatasetRenderConfig::preset(Preset::Quick);
        let rig = pathtracer::rig::build_rig(renderer.scene(), &quick.rig_config())?;
        let cameras = rig.split(dataset::SplitKind::Train);
        let cam = cameras[0];
        let scale = 256.0 / cam.intrinsics.width as f64;
        let big = dataset::Camera {
            intrinsics: dataset::Intrinsics {
                width: 256,
                height: (cam.intrinsics.height as f64 * scale).round() as u32,
                fl_x: cam.intrinsics.fl_x * scale,
                fl_y: cam.intrinsics.fl_y * scale,
                cx: cam.intrinsics.cx * scale,
                cy: cam.intrinsics.cy * scale,
            },
            c2w: cam.c2w,
        };
        let primary = median((0..RENDER_RUNS).map(|_| renderer.primary_ray_throughput(&big).rays_per_second).collect());
        let path_rate_of = |renderer: &Renderer, settings: &RenderSettings, camera: &dataset::Camera| {
            median(
                (0..RENDER_RUNS)
                    .map(|k| {
                        let t = std::time::Instant::now();
                        let out = renderer.render_view(camera, k as u32, settings);
                        out.samples as f64 / t.elapsed().as_secs_f64().max(1e-9)
                    })
                    .collect(),
            )
        };
        let path_rate = |settings: &RenderSettings, camera: &dataset::Camera| path_rate_of(&renderer, settings, camera);
        let quick_settings = RenderSettings {
            spp: quick.spp,
            max_bounces: quick.max_bounces,
            seed: 0,
            environment: quick.environment,
            transparent_background: true,
            environment_map: None,
        };
        let standard = DatasetRenderConfig::preset(Preset::Standard);
        let std_settings = RenderSettings { spp: standard.spp, max_bounces: standard.max_bounces, ..quick_settings.clone() };
        let quick_rate = path_rate(&quick_settings, &cam);
        // The same scene with every material exactly Lambertian (metallic 0, specular 0), for a
        // comparison with Mitsuba's native `diffuse`.
        let mut lambert_scene = scene_for_export.clone();
        for m in &mut lambert_scene.materials {
            (m.metallic_factor, m.specular_factor, m.metallic_roughness_texture) = (0.0, 0.0, None);
        }
        let lambert_rate = path_rate_of(&Renderer::new(lambert_scene.clone(), &params)?, &quick_settings, &cam);
        for (model, scene, rate, dir) in [("glTF BRDF", &scene_for_export, quick_rate, name.clone()), ("Lambert", &lambert_scene, lambert_rate, format!("{name}-lambert"))] {
            let export_dir = export_root.join(dir);
            pathtracer::export::export_scene(scene, &[cam], &quick_settings, &export_dir)
                .with_context(|| format!("exporting {name} for Mitsuba to {}", export_dir.display()))?;
            ours_quick.push(OursQuick { scene: name.clone(), model, rate, export: export_dir });
        }
        let small = cam.downscaled(2);
        let std_rate = path_rate(&std_settings, &small);
        println!(
            "{:<12} {:>9} {:>10} {:>9.2} {:>15.2} {:>16.3} {:>18.3}",
            name,
            triangles,
            rig.kind.name(),
            build_ms,
            primary * 1e-6,
            quick_rate * 1e-6,
            std_rate * 1e-6
        );
    }
    bench_render_mitsuba(&ours_quick)
}

/// Our quick-preset figure for one scene and material model, with its export for Mitsuba.
struct OursQuick {
    scene: String,
    /// `glTF BRDF` (as authored) or `Lambert` (every material made exactly Lambertian).
    model: &'static str,
    /// Camera samples per second.
    rate: f64,
    export: std::path::PathBuf,
}

/// Runs `tests/mitsuba/bench.py` on the exports in `ours` and prints the side-by-side table.
fn bench_render_mitsuba(ours: &[OursQuick]) -> anyhow::Result<()> {
    use anyhow::Context;
    let root = crate::render::repo_root();
    let python = root.join(".venv/bin/python");
    let quick = pathtracer::dataset_render::DatasetRenderConfig::preset(pathtracer::dataset_render::Preset::Quick);
    println!();
    if !python.is_file() {
        println!(
            "Mitsuba comparison skipped: {} not found (python3 -m venv .venv && .venv/bin/pip install -r tests/mitsuba/requirements.txt)",
            python.display()
        );
        return Ok(());
    }
    let mut cmd = std::process::Command::new(&python);
    cmd.arg(root.join("tests/mitsuba/bench.py"));
    for o in ours {
        cmd.arg("--export").arg(&o.export);
    }
    let out = cmd.stderr(std::process::Stdio::inherit()).output().with_context(|| format!("running {}", python.display()))?;
    if !out.status.success() {
        println!("Mitsuba comparison failed ({}); our figures above stand", out.status);
        return Ok(());
    }
    let lines: Vec<serde_json::Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter(|l| l.trim_start().starts_with('{'))
        .map(serde_json::from_str)
        .collect::<Result<_, _>>()
        .context("reading bench.py's output")?;
    println!(
        "vs Mitsuba 3: same camera, {}x{}, {} spp, our max_bounces {} = Mitsuba max_depth {} (Russian roulette from the third \
         vertex on both: rr_depth 2), environment {:?}, transparent background = hide_emitters; Mitsuba: median of 3 renders \
         after a first one (JIT compilation)",
        quick.width,
        quick.height,
        quick.spp,
        quick.max_bounces,
        quick.max_bounces + 1,
        quick.environment
    );
    println!(
        "{:<12} {:<10} {:>14} {:<12} {:>17} {:>11} {:>12}  Mitsuba BSDF",
        "scene", "model", "ours Msample/s", "variant", "Mitsuba Msample/s", "first run s", "ours/Mitsuba"
    );
    for o in ours {
        let dir = o.export.display().to_string();
        for t in lines.iter().filter(|t| t["export"].as_str() == Some(dir.as_str())) {
            let text = |k: &str| t[k].as_str().unwrap_or("").to_string();
            match t["samples_per_second"].as_f64() {
                Some(mr) => println!(
                    "{:<12} {:<10} {:>14.3} {:<12} {:>17.3} {:>11.2} {:>11.2}x  {}",
                    o.scene,
                    o.model,
                    o.rate * 1e-6,
                    text("variant"),
                    mr * 1e-6,
                    t["first_seconds"].as_f64().unwrap_or(f64::NAN),
                    o.rate / mr,
                    text("bsdf")
                ),
                None => println!("{:<12} {:<10} {:>14.3} {:<12} {}", o.scene, o.model, o.rate * 1e-6, text("variant"), text("error")),
            }
        }
    }
    Ok(())
}
