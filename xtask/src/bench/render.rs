//! `cargo xtask bench render|scaling|nerf|auto|auto-diff`: performance figures, printed (the render
//! benchmarks also write them as JSON).

use anyhow::Context;
use serde::Serialize;
use std::path::{Path, PathBuf};

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
    /// Path tracer (release profile): BVH build, primary and shadow rays, path samples per scene, and Mitsuba 3 side by side.
    Render(RenderBenchArgs),
    /// Path tracer (release profile): samples/s, BVH build time and memory against the triangle count (generated stress scenes).
    Scaling(ScalingBenchArgs),
    /// NeRF training (release profile): throughput of both models, the fast model's roofline, and the time to render a full-size view from a fast model.
    Nerf(super::nerf::NerfBenchArgs),
    /// `--model auto` against fixed fast sizes and paper on every scene (train, eval, compare).
    Auto(super::auto::AutoBenchArgs),
    /// Quality at equal time before and after a change: two `bench auto` output folders (two builds, the same runs) compared figure by figure against the seeds' noise.
    AutoDiff(super::auto_diff::AutoDiffArgs),
}

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

/// Options of `bench scaling`.
#[derive(clap::Args)]
pub struct ScalingBenchArgs {
    /// Approximate triangle counts of the generated stress scenes, comma-separated.
    #[arg(long, default_value = "1000,10000,100000,1000000")]
    pub triangles: String,
    /// Folder for `bench-scaling.json`, `bench-scaling.txt` and the generated scenes (`stress/`).
    #[arg(long, default_value = "out/bench")]
    pub out: PathBuf,
    /// Measure in the profile this xtask was built with instead of re-running it in release.
    #[arg(long)]
    pub no_release: bool,
}

/// Runs a benchmark.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    match args.what {
        BenchWhat::Render(a) => {
            if a.no_release || !rerun_in_release()? {
                bench_render(&a)?;
            }
            Ok(())
        }
        BenchWhat::Scaling(a) => {
            if a.no_release || !rerun_in_release()? {
                bench_scaling(&a)?;
            }
            Ok(())
        }
        BenchWhat::Nerf(a) => {
            if a.no_release || !rerun_in_release()? {
                super::nerf::run(a)?;
            }
            Ok(())
        }
        BenchWhat::Auto(a) => super::auto::run(a),
        BenchWhat::AutoDiff(a) => super::auto_diff::run(a),
    }
}

/// The cargo profile this binary was built with, as far as it can tell: `dev` keeps debug
/// assertions on (see the workspace `Cargo.toml`), `release` turns them off.
pub fn build_profile() -> &'static str {
    if cfg!(debug_assertions) { "dev" } else { "release" }
}

/// The CPU the benchmark ran on, as Linux's `/proc/cpuinfo` names it (first processor), so that
/// figures from different machines are told apart: a cloud VM often reports only a family
/// ("AMD EPYC"), so the vendor's family, model and stepping numbers and the per-core L2 size
/// (`cache size`) are kept, with the widest vector extension detected at run time.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CpuInfo {
    pub model_name: String,
    pub vendor: String,
    pub family: Option<u32>,
    pub model: Option<u32>,
    pub stepping: Option<u32>,
    pub cache: String,
    pub logical_cpus: usize,
    /// "avx512f", "avx2", "sse2" or "" (not x86-64).
    pub widest_simd: &'static str,
}

impl CpuInfo {
    /// This machine's description: its `/proc/cpuinfo` (fields left empty where that file is
    /// missing), its CPU count and the widest SIMD it has.
    pub fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        let widest_simd = if std::arch::is_x86_feature_detected!("avx512f") {
            "avx512f"
        } else if std::arch::is_x86_feature_detected!("avx2") {
            "avx2"
        } else {
            "sse2"
        };
        #[cfg(not(target_arch = "x86_64"))]
        let widest_simd = "";
        let logical_cpus = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
        Self::parse(&std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default(), logical_cpus, widest_simd)
    }

    /// The description from the text of a `/proc/cpuinfo` (its first processor's block), with
    /// the CPU count and SIMD level detected elsewhere.
    pub fn parse(cpuinfo: &str, logical_cpus: usize, widest_simd: &'static str) -> Self {
        let first = cpuinfo.split("\n\n").next().unwrap_or("");
        let field = |key: &str| {
            first.lines().find_map(|l| {
                let (k, v) = l.split_once(':')?;
                (k.trim() == key).then(|| v.trim().to_string())
            })
        };
        let number = |key: &str| field(key).and_then(|v| v.parse().ok());
        CpuInfo {
            model_name: field("model name").unwrap_or_else(|| "unknown".into()),
            vendor: field("vendor_id").unwrap_or_default(),
            family: number("cpu family"),
            model: number("model"),
            stepping: number("stepping"),
            cache: field("cache size").unwrap_or_default(),
            logical_cpus,
            widest_simd,
        }
    }

    /// One line: `AMD EPYC (AuthenticAMD family 25 model 17 stepping 1, cache 1024 KB, 2 CPUs, avx512f)`.
    pub fn summary(&self) -> String {
        let num = |n: Option<u32>| n.map_or("?".to_string(), |n| n.to_string());
        format!(
            "{} ({} family {} model {} stepping {}, cache {}, {} CPUs, {})",
            self.model_name,
            if self.vendor.is_empty() { "unknown vendor" } else { &self.vendor },
            num(self.family),
            num(self.model),
            num(self.stepping),
            if self.cache.is_empty() { "?" } else { &self.cache },
            self.logical_cpus,
            if self.widest_simd.is_empty() { "no x86 SIMD" } else { self.widest_simd }
        )
    }
}

