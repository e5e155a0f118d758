//! `cargo xtask bench render`: the path tracer per scene in `scenes/` (BVH, rays, path samples)
//! and, where the Python environment is set up, beside Mitsuba 3 (`mitsuba.rs`).

use super::cpu::{CpuInfo, build_profile};
use super::figures::{RENDER_RUNS, Report, Spread, out_dir};
use super::mitsuba::{CMP_EXCLUDED, CMP_REF_SPP, CMP_SPP, CMP_WIDTH, MitsubaServer, MitsubaState, OursQuick, bench_render_mitsuba, compare_run};
use anyhow::Context;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Options of `bench render`.
#[derive(clap::Args)]
pub struct RenderBenchArgs {
    /// Scenes (names in `scenes/`), comma-separated; default every scene.
    #[arg(long)]
    pub scenes: Option<String>,
    /// Folder for `bench-render.json` and `bench-render.txt` (the printed tables).
    #[arg(long, default_value = "out/bench")]
    pub out: PathBuf,
    /// Timed renders per renderer, scene, model and sampler in the comparison with Mitsuba.
    #[arg(long, default_value_t = CMP_RUNS)]
    pub runs: usize,
    /// Measure in the profile this xtask was built with instead of re-running it in release.
    #[arg(long)]
    pub no_release: bool,
    /// Measure our renderer only (no Mitsuba renders; the comparison table is left out).
    #[arg(long)]
    pub no_mitsuba: bool,
}

/// Timed renders per renderer, scene and sampler in the comparison with Mitsuba. The error
/// of one render is heavy-tailed where caustics make fireflies, so its median over few renders
/// is itself noisy: over 5 renders Mitsuba's `ldsampler` error on `tabletop` read 3.4e-4, over
/// 15 it reads 5.5e-4 (its `multijitter`, 6.6e-4 and 6.4e-4). Both renderers get the same
/// number of renders.
const CMP_RUNS: usize = 15;

/// One scene's figures from our renderer alone.
#[derive(Serialize)]
struct SceneFigures {
    scene: String,
    triangles: usize,
    rig: String,
    bvh_build_ms: Spread,
    bvh_bytes_per_triangle: f64,
    primary_mrays_per_s: Spread,
    /// The same rays, each row's traced as packets of neighbours (as a pixel's samples are).
    primary_packet_mrays_per_s: Spread,
    shadow_mrays_per_s: Spread,
    shadow_rays_occluded: f64,
    quick_msamples_per_s: Spread,
    std_spp_msamples_per_s: Spread,
    /// `pathtracer::version::view_hash` of the first quick render (view 0), hex.
    quick_render_hash: String,
}

