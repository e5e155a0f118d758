//! `cargo xtask bench scaling`: the path tracer against the triangle count, on generated
//! stress scenes.

use super::cpu::{CpuInfo, build_profile};
use super::figures::{RENDER_RUNS, Report, Spread, out_dir};
use anyhow::Context;
use serde::Serialize;
use std::path::PathBuf;

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
pub(super) fn bench_scaling(args: &ScalingBenchArgs) -> anyhow::Result<()> {
    use pathtracer::accel::{Accel, AccelParams};
    use pathtracer::dataset_render::{DatasetRenderConfig, Preset};
    use pathtracer::render::Renderer;

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
    let settings = super::render::quick_render_settings(&quick);
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