/// In a dev build, builds the workspace in the release profile (`cargo build --release
/// --workspace --locked` from the repository root: the same features as every other build, so
/// nothing is rebuilt twice) and runs this same command line with the release `xtask`, returning
/// `true` once it succeeded; in a release build returns `false` at once (the caller measures).
/// Path tracing is measured in release: the dev profile keeps overflow checks and debug
/// assertions and compiles our crates incrementally.
fn rerun_in_release() -> anyhow::Result<bool> {
    if !cfg!(debug_assertions) {
        return Ok(false);
    }
    let root = crate::render::repo_root();
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    eprintln!("bench: this xtask is a dev build; building the release profile (cargo build --release --workspace; the first build takes minutes)");
    let status = std::process::Command::new(&cargo)
        .current_dir(&root)
        .args(["build", "--release", "--workspace", "--locked"])
        .status()
        .context("running cargo build --release")?;
    anyhow::ensure!(status.success(), "cargo build --release failed ({status})");
    let target = std::env::var_os("CARGO_TARGET_DIR").map(PathBuf::from).unwrap_or_else(|| root.join("target"));
    let exe = target.join("release").join(format!("xtask{}", std::env::consts::EXE_SUFFIX));
    let status = std::process::Command::new(&exe)
        .current_dir(&root)
        .args(std::env::args_os().skip(1))
        .status()
        .with_context(|| format!("running {}", exe.display()))?;
    anyhow::ensure!(status.success(), "the release run of the benchmark failed ({status})");
    Ok(true)
}

/// Repetitions per figure; the median is reported.
const RENDER_RUNS: usize = 5;

/// Timed renders per renderer, scene and sampler in the comparison with Mitsuba. The error
/// of one render is heavy-tailed where caustics make fireflies, so its median over few renders
/// is itself noisy: over 5 renders Mitsuba's `ldsampler` error on `tabletop` read 3.4e-4, over
/// 15 it reads 5.5e-4 (its `multijitter`, 6.6e-4 and 6.4e-4). Both renderers get the same
/// number of renders.
const CMP_RUNS: usize = 15;

/// A measured figure over repeated runs: its median and spread.
#[derive(Clone, Copy, Debug, Serialize)]
struct Spread {
    median: f64,
    /// First and third quartiles (linear interpolation between order statistics).
    q1: f64,
    q3: f64,
    min: f64,
    max: f64,
    /// Number of runs.
    n: usize,
}

impl Spread {
    /// The figures of `v` (all zero for an empty list).
    fn of(v: &[f64]) -> Spread {
        let mut v = v.to_vec();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n == 0 {
            return Spread { median: 0.0, q1: 0.0, q3: 0.0, min: 0.0, max: 0.0, n };
        }
        let at = |q: f64| {
            let x = q * (n - 1) as f64;
            let (i, f) = (x.floor() as usize, x.fract());
            if i + 1 < n { v[i] + f * (v[i + 1] - v[i]) } else { v[i] }
        };
        Spread { median: at(0.5), q1: at(0.25), q3: at(0.75), min: v[0], max: v[n - 1], n }
    }
    /// `x ↦ s·x` applied to every figure (`s > 0`).
    fn scaled(self, s: f64) -> Spread {
        Spread { median: self.median * s, q1: self.q1 * s, q3: self.q3 * s, min: self.min * s, max: self.max * s, n: self.n }
    }
    /// The interquartile range as `[q1, q3]` in text with `digits` decimals.
    fn iqr(&self, digits: usize) -> String {
        format!("{:.digits$}-{:.digits$}", self.q1, self.q3)
    }
}

/// The printed tables, kept to be written next to the JSON.
#[derive(Default)]
struct Report(String);

impl Report {
    /// Prints `line` and keeps it.
    fn line(&mut self, line: impl AsRef<str>) {
        println!("{}", line.as_ref());
        self.0.push_str(line.as_ref());
        self.0.push('\n');
    }
    /// Writes the tables to `<out>/<stem>.txt` and `json` to `<out>/<stem>.json`, and says where.
    fn write(&self, out: &Path, stem: &str, json: &serde_json::Value) -> anyhow::Result<()> {
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        let (txt, js) = (out.join(format!("{stem}.txt")), out.join(format!("{stem}.json")));
        dataset::io::atomic_write(&txt, self.0.as_bytes())?;
        dataset::io::atomic_write_json(&js, json)?;
        println!("wrote {} and {}", js.display(), txt.display());
        Ok(())
    }
}

