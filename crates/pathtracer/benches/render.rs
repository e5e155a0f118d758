//! Path-tracer throughput without the rest of the workspace: the figures of
//! `cargo xtask bench render` (primary rays at 256 px wide, path samples at the quick preset:
//! 64×64, 16 spp, 4 bounces) for every scene in `scenes/`, so that an old commit can be
//! compared side by side from a worktree that builds only this crate.
//!
//! ```text
//! cargo bench -p pathtracer --bench render [-- SCENE…] [--runs N] [--seconds S] [--accel PRESET] [--spp N] [--width W]
//! ```
//! `--spp N` and `--width W` change the quick view's samples per pixel (16) and width (64, the
//! camera scaled): `--spp 64 --width 128` is the view `cargo xtask bench render` compares with
//! Mitsuba, where a pixel's 64 camera rays are traced as packets (the quick view's 16 are not).
//! `--seconds S` renders the first scene's quick view repeatedly for `S` seconds (a steady
//! load for `perf record`) instead of printing the table; `--primary` does the same with
//! primary rays; `--hash` prints a hash of each scene's quick view (colour, depth, normal
//! bits) to check that a change leaves images bit-identical; `--rays FILE` (repeatable) times
//! the first scene's one-ray closest-hit and any-hit queries and the packet closest-hit query
//! on the rays in FILE (little-endian `f32` records of origin, direction and `t_max`, in the
//! scene's local frame: e.g. rays written by Mitsuba for the same exported scene), 15 times
//! each on all threads, and prints the median Mray/s of each.

use pathtracer::accel::AccelParams;
use pathtracer::dataset_render::{DatasetRenderConfig, Preset};
use pathtracer::render::{RenderSettings, Renderer};
use std::path::PathBuf;

