//! `cargo xtask bench render|nerf`: performance figures, printed.

/// Arguments of `bench`.
#[derive(clap::Args)]
pub struct BenchArgs {
    /// What to measure.
    #[command(subcommand)]
    pub what: BenchWhat,
}

/// Benchmarks, each with its own options.
#[derive(clap::Subcommand)]
pub enum BenchWhat {
    /// Path tracer: BVH build, primary rays, path samples per scene, and Mitsuba 3 side by side.
    Render(RenderBenchArgs),
    /// NeRF training throughput for both models, and the time to render a full-size view from
    /// a fast model.
    Nerf(crate::bench_nerf::NerfBenchArgs),
    /// `--model auto` against fixed fast sizes and paper on every scene (train, eval, compare).
    Auto(crate::bench_auto::AutoBenchArgs),
}

/// Options of `bench render`.
#[derive(clap::Args)]
pub struct RenderBenchArgs {
    /// Scenes (names in `scenes/`), comma-separated; default every scene.
    #[arg(long)]
    pub scenes: Option<String>,
}

/// Runs a benchmark.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    match args.what {
        BenchWhat::Render(a) => bench_render(a.scenes.as_deref()),
        BenchWhat::Nerf(a) => crate::bench_nerf::run(a),
        BenchWhat::Auto(a) => crate::bench_auto::run(a),
    }
}

/// Repetitions per figure; the median is reported.
const RENDER_RUNS: usize = 5;

/// Timed renders per renderer, scene and sampler in the comparison with Mitsuba. The error
/// of one render is heavy-tailed where caustics make fireflies, so its median over few renders
/// is itself noisy: over 5 renders Mitsuba's `ldsampler` error on `tabletop` read 3.4e-4, over
/// 15 it reads 5.5e-4 (its `multijitter`, 6.6e-4 and 6.4e-4). Both renderers get the same
/// number of renders.
const CMP_RUNS: usize = 15;

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
/// [`RENDER_RUNS`] runs, all cores. Then both renderers on one image of each scene (the quick
/// camera at [`CMP_WIDTH`] px, [`CMP_SPP`] spp, quick bounces; Mitsuba 3 through
/// `tests/mitsuba/bench.py` from an export of the scene with that camera and settings,
/// `llvm_ad_rgb` where LLVM works, else `scalar_rgb`): samples/s, the mean squared error against
/// our [`CMP_REF_SPP`]-spp reference, our samples/s divided by Mitsuba's and the speed at equal
/// error; for each scene twice: as authored (Mitsuba runs our glTF BRDF as its Python BSDF
/// plugin) and with every material made exactly Lambertian (ours `Diffuse`, Mitsuba's native
/// `diffuse`); without the Python environment a note says how to create it.
fn bench_render(only: Option<&str>) -> anyhow::Result<()> {
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
    if let Some(only) = only {
        let names: Vec<&str> = only.split(',').map(str::trim).filter(|n| !n.is_empty()).collect();
        for n in &names {
            anyhow::ensure!(
                scenes.iter().any(|p| p.file_stem().is_some_and(|s| s == *n)),
                "--scenes: no scene '{n}' in {}",
                dir.display()
            );
        }
        scenes.retain(|p| p.file_stem().is_some_and(|s| names.iter().any(|n| s == *n)));
    }
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
        let big = scaled_camera(&cam, 256);
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
        let lambert_renderer = Renderer::new(lambert_scene.clone(), &params)?;
        // The comparison with Mitsuba: its own camera size and spp (see [`CMP_WIDTH`]).
        let cmp_cam = scaled_camera(&cam, CMP_WIDTH);
        // Opaque background: Mitsuba's `hide_emitters` (its transparent background) would
        // also hide emitters the camera sees directly.
        let cmp_settings = RenderSettings { spp: CMP_SPP, transparent_background: false, ..quick_settings.clone() };
        for (model, scene, renderer, dir) in [
            ("glTF BRDF", &scene_for_export, &renderer, name.clone()),
            ("Lambert", &lambert_scene, &lambert_renderer, format!("{name}-lambert")),
        ] {
            let export_dir = export_root.join(dir);
            pathtracer::export::export_scene(scene, &[cmp_cam], &cmp_settings, &export_dir)
                .with_context(|| format!("exporting {name} for Mitsuba to {}", export_dir.display()))?;
            let cmp = compare_run(renderer, &cmp_cam, &cmp_settings, &export_dir)?;
            ours_quick.push(OursQuick { scene: name.clone(), model, cmp, export: export_dir });
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

/// Width of the image rendered by both renderers for the side-by-side comparison (the quick
/// rig's first train camera scaled to it): large enough that Mitsuba's per-render overhead
/// (Python, kernel launch) is a small part of its time.
const CMP_WIDTH: u32 = 128;
/// Samples per pixel of the compared renders.
const CMP_SPP: u32 = 64;
/// Samples per pixel of our reference image (two independent halves), against which both
/// renderers' errors are measured.
const CMP_REF_SPP: u32 = 1024;

/// `cam` with the same field of view at `width` pixels.
fn scaled_camera(cam: &dataset::Camera, width: u32) -> dataset::Camera {
    let scale = width as f64 / cam.intrinsics.width as f64;
    dataset::Camera {
        intrinsics: dataset::Intrinsics {
            width,
            height: (cam.intrinsics.height as f64 * scale).round().max(1.0) as u32,
            fl_x: cam.intrinsics.fl_x * scale,
            fl_y: cam.intrinsics.fl_y * scale,
            cx: cam.intrinsics.cx * scale,
            cy: cam.intrinsics.cy * scale,
        },
        c2w: cam.c2w,
    }
}

/// RGB of an RGBA image, as `f64`.
fn rgb_of(img: &dataset::RgbaImage) -> Vec<f64> {
    img.data.chunks_exact(4).flat_map(|p| [p[0] as f64, p[1] as f64, p[2] as f64]).collect()
}

/// Mean squared difference over the RGB pixels where `mask` is true (every pixel without one).
fn mse(a: &[f64], b: &[f64], mask: Option<&[bool]>) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        if mask.is_none_or(|m| m[i / 3]) {
            sum += (x - y) * (x - y);
            n += 1;
        }
    }
    sum / n.max(1) as f64
}