/// `cargo xtask bench render`: per scene in `scenes/`, the BVH build time (obvhs medium
/// preset) and memory, primary-ray throughput (pixel-centre closest hits, 256×256 from the
/// quick rig's first train camera), shadow-ray throughput (any-hit queries of the shadow rays
/// of those pixels' first vertices, [`pathtracer::render::Renderer::shadow_rays`]) and
/// path-tracing throughput at the quick preset (64×64, 16 spp, 4 bounces) and at the standard
/// preset's 128 spp and 8 bounces at 32×32; medians and quartiles over [`RENDER_RUNS`] runs,
/// all cores. Then both renderers on one image of each scene (the quick camera at
/// [`CMP_WIDTH`] px, [`CMP_SPP`] spp, quick bounces; Mitsuba 3 through
/// `tests/mitsuba/bench.py` from an export of the scene with that camera and settings,
/// `llvm_ad_rgb` where LLVM works, else `scalar_rgb`): samples/s, the mean squared error against
/// our [`CMP_REF_SPP`]-spp reference, our samples/s divided by Mitsuba's and the speed at equal
/// error; for each scene twice: as authored (Mitsuba runs our glTF BRDF as its Python BSDF
/// plugin) and with every material made exactly Lambertian (ours `Diffuse`, Mitsuba's native
/// `diffuse`); without the Python environment a note says how to create it. The tables go to
/// `<out>/bench-render.txt`, every figure with its spread to `<out>/bench-render.json`.
pub(super) fn bench_render(args: &RenderBenchArgs) -> anyhow::Result<()> {
    use pathtracer::accel::{Accel, AccelParams};
    use pathtracer::dataset_render::{DatasetRenderConfig, Preset};
    use pathtracer::render::{RenderSettings, Renderer};

    let only = args.scenes.as_deref();
    let cmp_runs = args.runs.max(1);
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
    let cpu = CpuInfo::detect();
    let threads = cpu.logical_cpus;
    let mut report = Report::default();
    report.line(format!("cpu: {}", cpu.summary()));
    report.line(format!(
        "bench render: profile {}, {threads} threads; medians of {RENDER_RUNS} runs (IQR = quartiles); BVH = obvhs medium_build; \
         primary = 256x256 pixel-centre closest hits, one ray at a time (every ray figure: each run repeats its rays for at least {MIN_RAY_RUN_SECONDS} s); packet = the same, each row's 64 to a packet; shadow = any-hit rays from those hits to every punctual light and one emitter \
         point; quick = 64x64 16 spp 4 bounces; std-spp = 32x32 128 spp 8 bounces; quick hash = the first quick render's bits \
         (colour and ground truth, pathtracer::version::view_hash): equal between two builds = bit-identical renders",
        build_profile()
    ));
    report.line(format!(
        "{:<12} {:>9} {:>10} {:>8} {:>8} {:>15} {:>11} {:>14} {:>14} {:>11} {:>16} {:>18}  {:<16}",
        "scene", "triangles", "rig", "BVH ms", "B/tri", "primary Mray/s", "IQR", "packet Mray/s", "shadow Mray/s", "IQR", "quick Msample/s", "std-spp Msample/s", "quick hash"
    ));
    let export_root = crate::render::repo_root().join("out/bench/mitsuba");
    let mut mitsuba = if args.no_mitsuba {
        MitsubaState::Skipped
    } else {
        let root = crate::render::repo_root();
        let python = root.join(".venv/bin/python");
        if !python.is_file() {
            MitsubaState::NoPython(python)
        } else {
            match MitsubaServer::start(&python, &root.join("tests/mitsuba/bench.py")) {
                Ok(server) => MitsubaState::Running(server),
                Err(e) => MitsubaState::Failed(format!("{e:#}")),
            }
        }
    };
    let mut ours_quick: Vec<OursQuick> = Vec::new();
    let mut figures: Vec<SceneFigures> = Vec::new();
    let mut simd = "";
    // Each scene's renderer, kept for the ray queries against Mitsuba's after its renders.
    let mut renderers: Vec<(String, Renderer)> = Vec::new();
    for path in scenes {
        let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let scene = pathtracer::import::load_gltf(&path, &pathtracer::import::ImportOptions::default())?;
        let scene_for_export = scene.clone();
        let params = AccelParams::medium_build();
        let build_ms = Spread::of(
            &(0..RENDER_RUNS)
                .map(|_| Accel::build(&scene, &params).map(|a| a.build_time().as_secs_f64() * 1e3))
                .collect::<Result<Vec<_>, _>>()?,
        );
        let triangles = scene.mesh.indices.len();
        let renderer = Renderer::new(scene, &params)?;
        simd = renderer.accel().simd_level();
        let bytes_per_tri = renderer.accel().memory_bytes() as f64 / triangles.max(1) as f64;
        let quick = DatasetRenderConfig::preset(Preset::Quick);
        let rig = pathtracer::rig::build_rig(renderer.scene(), &quick.rig_config())?;
        let cameras = rig.split(dataset::SplitKind::Train);
        let cam = cameras[0];
        let big = cam.at_width(256);
        let (primary, _) = sustained_mrays(|| renderer.primary_ray_throughput(&big));
        let (packet, _) = sustained_mrays(|| renderer.primary_packet_throughput(&big));
        let (shadow, occluded) = sustained_mrays(|| renderer.shadow_ray_throughput(&big));
        // Samples/s over the runs (view index k in run k), and the hash of run 0's output
        // (`pathtracer::version::view_hash`): equal hashes from two builds mean their renders
        // are bit-identical.
        let path_rate_of = |renderer: &Renderer, settings: &RenderSettings, camera: &dataset::Camera| {
            let mut hash = 0u64;
            let rates: Vec<f64> = (0..RENDER_RUNS)
                .map(|k| {
                    let t = std::time::Instant::now();
                    let out = renderer.render_view(camera, k as u32, settings);
                    let rate = out.samples as f64 / t.elapsed().as_secs_f64().max(1e-9) * 1e-6;
                    if k == 0 {
                        hash = pathtracer::version::view_hash(&out);
                    }
                    rate
                })
                .collect();
            (Spread::of(&rates), hash)
        };
        let path_rate = |settings: &RenderSettings, camera: &dataset::Camera| path_rate_of(&renderer, settings, camera);
        let quick_settings = quick_render_settings(&quick);
        let standard = DatasetRenderConfig::preset(Preset::Standard);
        let std_settings = RenderSettings { spp: standard.spp, max_bounces: standard.max_bounces, ..quick_settings.clone() };
        let (quick_rate, quick_hash) = path_rate(&quick_settings, &cam);
        // The same scene with every material exactly Lambertian (metallic 0, specular 0), for a
        // comparison with Mitsuba's native `diffuse`.
        let mut lambert_scene = scene_for_export.clone();
        for m in &mut lambert_scene.materials {
            (m.metallic_factor, m.specular_factor, m.metallic_roughness_texture) = (0.0, 0.0, None);
        }
        let lambert_renderer = Renderer::new(lambert_scene.clone(), &params)?;
        // The comparison with Mitsuba: its own camera size and spp (see [`CMP_WIDTH`]).
        let cmp_cam = cam.at_width(CMP_WIDTH);
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
            let cmp = compare_run(renderer, &cmp_cam, &cmp_settings, &export_dir, cmp_runs)?;
            // Mitsuba's renders of the same image right after ours: seconds apart, not minutes.
            let records = mitsuba
                .request(serde_json::json!({ "cmd": "measure", "export": export_dir.display().to_string(), "runs": cmp_runs }))
                .and_then(|v| v.get("records").and_then(|r| r.as_array()).cloned());
            ours_quick.push(OursQuick { scene: name.clone(), model, cmp, export: export_dir, mitsuba: records });
        }
        let small = cam.downscaled(2);
        let (std_rate, _) = path_rate(&std_settings, &small);
        report.line(format!(
            "{:<12} {:>9} {:>10} {:>8.2} {:>8.0} {:>15.2} {:>11} {:>14.2} {:>14.2} {:>11} {:>16.3} {:>18.3}  {:016x}",
            name,
            triangles,
            rig.kind.name(),
            build_ms.median,
            bytes_per_tri,
            primary.median,
            primary.iqr(2),
            packet.median,
            shadow.median,
            shadow.iqr(2),
            quick_rate.median,
            std_rate.median,
            quick_hash
        ));
        figures.push(SceneFigures {
            scene: name.clone(),
            triangles,
            rig: rig.kind.name().to_string(),
            bvh_build_ms: build_ms,
            bvh_bytes_per_triangle: bytes_per_tri,
            primary_mrays_per_s: primary,
            primary_packet_mrays_per_s: packet,
            shadow_mrays_per_s: shadow,
            shadow_rays_occluded: occluded,
            quick_msamples_per_s: quick_rate,
            std_spp_msamples_per_s: std_rate,
            quick_render_hash: format!("{quick_hash:016x}"),
        });
        renderers.push((name, renderer));
    }
    report.line(format!("child-box test: {simd}"));
    let comparisons = bench_render_mitsuba(&ours_quick, cmp_runs, &mitsuba, &mut report)?;
    drop(mitsuba);
    let rays = if args.no_mitsuba { Vec::new() } else { bench_render_rays(&renderers, &export_root, &out_dir(&args.out), &mut report)? };
    let json = serde_json::json!({
        "profile": build_profile(),
        "cpu": cpu,
        "threads": threads,
        "child_box_test": simd,
        "runs": RENDER_RUNS,
        "comparison_settings": { "width": CMP_WIDTH, "spp": CMP_SPP, "reference_spp": CMP_REF_SPP, "runs": cmp_runs, "excluded_pixel_share": CMP_EXCLUDED },
        "scenes": figures,
        "comparisons": comparisons,
        "rays_vs_mitsuba": rays,
    });
    report.write(&out_dir(&args.out), "bench-render", &json)
}