/// CPU time of this process (all threads, user + system) in seconds, from `/proc/self/stat`
/// (clock ticks of 1/100 s); 0 where unavailable.
fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else { return 0.0 };
    let Some(rest) = stat.rsplit(')').next() else { return 0.0 };
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |k: usize| f.get(k).and_then(|v| v.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut names = Vec::new();
    let mut runs = 5usize;
    let mut seconds: Option<f64> = None;
    let mut primary_only = false;
    let mut hash_only = false;
    let mut ray_files: Vec<String> = Vec::new();
    let mut spp: Option<u32> = None;
    let mut width: Option<u32> = None;
    let mut accel = AccelParams::medium_build();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--bench" => {}
            "--runs" => runs = args.next().ok_or("--runs N")?.parse()?,
            "--seconds" => seconds = Some(args.next().ok_or("--seconds S")?.parse()?),
            "--primary" => primary_only = true,
            "--hash" => hash_only = true,
            "--rays" => ray_files.push(args.next().ok_or("--rays FILE")?),
            "--spp" => spp = Some(args.next().ok_or("--spp N")?.parse()?),
            "--width" => width = Some(args.next().ok_or("--width W")?.parse()?),
            "--accel" => {
                accel = match args.next().as_deref() {
                    Some("fastest") => AccelParams::fastest_build(),
                    Some("fast") => AccelParams::fast_build(),
                    Some("medium") => AccelParams::medium_build(),
                    Some("slow") => AccelParams::slow_build(),
                    _ => return Err("--accel fastest|fast|medium|slow".into()),
                }
            }
            _ => names.push(a),
        }
    }
    if spp == Some(0) || width == Some(0) {
        return Err("--spp and --width must be at least 1".into());
    }
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let mut scenes: Vec<PathBuf> = std::fs::read_dir(&dir)?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "gltf"))
        .filter(|p| names.is_empty() || names.iter().any(|n| p.file_stem().is_some_and(|s| s == n.as_str())))
        .collect();
    scenes.sort();
    println!(
        "{:<12} {:>15} {:>16} {:>20}   ({} threads, medians of {runs}; per CPU-s: quick samples over the process's CPU time for 1.5 s of renders)",
        "scene",
        "primary Mray/s",
        "quick Msample/s",
        "quick Msample/CPU-s",
        rayon::current_num_threads()
    );
    for path in scenes {
        let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        let scene = pathtracer::import::load_gltf(&path, &pathtracer::import::ImportOptions::default())?;
        let renderer = Renderer::new(scene, &accel)?;
        let quick = DatasetRenderConfig::preset(Preset::Quick);
        let rig = pathtracer::rig::build_rig(renderer.scene(), &quick.rig_config())?;
        let cam = rig.split(dataset::SplitKind::Train)[0];
        let cam = match width {
            Some(w) => cam.at_width(w),
            None => cam,
        };
        let mut settings = RenderSettings::preview(0);
        settings.spp = spp.unwrap_or(quick.spp);
        settings.max_bounces = quick.max_bounces;
        settings.environment = quick.environment;
        let big = cam.at_width(256);
        if !ray_files.is_empty() {
            for f in &ray_files {
                ray_file_throughput(&renderer, &name, f)?;
            }
            return Ok(());
        }
        if hash_only {
            // FNV-1a over the bits of the quick view's colour and ground truth: equal hashes
            // mean bit-identical images.
            let out = renderer.render_view(&cam, 0, &settings);
            let mut h = 0xcbf2_9ce4_8422_2325u64;
            for v in out.color.data.iter().chain(&out.ground_truth.depth).chain(&out.ground_truth.normal) {
                h = (h ^ v.to_bits() as u64).wrapping_mul(0x100_0000_01b3);
            }
            println!("{name}: {h:016x}");
            continue;
        }
        if let (Some(s), true) = (seconds, primary_only) {
            let t = std::time::Instant::now();
            let mut rays = 0u64;
            while t.elapsed().as_secs_f64() < s {
                rays += renderer.primary_ray_throughput(&big).rays;
            }
            println!("{name}: {:.3} Mray/s over {:.1} s", rays as f64 * 1e-6 / t.elapsed().as_secs_f64(), t.elapsed().as_secs_f64());
            return Ok(());
        }
        if let Some(s) = seconds {
            let t = std::time::Instant::now();
            let c = cpu_seconds();
            let mut samples = 0u64;
            let mut k = 0;
            while t.elapsed().as_secs_f64() < s {
                samples += renderer.render_view(&cam, k, &settings).samples;
                k += 1;
            }
            println!(
                "{name}: {:.3} Msample/s, {:.3} Msample/CPU-s over {:.1} s",
                samples as f64 * 1e-6 / t.elapsed().as_secs_f64(),
                samples as f64 * 1e-6 / (cpu_seconds() - c).max(1e-9),
                t.elapsed().as_secs_f64()
            );
            return Ok(());
        }
        let primary = median((0..runs).map(|_| renderer.primary_ray_throughput(&big).rays_per_second).collect());
        let quick_rate = median(
            (0..runs)
                .map(|k| {
                    let t = std::time::Instant::now();
                    let out = renderer.render_view(&cam, k as u32, &settings);
                    out.samples as f64 / t.elapsed().as_secs_f64().max(1e-9)
                })
                .collect(),
        );
        let (t, c) = (std::time::Instant::now(), cpu_seconds());
        let mut samples = 0u64;
        let mut k = 0;
        while t.elapsed().as_secs_f64() < 1.5 {
            samples += renderer.render_view(&cam, k, &settings).samples;
            k += 1;
        }
        let per_cpu = samples as f64 / (cpu_seconds() - c).max(1e-9);
        println!("{:<12} {:>15.2} {:>16.3} {:>20.3}", name, primary * 1e-6, quick_rate * 1e-6, per_cpu * 1e-6);
    }
    Ok(())
}

/// `--rays FILE`: the one-ray and packet queries' throughput on the rays in `file`.
fn ray_file_throughput(renderer: &Renderer, name: &str, file: &str) -> Result<(), Box<dyn std::error::Error>> {
    use pathtracer::render::RayQuery;
    let rays = pathtracer::render::read_ray_file(std::path::Path::new(file))?;
    let time = |q: RayQuery| {
        let runs: Vec<_> = (0..15).map(|_| renderer.ray_query_throughput(&rays, q)).collect();
        (median(runs.iter().map(|r| r.rays_per_second * 1e-6).collect()), runs[0].hits)
    };
    let (c, hc) = time(RayQuery::Closest);
    let (o, ho) = time(RayQuery::AnyHit);
    let (p, hp) = time(RayQuery::ClosestPackets);
    println!("{name} {file}: {} rays, closest {c:.2} Mray/s ({hc} hits), occluded {o:.2} Mray/s ({ho}), packets {p:.2} Mray/s ({hp})", rays.len());
    Ok(())
}