/// Share of the pixels left out of the compared errors: those where our reference's own noise
/// (its two halves' squared difference) is largest. A highlight or caustic that a
/// reference of [`CMP_REF_SPP`] samples has not converged in (one pixel of the `materials`
/// scene at 35 where Mitsuba's 4096-spp image has 13) otherwise decides every render's error,
/// theirs and ours alike; both renderers are measured on the same pixels.
const CMP_EXCLUDED: f64 = 0.001;

/// The pixels whose reference noise `(r1 − r2)² / 4` (mean over RGB) is not among the
/// [`CMP_EXCLUDED`] largest.
fn reliable_pixels(r1: &[f64], r2: &[f64]) -> Vec<bool> {
    let noise: Vec<f64> = r1.chunks_exact(3).zip(r2.chunks_exact(3)).map(|(a, b)| mse(a, b, None) / 4.0).collect();
    let drop = (noise.len() as f64 * CMP_EXCLUDED).ceil() as usize;
    let mut order: Vec<usize> = (0..noise.len()).collect();
    order.sort_by(|&i, &j| noise[j].total_cmp(&noise[i]).then(i.cmp(&j)));
    let mut keep = vec![true; noise.len()];
    for &i in order.iter().take(drop) {
        keep[i] = false;
    }
    keep
}

/// Our side of the comparison for one scene and material model.
struct CmpRun {
    /// Median seconds of one render of the compared image.
    seconds: f64,
    /// Camera samples of that render.
    samples: u64,
    /// Median over the timed renders of the mean squared RGB error against the reference, less
    /// the reference's own noise (the median: in a scene with caustics one render in several
    /// catches a firefly of 10^4 in one sample, for either renderer, and the mean of a few
    /// renders is then decided by luck).
    mse: f64,
}

/// Renders our reference (`reference.npy`, RGB, two independent halves of [`CMP_REF_SPP`]; its
/// noise, the mean squared half-difference / 4, goes to `reference_noise.json`) into the
/// export folder and times [`CMP_RUNS`] renders of `settings` against it.
fn compare_run(
    renderer: &pathtracer::render::Renderer,
    cam: &dataset::Camera,
    settings: &pathtracer::render::RenderSettings,
    export_dir: &std::path::Path,
) -> anyhow::Result<CmpRun> {
    let half = pathtracer::render::RenderSettings { spp: CMP_REF_SPP / 2, seed: 1_000_003, ..settings.clone() };
    let r1 = rgb_of(&renderer.render_view(cam, 0, &half).color);
    let r2 = rgb_of(&renderer.render_view(cam, 1, &half).color);
    let reference: Vec<f64> = r1.iter().zip(&r2).map(|(a, b)| 0.5 * (a + b)).collect();
    let keep = reliable_pixels(&r1, &r2);
    let ref_noise = mse(&r1, &r2, Some(&keep)) / 4.0;
    let (w, h) = (cam.intrinsics.width as usize, cam.intrinsics.height as usize);
    let ref32: Vec<f32> = reference.iter().map(|&v| v as f32).collect();
    pathtracer::export::write_npy_f32(&export_dir.join("reference.npy"), &[h, w, 3], &ref32)?;
    let mask32: Vec<f32> = keep.iter().map(|&k| if k { 1.0 } else { 0.0 }).collect();
    pathtracer::export::write_npy_f32(&export_dir.join("reference_mask.npy"), &[h, w], &mask32)?;
    dataset::io::atomic_write_json(
        &export_dir.join("reference_noise.json"),
        &serde_json::json!({ "spp": CMP_REF_SPP, "mse": ref_noise }),
    )?;
    let mut times = Vec::new();
    let mut errors = Vec::new();
    let mut samples = 0;
    for k in 0..CMP_RUNS {
        let t = std::time::Instant::now();
        let out = renderer.render_view(cam, 10 + k as u32, settings);
        times.push(t.elapsed().as_secs_f64());
        samples = out.samples;
        errors.push(mse(&rgb_of(&out.color), &reference, Some(&keep)) - ref_noise);
    }
    Ok(CmpRun { seconds: median(times), samples, mse: median(errors) })
}