/// Shortest timed span of one run of a ray-throughput figure, seconds.
const MIN_RAY_RUN_SECONDS: f64 = 0.1;

/// A ray-throughput figure in Mray/s over [`RENDER_RUNS`] runs, each run calling `trace` (one
/// parallel pass over a set of rays, [`pathtracer::render::PrimaryRayStats`]) until it has
/// traced for [`MIN_RAY_RUN_SECONDS`]: a single pass over a small scene's rays takes a few
/// milliseconds, about what waking a virtual machine's second CPU can take, and read half the
/// throughput in some runs. Also the share of the traced rays that hit.
fn sustained_mrays(mut trace: impl FnMut() -> pathtracer::render::PrimaryRayStats) -> (Spread, f64) {
    let (mut all_rays, mut all_hits) = (0u64, 0u64);
    let runs: Vec<f64> = (0..RENDER_RUNS)
        .map(|_| {
            let (mut rays, mut seconds) = (0u64, 0.0f64);
            while seconds < MIN_RAY_RUN_SECONDS {
                let s = trace();
                if s.rays == 0 {
                    break;
                }
                rays += s.rays;
                seconds += s.seconds;
                all_hits += s.hits;
            }
            all_rays += rays;
            if seconds > 0.0 { rays as f64 / seconds * 1e-6 } else { 0.0 }
        })
        .collect();
    (Spread::of(&runs), all_hits as f64 / all_rays.max(1) as f64)
}