/// A relative `--out` folder is taken from the repository root (the release re-run starts there).
fn out_dir(out: &Path) -> PathBuf {
    if out.is_absolute() { out.to_path_buf() } else { crate::render::repo_root().join(out) }
}

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
fn bench_render(args: &RenderBenchArgs) -> anyhow::Result<()> {
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

/// One stress scene's figures in `bench scaling`.
#[derive(Serialize)]
struct ScalingFigures {
    requested_triangles: u32,
    triangles: usize,
    bvh_build_ms: Spread,
    bvh_bytes: usize,
    bvh_bytes_per_triangle: f64,
    primary_mrays_per_s: Spread,
    /// The same rays, each row's traced as packets of neighbours.
    primary_packet_mrays_per_s: Spread,
    shadow_mrays_per_s: Spread,
    msamples_per_s: Spread,
    us_per_sample: f64,
}

/// Width of the `bench scaling` renders (the quick rig's first train camera scaled to it).
const SCALING_WIDTH: u32 = 128;

/// `cargo xtask bench scaling`: for each requested triangle count, the generated stress scene
/// ([`scenegen::stress`], written to `<out>/stress/` as `.glb` and imported like any scene):
/// BVH build time (medium preset, medians of 3) and the bytes the traversal reads per triangle,
/// primary and shadow Mrays/s (256 px wide, as `bench render`), and path samples/s of the quick
/// settings (16 spp, 4 bounces) at [`SCALING_WIDTH`] px; then the least-squares slope of the
/// time per sample against log10(triangles) and how far that line explains the points, which
/// is what "grows logarithmically" means here. Writes `<out>/bench-scaling.{txt,json}`.
fn bench_scaling(args: &ScalingBenchArgs) -> anyhow::Result<()> {
    use pathtracer::accel::{Accel, AccelParams};
    use pathtracer::dataset_render::{DatasetRenderConfig, Preset};
    use pathtracer::render::{RenderSettings, Renderer};

    let counts: Vec<u32> = args
        .triangles
        .split(',')
        .map(|t| t.trim().parse::<u32>().with_context(|| format!("--triangles: '{t}' is not a count")))
        .collect::<Result<_, _>>()?;
    anyhow::ensure!(counts.iter().all(|&n| (100..=50_000_000).contains(&n)), "--triangles: counts must be 100 to 5e7");
    let out = out_dir(&args.out);
    let stress_dir = out.join("stress");
    std::fs::create_dir_all(&stress_dir).with_context(|| format!("creating {}", stress_dir.display()))?;
    let cpu = CpuInfo::detect();
    let threads = cpu.logical_cpus;
    let mut report = Report::default();
    report.line(format!("cpu: {}", cpu.summary()));
    report.line(format!(
        "bench scaling: profile {}, {threads} threads; generated stress scenes (scenegen::stress: a floor and 16 UV spheres \
         tessellated to the count); BVH = obvhs medium_build, medians of 3 builds; B/tri = bytes of the wide nodes (exact f32 child boxes) and packed \
         triangles per triangle; primary/packet/shadow as in bench render (256 px); path = {SCALING_WIDTH} px, 16 spp, 4 bounces; medians of {RENDER_RUNS}",
        build_profile()
    ));
    report.line(format!(
        "{:>10} {:>9} {:>8} {:>15} {:>14} {:>14} {:>11} {:>10}",
        "triangles", "BVH ms", "B/tri", "primary Mray/s", "packet Mray/s", "shadow Mray/s", "Msample/s", "us/sample"
    ));
    let quick = DatasetRenderConfig::preset(Preset::Quick);
    let settings = RenderSettings {
        spp: quick.spp,
        max_bounces: quick.max_bounces,
        seed: 0,
        environment: quick.environment,
        transparent_background: true,
        environment_map: None,
    };
    let mut rows: Vec<ScalingFigures> = Vec::new();
    for &n in &counts {
        let path = stress_dir.join(format!("stress_{n}.glb"));
        scenegen::stress(n)?.write_glb(&path)?;
        let scene = pathtracer::import::load_gltf(&path, &pathtracer::import::ImportOptions::default())?;
        let params = AccelParams::medium_build();
        let build_ms = Spread::of(
            &(0..3).map(|_| Accel::build(&scene, &params).map(|a| a.build_time().as_secs_f64() * 1e3)).collect::<Result<Vec<_>, _>>()?,
        );
        let triangles = scene.mesh.indices.len();
        let renderer = Renderer::new(scene, &params)?;
        let bytes = renderer.accel().memory_bytes();
        let rig = pathtracer::rig::build_rig(renderer.scene(), &quick.rig_config())?;
        let cam = rig.split(dataset::SplitKind::Train)[0];
        let big = cam.at_width(256);
        let primary = Spread::of(&(0..RENDER_RUNS).map(|_| renderer.primary_ray_throughput(&big).rays_per_second * 1e-6).collect::<Vec<_>>());
        let packet = Spread::of(&(0..RENDER_RUNS).map(|_| renderer.primary_packet_throughput(&big).rays_per_second * 1e-6).collect::<Vec<_>>());
        let shadow = Spread::of(&(0..RENDER_RUNS).map(|_| renderer.shadow_ray_throughput(&big).rays_per_second * 1e-6).collect::<Vec<_>>());
        let cam = cam.at_width(SCALING_WIDTH);
        let rate = Spread::of(
            &(0..RENDER_RUNS)
                .map(|k| {
                    let t = std::time::Instant::now();
                    let out = renderer.render_view(&cam, k as u32, &settings);
                    out.samples as f64 / t.elapsed().as_secs_f64().max(1e-9) * 1e-6
                })
                .collect::<Vec<_>>(),
        );
        let row = ScalingFigures {
            requested_triangles: n,
            triangles,
            bvh_build_ms: build_ms,
            bvh_bytes: bytes,
            bvh_bytes_per_triangle: bytes as f64 / triangles.max(1) as f64,
            primary_mrays_per_s: primary,
            primary_packet_mrays_per_s: packet,
            shadow_mrays_per_s: shadow,
            msamples_per_s: rate,
            us_per_sample: 1.0 / rate.median.max(1e-12),
        };
        report.line(format!(
            "{:>10} {:>9.1} {:>8.0} {:>15.2} {:>14.2} {:>14.2} {:>11.3} {:>10.3}",
            row.triangles,
            row.bvh_build_ms.median,
            row.bvh_bytes_per_triangle,
            row.primary_mrays_per_s.median,
            row.primary_packet_mrays_per_s.median,
            row.shadow_mrays_per_s.median,
            row.msamples_per_s.median,
            row.us_per_sample
        ));
        rows.push(row);
    }
    // Time per sample against log10(triangles): least-squares line and its R².
    let pts: Vec<(f64, f64)> = rows.iter().map(|r| ((r.triangles.max(1) as f64).log10(), r.us_per_sample)).collect();
    let fit = (pts.len() >= 2).then(|| {
        let n = pts.len() as f64;
        let (mx, my) = (pts.iter().map(|p| p.0).sum::<f64>() / n, pts.iter().map(|p| p.1).sum::<f64>() / n);
        let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
        let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
        let syy: f64 = pts.iter().map(|p| (p.1 - my).powi(2)).sum();
        let slope = sxy / sxx.max(1e-12);
        let r2 = if syy > 0.0 { sxy * sxy / (sxx * syy) } else { 1.0 };
        (slope, my - slope * mx, r2)
    });
    if let (Some((slope, icpt, r2)), Some(first), Some(last)) = (fit, rows.first(), rows.last()) {
        let growth = last.us_per_sample / first.us_per_sample;
        let tri_growth = last.triangles as f64 / first.triangles.max(1) as f64;
        report.line(format!(
            "time per sample = {icpt:.3} + {slope:.3} us x log10(triangles) (R² {r2:.3}): {growth:.2}x the time for {tri_growth:.0}x the triangles"
        ));
    }
    let json = serde_json::json!({
        "profile": build_profile(),
        "cpu": cpu,
        "threads": threads,
        "runs": RENDER_RUNS,
        "width": SCALING_WIDTH,
        "spp": settings.spp,
        "max_bounces": settings.max_bounces,
        "rows": rows,
        "fit_us_per_sample_vs_log10_triangles": fit.map(|(slope, intercept, r2)| serde_json::json!({ "slope": slope, "intercept": intercept, "r2": r2 })),
    });
    report.write(&out, "bench-scaling", &json)
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
    /// Seconds of each timed render of the compared image.
    seconds: Vec<f64>,
    /// Camera samples of one render.
    samples: u64,
    /// Per timed render, the mean squared RGB error against the reference, less the
    /// reference's own noise (compared as the median: in a scene with caustics one render in
    /// several catches a firefly of 10^4 in one sample, for either renderer, and the mean of a
    /// few renders is then decided by luck).
    mse: Vec<f64>,
    /// The rays the timed renders traced, all of them together ([`pathtracer::render::ViewOutput::rays`]).
    rays: pathtracer::integrator::RayCounts,
}

impl CmpRun {
    /// Samples per second of each timed render.
    fn rate(&self) -> Spread {
        Spread::of(&self.seconds.iter().map(|s| self.samples as f64 / s.max(1e-9)).collect::<Vec<_>>())
    }

    /// Closest-hit and any-hit rays per camera sample, over the timed renders.
    fn rays_per_sample(&self) -> [f64; 2] {
        let n = (self.samples as f64 * self.seconds.len() as f64).max(1.0);
        [self.rays.closest as f64 / n, self.rays.any_hit as f64 / n]
    }
}

/// Renders our reference (`reference.npy`, RGB, two independent halves of [`CMP_REF_SPP`]; its
/// noise, the mean squared half-difference / 4, goes to `reference_noise.json`) into the
/// export folder and times `runs` renders of `settings` against it.
fn compare_run(
    renderer: &pathtracer::render::Renderer,
    cam: &dataset::Camera,
    settings: &pathtracer::render::RenderSettings,
    export_dir: &std::path::Path,
    runs: usize,
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
    let mut rays = pathtracer::integrator::RayCounts::default();
    for k in 0..runs {
        let t = std::time::Instant::now();
        let out = renderer.render_view(cam, 10 + k as u32, settings);
        times.push(t.elapsed().as_secs_f64());
        samples = out.samples;
        rays = rays + out.rays;
        errors.push(mse(&rgb_of(&out.color), &reference, Some(&keep)) - ref_noise);
    }
    Ok(CmpRun { seconds: times, samples, mse: errors, rays })
}

/// Our figures for one scene and material model, with its export for Mitsuba.
struct OursQuick {
    scene: String,
    /// `glTF BRDF` (as authored) or `Lambert` (every material made exactly Lambertian).
    model: &'static str,
    /// The compared render.
    cmp: CmpRun,
    export: std::path::PathBuf,
    /// Mitsuba's records for this export (`tests/mitsuba/bench.py`), measured right after our
    /// renders of it; `None` without Mitsuba.
    mitsuba: Option<Vec<serde_json::Value>>,
}

/// `tests/mitsuba/bench.py --serve` in a child process: Mitsuba's renders of an export on
/// request, so that each image is timed by both renderers within seconds (it used to run once
/// after all of ours, minutes later, and this machine's speed drifts by several per cent over
/// minutes).
struct MitsubaServer {
    child: std::process::Child,
    stdin: std::process::ChildStdin,
    stdout: std::io::BufReader<std::process::ChildStdout>,
}

impl MitsubaServer {
    fn start(python: &Path, script: &Path) -> anyhow::Result<MitsubaServer> {
        let mut child = std::process::Command::new(python)
            .arg(script)
            .arg("--serve")
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::inherit())
            .spawn()
            .with_context(|| format!("starting {} {}", python.display(), script.display()))?;
        let (Some(stdin), Some(stdout)) = (child.stdin.take(), child.stdout.take()) else {
            anyhow::bail!("{}: no pipes to the child process", script.display());
        };
        let mut server = MitsubaServer { child, stdin, stdout: std::io::BufReader::new(stdout) };
        // Its start-up (imports, the LLVM probe) ends with a first answer; none of our timings
        // may overlap it.
        server.answer()?;
        Ok(server)
    }

    /// Sends `cmd` and returns its answer ([`MitsubaServer::answer`]).
    fn request(&mut self, cmd: serde_json::Value) -> anyhow::Result<serde_json::Value> {
        use std::io::Write;
        writeln!(self.stdin, "{cmd}").and_then(|_| self.stdin.flush()).context("writing to bench.py")?;
        self.answer()
    }

    /// The next line of the child's output that is a JSON object (other lines are skipped);
    /// one with an `error` is an error.
    fn answer(&mut self) -> anyhow::Result<serde_json::Value> {
        use std::io::BufRead;
        let mut line = String::new();
        loop {
            line.clear();
            if self.stdout.read_line(&mut line).context("reading from bench.py")? == 0 {
                anyhow::bail!("bench.py exited ({})", self.child.wait().map_or_else(|e| e.to_string(), |s| s.to_string()));
            }
            if let Ok(v) = serde_json::from_str::<serde_json::Value>(line.trim())
                && v.is_object()
            {
                if let Some(e) = v.get("error") {
                    anyhow::bail!("bench.py: {}", e.as_str().unwrap_or("error"));
                }
                return Ok(v);
            }
        }
    }
}