/// Our figures for one scene and material model, with its export for Mitsuba.
struct OursQuick {
    scene: String,
    /// `glTF BRDF` (as authored) or `Lambert` (every material made exactly Lambertian).
    model: &'static str,
    /// The compared render.
    cmp: CmpRun,
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
    cmd.arg(root.join("tests/mitsuba/bench.py")).arg("--runs").arg(CMP_RUNS.to_string());
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
        "vs Mitsuba 3: same camera (the quick rig's first train view) at {CMP_WIDTH} px wide, {CMP_SPP} spp, our max_bounces {} = \
         Mitsuba max_depth {} (Russian roulette from the third vertex on both: rr_depth 2), environment {:?} as an opaque \
         background (both show it and the emitters the camera sees); medians of {CMP_RUNS} timed renders (Mitsuba's after a first one for \
         JIT compilation; Mitsuba with its default `independent` sampler, with `ldsampler`, its counterpart of our padded \
         Owen-scrambled Sobol' sampler, and with `multijitter`). MSE = mean squared RGB error of one render against our {CMP_REF_SPP}-spp reference, less that \
         reference's own noise, over the pixels but the {}% where that noise is largest (a few unconverged highlight or caustic \
         pixels of the reference would otherwise decide it), median over the timed renders (a rare caustic firefly would \
         decide a mean of a few); Mi bias² = the part of Mitsuba's MSE that more samples would not remove (≈ 0: both \
         converge to the same image). Equal-error speed = (MSE x seconds of Mitsuba) / (MSE x seconds of ours): how much less time we need \
         for the same error (Monte Carlo error falls as 1/time).",
        quick.max_bounces,
        quick.max_bounces + 1,
        quick.environment,
        CMP_EXCLUDED * 100.0
    );
    println!(
        "{:<10} {:<9} {:>8} {:>10} {:<11} {:<11} {:>8} {:>10} {:>10} {:>8} {:>8}  Mitsuba BSDF",
        "scene", "model", "ours Ms/s", "ours MSE", "variant", "Mi sampler", "Mi Ms/s", "Mi MSE", "Mi bias²", "speed", "eq-err"
    );
    for o in ours {
        let dir = o.export.display().to_string();
        let ours_rate = o.cmp.samples as f64 / o.cmp.seconds.max(1e-9);
        for t in lines.iter().filter(|t| t["export"].as_str() == Some(dir.as_str())) {
            let text = |k: &str| t[k].as_str().unwrap_or("").to_string();
            match (t["samples_per_second"].as_f64(), t["seconds"].as_f64()) {
                (Some(mr), Some(ms)) => {
                    let mi_mse = t["mse"].as_f64().unwrap_or(f64::NAN);
                    println!(
                        "{:<10} {:<9} {:>8.3} {:>10.3e} {:<11} {:<11} {:>8.3} {:>10.3e} {:>10.1e} {:>7.2}x {:>7.2}x  {}",
                        o.scene,
                        o.model,
                        ours_rate * 1e-6,
                        o.cmp.mse,
                        text("variant"),
                        text("sampler"),
                        mr * 1e-6,
                        mi_mse,
                        t["bias2"].as_f64().unwrap_or(f64::NAN),
                        ours_rate / mr,
                        (mi_mse * ms) / (o.cmp.mse * o.cmp.seconds),
                        text("bsdf")
                    )
                }
                _ => println!(
                    "{:<10} {:<9} {:>8.3} {:>10.3e} {:<11} {}",
                    o.scene,
                    o.model,
                    ours_rate * 1e-6,
                    o.cmp.mse,
                    text("variant"),
                    text("error")
                ),
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_noisiest_reference_pixels_are_left_out_of_the_error() {
        // 2000 pixels whose halves agree to within 0.01, and one unconverged highlight.
        let n = 2000;
        let r1: Vec<f64> = (0..n * 3).map(|i| 0.5 + 0.01 * ((i * 7919) % 13) as f64 / 13.0).collect();
        let mut r2 = vec![0.5; n * 3];
        r2[3 * 1234..3 * 1235].copy_from_slice(&[60.0, 50.0, 20.0]);
        let keep = reliable_pixels(&r1, &r2);
        // ⌈2000 × 0.001⌉ = 2 pixels out: the highlight first.
        assert_eq!(keep.iter().filter(|k| !**k).count(), 2);
        assert!(!keep[1234]);
        // A render that is exact but for that pixel has (almost) no error on the kept pixels,
        // and a large one over all of them.
        let mut render = r1.clone();
        render[3 * 1234] = 0.0;
        assert!(mse(&render, &r1, Some(&keep)) == 0.0);
        assert!(mse(&render, &r2, None) > 0.5);
    }
}