/// The JSON objects a harness script printed, one per line (other lines are skipped).
fn json_lines(stdout: &[u8]) -> serde_json::Result<Vec<serde_json::Value>> {
    String::from_utf8_lossy(stdout).lines().filter(|l| l.trim_start().starts_with('{')).map(serde_json::from_str).collect()
}

/// Ray queries of ours and Mitsuba 3's on exactly the same rays: `tests/mitsuba/rays.py` writes,
/// per scene (its export for the comparison, `<export_root>/<scene>`), the 256-px pixel-centre
/// camera rays and one uniformly random ray from each of their hits, with the Mray/s of
/// Mitsuba's closest-hit and any-hit queries on them (all threads, medians); ours are timed on
/// the files ([`pathtracer::render::Renderer::ray_query_throughput`], medians of
/// [`RENDER_RUNS`]). Returns nothing where the virtual environment is missing (the
/// comparison above has said so) and says why where `rays.py` fails.
fn bench_render_rays(scenes: &[(String, pathtracer::render::Renderer)], export_root: &Path, out: &Path, report: &mut Report) -> anyhow::Result<Vec<serde_json::Value>> {
    use pathtracer::render::{RayQuery, read_ray_file};
    let root = crate::render::repo_root();
    let python = root.join(".venv/bin/python");
    if !python.is_file() || scenes.is_empty() {
        return Ok(Vec::new());
    }
    let ray_dir = out.join("rays");
    let mut cmd = std::process::Command::new(&python);
    cmd.arg(root.join("tests/mitsuba/rays.py")).arg("--out").arg(&ray_dir);
    for (name, _) in scenes {
        cmd.arg("--export").arg(export_root.join(name));
    }
    let run = cmd.stderr(std::process::Stdio::inherit()).output().with_context(|| format!("running {}", python.display()))?;
    report.line("");
    if !run.status.success() {
        report.line(format!("rays vs Mitsuba skipped: tests/mitsuba/rays.py failed ({})", run.status));
        return Ok(Vec::new());
    }
    let lines = json_lines(&run.stdout).context("reading rays.py's output")?;
    report.line(format!(
        "rays vs Mitsuba 3 ({}): the same rays for both (tests/mitsuba/rays.py, in {}): `camera` = the comparison camera's pixel-centre rays at 256 px wide, \
         `incoherent` = one ray from each of their hits in a uniformly random direction; Mray/s on all threads, medians ({RENDER_RUNS} runs ours, 30 Mitsuba's); \
         ours one ray at a time, and as packets of 64 consecutive rays (as a pixel's camera rays are traced); ratio = ours (the faster way) / Mitsuba's",
        lines.first().and_then(|l| l["variant"].as_str()).unwrap_or("?"),
        ray_dir.display()
    ));
    report.line(format!(
        "{:<10} {:>7} {:>9} {:>9} {:>9} {:>6}   {:>7} {:>9} {:>9} {:>6}   {:>9} {:>9} {:>6}",
        "scene", "camera", "closest", "packets", "Mi", "ratio", "incoh.", "closest", "Mi", "ratio", "any-hit", "Mi", "ratio"
    ));
    let mut rows = Vec::new();
    for (name, renderer) in scenes {
        let Some(mi) = lines.iter().find(|l| l["scene"].as_str() == Some(name.as_str())) else { continue };
        let rays_of = |set: &str| -> anyhow::Result<Vec<(pathtracer::geometry::Ray, f32)>> {
            let file = mi[set]["file"].as_str().with_context(|| format!("rays.py: no {set} file for {name}"))?;
            Ok(read_ray_file(Path::new(file))?)
        };
        let ours = |rays: &[(pathtracer::geometry::Ray, f32)], q: RayQuery| sustained_mrays(|| renderer.ray_query_throughput(rays, q)).0;
        let mi_rate = |set: &str, k: &str| mi[set][k].as_f64().unwrap_or(f64::NAN);
        let (camera_rays, incoherent_rays) = (rays_of("primary")?, rays_of("incoherent")?);
        let cam = ours(&camera_rays, RayQuery::Closest);
        let cam_packets = ours(&camera_rays, RayQuery::ClosestPackets);
        let inc = ours(&incoherent_rays, RayQuery::Closest);
        let inc_any = ours(&incoherent_rays, RayQuery::AnyHit);
        let (mi_cam, mi_inc, mi_any) = (mi_rate("primary", "closest_mrays_per_s"), mi_rate("incoherent", "closest_mrays_per_s"), mi_rate("incoherent", "any_hit_mrays_per_s"));
        let best_cam = cam.median.max(cam_packets.median);
        report.line(format!(
            "{:<10} {:>7} {:>9.2} {:>9.2} {:>9.2} {:>5.2}x   {:>7} {:>9.2} {:>9.2} {:>5.2}x   {:>9.2} {:>9.2} {:>5.2}x",
            name,
            mi["primary"]["rays"].as_u64().unwrap_or(0),
            cam.median,
            cam_packets.median,
            mi_cam,
            best_cam / mi_cam,
            mi["incoherent"]["rays"].as_u64().unwrap_or(0),
            inc.median,
            mi_inc,
            inc.median / mi_inc,
            inc_any.median,
            mi_any,
            inc_any.median / mi_any
        ));
        rows.push(serde_json::json!({
            "scene": name,
            "camera": { "rays": mi["primary"]["rays"], "ours_closest_mrays_per_s": cam, "ours_packets_mrays_per_s": cam_packets, "mitsuba_closest_mrays_per_s": mi_cam, "mitsuba_any_hit_mrays_per_s": mi_rate("primary", "any_hit_mrays_per_s") },
            "incoherent": { "rays": mi["incoherent"]["rays"], "ours_closest_mrays_per_s": inc, "ours_any_hit_mrays_per_s": inc_any, "mitsuba_closest_mrays_per_s": mi_inc, "mitsuba_any_hit_mrays_per_s": mi_any },
        }));
    }
    Ok(rows)
}

/// The path-tracing settings of a quick-preset view as the benches time it: the preset's spp,
/// bounces and constant environment, seed 0, a transparent background, no environment map.
pub(super) fn quick_render_settings(
    quick: &pathtracer::dataset_render::DatasetRenderConfig,
) -> pathtracer::render::RenderSettings {
    pathtracer::render::RenderSettings {
        spp: quick.spp,
        max_bounces: quick.max_bounces,
        seed: 0,
        environment: quick.environment,
        transparent_background: true,
        environment_map: None,
    }
}