impl Drop for MitsubaServer {
    fn drop(&mut self) {
        // The child keeps nothing worth a clean exit; killing it also ends one stuck in a render.
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Where the Mitsuba side of the comparison stands.
enum MitsubaState {
    /// Not asked for (`--no-mitsuba`).
    Skipped,
    /// No virtual environment at this path.
    NoPython(PathBuf),
    /// Running (its records are in each [`OursQuick`]).
    Running(MitsubaServer),
    /// Stopped by this error; our figures stand.
    Failed(String),
}

impl MitsubaState {
    /// Sends `cmd` while running; an error stops Mitsuba for the rest of the bench.
    fn request(&mut self, cmd: serde_json::Value) -> Option<serde_json::Value> {
        let MitsubaState::Running(server) = self else { return None };
        match server.request(cmd) {
            Ok(v) => Some(v),
            Err(e) => {
                *self = MitsubaState::Failed(format!("{e:#}"));
                None
            }
        }
    }
}

/// From Mitsuba's records gathered beside our renders (`tests/mitsuba/bench.py --serve`, its
/// `runs` timed renders of each export right after ours), prints the side-by-side table with a
/// line per target of issue 25 (raw samples/s at least Mitsuba's, at least 2x at equal error),
/// and returns the rows for the JSON.
fn bench_render_mitsuba(ours: &[OursQuick], runs: usize, mitsuba: &MitsubaState, report: &mut Report) -> anyhow::Result<Vec<serde_json::Value>> {
    let quick = pathtracer::dataset_render::DatasetRenderConfig::preset(pathtracer::dataset_render::Preset::Quick);
    report.line("");
    let ours_json = |o: &OursQuick| {
        let [closest, any_hit] = o.cmp.rays_per_sample();
        serde_json::json!({
            "samples": o.cmp.samples,
            "seconds": Spread::of(&o.cmp.seconds),
            "samples_per_s": o.cmp.rate(),
            "mse": Spread::of(&o.cmp.mse),
            "rays_per_sample": { "closest": closest, "any_hit": any_hit },
        })
    };
    // Without Mitsuba's figures, ours alone: enough to compare two builds of ours (error ×
    // time is what the equal-error target weighs).
    let only_ours = |report: &mut Report| -> Vec<serde_json::Value> {
        report.line(format!(
            "ours alone ({} px, {} spp, medians of {} renders; MSE against our {}-spp reference as in the comparison):",
            CMP_WIDTH,
            CMP_SPP,
            runs,
            CMP_REF_SPP
        ));
        report.line(format!("{:<10} {:<10} {:>9} {:>11} {:>10} {:>21} {:>10}", "scene", "model", "ours Ms/s", "IQR", "ours MSE", "IQR", "MSE x s"));
        for o in ours {
            let (r, e, t) = (o.cmp.rate().scaled(1e-6), Spread::of(&o.cmp.mse), Spread::of(&o.cmp.seconds));
            report.line(format!(
                "{:<10} {:<10} {:>9.3} {:>11} {:>10.3e} {:>21} {:>10.3e}",
                o.scene,
                o.model,
                r.median,
                r.iqr(2),
                e.median,
                format!("{:.3e}-{:.3e}", e.q1, e.q3),
                e.median * t.median
            ));
        }
        ours.iter().map(|o| serde_json::json!({ "scene": o.scene, "model": o.model, "ours": ours_json(o) })).collect()
    };
    match mitsuba {
        MitsubaState::Skipped => {
            report.line("Mitsuba comparison skipped (--no-mitsuba)");
            return Ok(only_ours(report));
        }
        MitsubaState::NoPython(python) => {
            report.line(format!(
                "Mitsuba comparison skipped: {} not found (python3 -m venv .venv && .venv/bin/pip install -r tests/mitsuba/requirements.txt)",
                python.display()
            ));
            return Ok(only_ours(report));
        }
        MitsubaState::Failed(why) => {
            report.line(format!("Mitsuba comparison failed ({why}); our figures above stand"));
            return Ok(only_ours(report));
        }
        MitsubaState::Running(_) => {}
    }
    let lines: Vec<serde_json::Value> = ours.iter().flat_map(|o| o.mitsuba.iter().flatten().cloned()).collect();
    report.line(format!(
        "vs Mitsuba 3: same camera (the quick rig's first train view) at {CMP_WIDTH} px wide, {CMP_SPP} spp, our max_bounces {} = \
         Mitsuba max_depth {} (Russian roulette from the third vertex on both: rr_depth 2; ours survives with min(1, 2 x max throughput), Mitsuba with min(0.95, max throughput)), environment {:?} as an opaque \
         background (both show it and the emitters the camera sees); medians of {runs} timed renders, Mitsuba's of each image right \
         after ours (Mitsuba's after a first one for JIT compilation; Mitsuba with its default `independent` sampler, with `ldsampler`, its counterpart of our padded \
         Owen-scrambled Sobol' sampler, and with `multijitter`). MSE = mean squared RGB error of one render against our {CMP_REF_SPP}-spp reference, less that \
         reference's own noise, over the pixels but the {}% where that noise is largest (a few unconverged highlight or caustic \
         pixels of the reference would otherwise decide it), median over the timed renders (a rare caustic firefly would \
         decide a mean of a few); Mi bias² = the part of Mitsuba's MSE that more samples would not remove (≈ 0: both \
         converge to the same image). speed = our samples/s over Mitsuba's (medians; range = quartile against quartile). \
         eq-err = (MSE x seconds of Mitsuba) / (MSE x seconds of ours): how much less time we need for the same error (Monte \
         Carlo error falls as 1/time).",
        quick.max_bounces,
        quick.max_bounces + 1,
        quick.environment,
        CMP_EXCLUDED * 100.0
    ));
    report.line(format!(
        "{:<10} {:<9} {:>9} {:>11} {:>10} {:<11} {:<11} {:>8} {:>11} {:>10} {:>8} {:>11} {:>8}  Mitsuba BSDF",
        "scene", "model", "ours Ms/s", "IQR", "ours MSE", "variant", "Mi sampler", "Mi Ms/s", "Mi MSE", "Mi bias²", "speed", "range", "eq-err"
    ));
    let mut rows = Vec::new();
    // The lowest ratio of each kind and its row.
    // With the row's quartile range, so that a verdict within the run-to-run spread says so.
    let mut worst_speed: Option<(f64, [f64; 2], String)> = None;
    let mut worst_eq: Option<(f64, [f64; 2], String)> = None;
    let mut unjudged = std::collections::BTreeSet::new();
    for o in ours {
        let dir = o.export.display().to_string();
        let secs = Spread::of(&o.cmp.seconds);
        let rate = o.cmp.rate();
        let our_mse = Spread::of(&o.cmp.mse);
        let mut mitsuba = Vec::new();
        for t in lines.iter().filter(|t| t["export"].as_str() == Some(dir.as_str())) {
            let text = |k: &str| t[k].as_str().unwrap_or("").to_string();
            let list = |k: &str| t[k].as_array().map(|a| a.iter().filter_map(|v| v.as_f64()).collect::<Vec<_>>()).unwrap_or_default();
            let (mi_secs, mi_err) = (list("times"), list("errors"));
            if mi_secs.is_empty() {
                report.line(format!(
                    "{:<10} {:<9} {:>9.3} {:>11} {:>10.3e} {:<11} {}",
                    o.scene,
                    o.model,
                    rate.median * 1e-6,
                    rate.scaled(1e-6).iqr(2),
                    our_mse.median,
                    text("variant"),
                    text("error")
                ));
                mitsuba.push(t.clone());
                continue;
            }
            let mi_rate = mitsuba_rate(t, &mi_secs);
            let mi_s = Spread::of(&mi_secs);
            let mi_mse = if mi_err.is_empty() { None } else { Some(Spread::of(&mi_err)) };
            let speed = rate.median / mi_rate.median;
            let speed_range = [rate.q1 / mi_rate.q3, rate.q3 / mi_rate.q1];
            let eq = mi_mse.map(|m| (m.median * mi_s.median) / (our_mse.median * secs.median));
            let eq_range = mi_mse.map(|m| [(m.q1 * mi_s.q1) / (our_mse.q3 * secs.q3), (m.q3 * mi_s.q3) / (our_mse.q1 * secs.q1)]);
            let row_name = format!("{} {} vs {}", o.scene, o.model, text("sampler"));
            // The targets are against `llvm_ad_rgb`: a row of another variant (`scalar_rgb`
            // where Dr.Jit found no working LLVM, many times slower) is shown, not judged.
            let judged = text("variant") == TARGET_VARIANT;
            if !judged {
                unjudged.insert(text("variant"));
            }
            if judged && worst_speed.as_ref().is_none_or(|(w, _, _)| speed < *w) {
                worst_speed = Some((speed, speed_range, row_name.clone()));
            }
            if judged
                && let Some(e) = eq
                && let Some(r) = eq_range
                && worst_eq.as_ref().is_none_or(|(w, _, _)| e < *w)
            {
                worst_eq = Some((e, r, row_name));
            }
            report.line(format!(
                "{:<10} {:<9} {:>9.3} {:>11} {:>10.3e} {:<11} {:<11} {:>8.3} {:>11.3e} {:>10.1e} {:>7.2}x {:>11} {:>7.2}x  {}",
                o.scene,
                o.model,
                rate.median * 1e-6,
                rate.scaled(1e-6).iqr(2),
                our_mse.median,
                text("variant"),
                text("sampler"),
                mi_rate.median * 1e-6,
                mi_mse.map_or(f64::NAN, |m| m.median),
                t["bias2"].as_f64().unwrap_or(f64::NAN),
                speed,
                format!("{:.2}-{:.2}", speed_range[0], speed_range[1]),
                eq.unwrap_or(f64::NAN),
                text("bsdf")
            ));
            mitsuba.push(serde_json::json!({
                "variant": text("variant"),
                "sampler": text("sampler"),
                "bsdf": text("bsdf"),
                "first_seconds": t["first_seconds"],
                "seconds": mi_s,
                "samples_per_s": mi_rate,
                "mse": mi_mse,
                "bias2": t["bias2"],
                "ratio": speed,
                "ratio_range": speed_range,
                "equal_error_speedup": eq,
                "equal_error_speedup_range": eq_range,
                "rays_per_sample": t["rays_per_sample"],
            }));
        }
        rows.push(serde_json::json!({ "scene": o.scene, "model": o.model, "ours": ours_json(o), "mitsuba": mitsuba }));
    }
    ray_work_table(report, ours, &lines);
    for line in target_lines(worst_speed, worst_eq, &unjudged) {
        report.line(line);
    }
    Ok(rows)
}

/// How many rays a camera sample traces in each renderer, and the raw speed ratio per ray:
/// ours counted ([`pathtracer::render::ViewOutput::rays`], over the timed renders), Mitsuba's
/// from its `path` integrator's loop replayed on the same scene (`rays_per_sample` of
/// `tests/mitsuba/bench.py`). Our samples trace more rays (a shadow ray to every punctual
/// light, paths kept longer, the light tracer's paths), so samples/s alone compares unequal
/// work; rays/s inside the render does not.
fn ray_work_table(report: &mut Report, ours: &[OursQuick], lines: &[serde_json::Value]) {
    let mut header = false;
    for o in ours {
        let dir = o.export.display().to_string();
        // Mitsuba's `independent` row in the targets' variant: its default sampler, and its
        // fastest.
        let Some(t) = lines.iter().find(|t| {
            t["export"].as_str() == Some(dir.as_str()) && t["sampler"].as_str() == Some("independent") && t["variant"].as_str() == Some(TARGET_VARIANT)
        }) else {
            continue;
        };
        let (Some(mc), Some(ms)) = (t["rays_per_sample"]["closest"].as_f64(), t["rays_per_sample"]["shadow"].as_f64()) else { continue };
        let mi_times: Vec<f64> = t["times"].as_array().map(|a| a.iter().filter_map(|v| v.as_f64()).collect()).unwrap_or_default();
        if mi_times.is_empty() {
            continue;
        }
        let mi_rate = mitsuba_rate(t, &mi_times);
        let [oc, oa] = o.cmp.rays_per_sample();
        let speed = o.cmp.rate().median / mi_rate.median;
        let work = (oc + oa) / (mc + ms).max(1e-9);
        if !header {
            report.line(
                "rays per camera sample, ours counted (closest-hit + any-hit queries of the timed renders: path samples, ground truth, \
                 emitter-edge pixels, light tracer) and Mitsuba's from its `path` integrator's loop replayed on the same scene (tests/mitsuba/bench.py \
                 ray_counts: closest hits + shadow rays); speed = our samples/s over Mitsuba's `independent` (as above); per ray = speed x our rays \
                 per sample / Mitsuba's: the ratio of rays traced per second within the render",
            );
            report.line(format!(
                "{:<10} {:<9} {:>11} {:>9} {:>9} {:>11} {:>9} {:>9} {:>9} {:>8} {:>8}",
                "scene", "model", "ours closest", "any-hit", "total", "Mi closest", "shadow", "total", "ours/Mi", "speed", "per ray"
            ));
            header = true;
        }
        report.line(format!(
            "{:<10} {:<9} {:>11.3} {:>9.3} {:>9.3} {:>11.3} {:>9.3} {:>9.3} {:>8.2}x {:>7.2}x {:>7.2}x",
            o.scene,
            o.model,
            oc,
            oa,
            oc + oa,
            mc,
            ms,
            mc + ms,
            work,
            speed,
            speed * work
        ));
    }
}

/// Samples per second of each of a Mitsuba record's timed renders (`seconds`, its `times`).
fn mitsuba_rate(t: &serde_json::Value, seconds: &[f64]) -> Spread {
    let samples = t["samples"].as_f64().unwrap_or(0.0);
    Spread::of(&seconds.iter().map(|s| samples / s.max(1e-9)).collect::<Vec<_>>())
}

/// The Mitsuba variant the targets are set against.
const TARGET_VARIANT: &str = "llvm_ad_rgb";

/// One line per target: its verdict from the lowest judged row (ratio, quartile range, row),
/// or why it was not judged (no row of [`TARGET_VARIANT`]; `unjudged` holds the variants the
/// rows ran instead).
fn target_lines(
    worst_speed: Option<(f64, [f64; 2], String)>,
    worst_eq: Option<(f64, [f64; 2], String)>,
    unjudged: &std::collections::BTreeSet<String>,
) -> Vec<String> {
    let mut out = Vec::new();
    for (worst, target, what) in [(worst_speed, 1.0, "raw samples/s >= 1.0x Mitsuba"), (worst_eq, 2.0, ">= 2x at equal error")] {
        match worst {
            Some((w, r, row)) => out.push(format!(
                "target {what} on every row: {} (lowest {w:.2}x, quartile range {:.2}-{:.2}x, {row}){}",
                verdict(w, r, target),
                r[0],
                r[1],
                if unjudged.is_empty() { String::new() } else { format!("; rows of {} not judged", unjudged.iter().cloned().collect::<Vec<_>>().join(", ")) }
            )),
            None if !unjudged.is_empty() => out.push(format!(
                "target {what} on every row: not judged: Mitsuba ran {} here, and the targets are against {TARGET_VARIANT} \
                 (Dr.Jit needs a working LLVM: apt-get install libllvm19)",
                unjudged.iter().cloned().collect::<Vec<_>>().join(", ")
            )),
            None => {}
        }
    }
    out
}

/// Whether a ratio meets `target`, from its median and its quartile range (our quartile
/// against Mitsuba's, [`bench_render_mitsuba`]): a median on either side of the target whose
/// range straddles it says so, since another run could read the other way.
fn verdict(median: f64, range: [f64; 2], target: f64) -> &'static str {
    match (median >= target, range[0] >= target, range[1] >= target) {
        (true, true, _) => "met",
        (true, false, _) => "met at the median, within the run-to-run spread",
        (false, _, true) => "missed at the median, within the run-to-run spread",
        (false, _, false) => "missed",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stand-in for `bench.py --serve`: a line of noise, the ready answer, then per command
    /// `measure` → records, `fail` → an error answer, anything else → exit.
    const FAKE_SERVER: &str = r#"
import json, sys
print("some library's banner")
print(json.dumps({"ok": True, "variant": "fake"}), flush=True)
for line in sys.stdin:
    cmd = json.loads(line)
    if cmd["cmd"] == "measure":
        print(json.dumps({"records": [{"export": cmd["export"], "runs": cmd["runs"]}]}), flush=True)
    elif cmd["cmd"] == "fail":
        print(json.dumps({"error": "boom"}), flush=True)
    else:
        sys.exit(3)
"#;

    #[test]
    fn targets_are_judged_only_against_llvm_ad_rgb() {
        let none = std::collections::BTreeSet::new();
        let scalar: std::collections::BTreeSet<String> = ["scalar_rgb".to_string()].into();
        let worst = Some((1.5, [1.4, 1.6], "row".to_string()));
        // Judged rows: a verdict each.
        let lines = target_lines(worst.clone(), Some((3.0, [2.5, 3.5], "row".into())), &none);
        assert!(lines[0].starts_with("target raw samples/s >= 1.0x Mitsuba on every row: met (lowest 1.50x"), "{lines:?}");
        assert!(lines[1].contains(": met (lowest 3.00x"), "{lines:?}");
        // Only scalar_rgb rows (no working LLVM): no verdict, and why.
        let lines = target_lines(None, None, &scalar);
        assert_eq!(lines.len(), 2);
        assert!(lines.iter().all(|l| l.contains("not judged: Mitsuba ran scalar_rgb") && !l.contains(" met")), "{lines:?}");
        // Both kinds: the verdict from the judged rows, the others named.
        let lines = target_lines(worst, None, &scalar);
        assert!(lines[0].contains("met (lowest 1.50x") && lines[0].ends_with("rows of scalar_rgb not judged"), "{lines:?}");
    }

    #[test]
    fn the_ray_table_weighs_the_speed_ratio_by_the_rays_each_sample_traces() {
        // Ours: 100 samples in 1 s with 300 closest-hit and 100 any-hit rays (4 per sample);
        // Mitsuba: 100 samples in 0.5 s with 2 rays per sample. Half the samples/s, twice the
        // rays per sample: the same rays per second.
        let ours = OursQuick {
            scene: "s".into(),
            model: "Lambert",
            cmp: CmpRun { seconds: vec![1.0], samples: 100, mse: vec![0.0], rays: pathtracer::integrator::RayCounts { closest: 300, any_hit: 100 } },
            export: "dir".into(),
            mitsuba: None,
        };
        let mi = serde_json::json!({ "export": "dir", "sampler": "independent", "variant": "llvm_ad_rgb", "samples": 100, "times": [0.5], "rays_per_sample": { "closest": 1.5, "shadow": 0.5 } });
        let mut report = Report(String::new());
        ray_work_table(&mut report, std::slice::from_ref(&ours), &[mi]);
        let row = report.0.lines().last().unwrap();
        let cols: Vec<&str> = row.split_whitespace().collect();
        assert_eq!(&cols[2..], ["3.000", "1.000", "4.000", "1.500", "0.500", "2.000", "2.00x", "0.50x", "1.00x"], "{row}");
        // No row without Mitsuba's counts.
        let mut report = Report(String::new());
        ray_work_table(&mut report, std::slice::from_ref(&ours), &[serde_json::json!({ "export": "dir", "sampler": "independent", "variant": "llvm_ad_rgb", "samples": 100, "times": [0.5] })]);
        assert!(report.0.is_empty());
        // Nor against another variant.
        let mut report = Report(String::new());
        let scalar = serde_json::json!({ "export": "dir", "sampler": "independent", "variant": "scalar_rgb", "samples": 100, "times": [0.5], "rays_per_sample": { "closest": 1.5, "shadow": 0.5 } });
        ray_work_table(&mut report, &[ours], &[scalar]);
        assert!(report.0.is_empty());
    }

    #[test]
    fn the_mitsuba_server_answers_requests_and_stops_at_its_first_error() {
        let dir = tempfile::tempdir().unwrap();
        let script = dir.path().join("fake.py");
        std::fs::write(&script, FAKE_SERVER).unwrap();
        let mut state = MitsubaState::Running(MitsubaServer::start(Path::new("python3"), &script).unwrap());
        let answer = state.request(serde_json::json!({ "cmd": "measure", "export": "x", "runs": 3 })).unwrap();
        assert_eq!(answer["records"][0]["runs"], 3);
        assert_eq!(answer["records"][0]["export"], "x");
        // An error answer stops Mitsuba for the rest of the bench, with the reason.
        assert!(state.request(serde_json::json!({ "cmd": "fail", "export": "x" })).is_none());
        let MitsubaState::Failed(why) = &state else { panic!("not failed after an error answer") };
        assert!(why.contains("boom"), "{why}");
        assert!(state.request(serde_json::json!({ "cmd": "measure", "export": "x", "runs": 1 })).is_none());
        // A child that exits is an error, not a hang.
        let mut server = MitsubaServer::start(Path::new("python3"), &script).unwrap();
        let err = server.request(serde_json::json!({ "cmd": "quit", "export": "x" })).unwrap_err();
        assert!(format!("{err:#}").contains("exited"), "{err:#}");
    }

    #[test]
    fn a_target_verdict_says_when_the_spread_straddles_the_target() {
        assert_eq!(verdict(2.3, [2.1, 2.5], 2.0), "met");
        assert_eq!(verdict(2.04, [1.9, 2.2], 2.0), "met at the median, within the run-to-run spread");
        assert_eq!(verdict(1.96, [1.85, 2.05], 2.0), "missed at the median, within the run-to-run spread");
        assert_eq!(verdict(0.22, [0.21, 0.23], 1.0), "missed");
        // Exactly on the target counts as met.
        assert_eq!(verdict(2.0, [2.0, 2.1], 2.0), "met");
    }

    #[test]
    fn the_cpu_is_read_from_the_first_processor_of_proc_cpuinfo() {
        let text = "processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 25\nmodel\t\t: 17\nmodel name\t: AMD EPYC\n\
                    stepping\t: 1\ncache size\t: 1024 KB\nflags\t\t: fpu avx2\n\nprocessor\t: 1\nvendor_id\t: Other\nmodel\t\t: 99\n";
        let cpu = CpuInfo::parse(text, 2, "avx512f");
        assert_eq!((cpu.model_name.as_str(), cpu.vendor.as_str()), ("AMD EPYC", "AuthenticAMD"));
        assert_eq!((cpu.family, cpu.model, cpu.stepping), (Some(25), Some(17), Some(1)));
        assert_eq!(cpu.cache, "1024 KB");
        assert_eq!(cpu.summary(), "AMD EPYC (AuthenticAMD family 25 model 17 stepping 1, cache 1024 KB, 2 CPUs, avx512f)");
        // No /proc/cpuinfo (another OS): named as unknown, not an error.
        let none = CpuInfo::parse("", 1, "");
        assert_eq!((none.model_name.as_str(), none.family), ("unknown", None));
        assert_eq!(none.summary(), "unknown (unknown vendor family ? model ? stepping ?, cache ?, 1 CPUs, no x86 SIMD)");
    }

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
