//! `bench render`'s side-by-side comparison with Mitsuba 3: our renders of each scene timed
//! against our reference, Mitsuba's renders of the same export through
//! `tests/mitsuba/bench.py --serve`, and the table of speed and speed at equal error.

use super::figures::{Report, Spread};
use anyhow::Context;
use std::path::{Path, PathBuf};

/// Width of the image rendered by both renderers for the side-by-side comparison (the quick
/// rig's first train camera scaled to it): large enough that Mitsuba's per-render overhead
/// (Python, kernel launch) is a small part of its time.
pub(super) const CMP_WIDTH: u32 = 128;
/// Samples per pixel of the compared renders.
pub(super) const CMP_SPP: u32 = 64;
/// Samples per pixel of our reference image (two independent halves), against which both
/// renderers' errors are measured.
pub(super) const CMP_REF_SPP: u32 = 1024;

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
pub(super) const CMP_EXCLUDED: f64 = 0.001;

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
pub(super) struct CmpRun {
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
pub(super) fn compare_run(
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
pub(super) struct OursQuick {
    pub(super) scene: String,
    /// `glTF BRDF` (as authored) or `Lambert` (every material made exactly Lambertian).
    pub(super) model: &'static str,
    /// The compared render.
    pub(super) cmp: CmpRun,
    pub(super) export: std::path::PathBuf,
    /// Mitsuba's records for this export (`tests/mitsuba/bench.py`), measured right after our
    /// renders of it; `None` without Mitsuba.
    pub(super) mitsuba: Option<Vec<serde_json::Value>>,
}

/// `tests/mitsuba/bench.py --serve` in a child process: Mitsuba's renders of an export on
/// request, so that each image is timed by both renderers within seconds (it used to run once
/// after all of ours, minutes later, and this machine's speed drifts by several per cent over
/// minutes).
pub(super) struct MitsubaServer {
    child: std::process::Child,
    stdin: std::process::ChildStdin,
    stdout: std::io::BufReader<std::process::ChildStdout>,
}

impl MitsubaServer {
    pub(super) fn start(python: &Path, script: &Path) -> anyhow::Result<MitsubaServer> {
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
pub(super) enum MitsubaState {
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
    pub(super) fn request(&mut self, cmd: serde_json::Value) -> Option<serde_json::Value> {
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
pub(super) fn bench_render_mitsuba(ours: &[OursQuick], runs: usize, mitsuba: &MitsubaState, report: &mut Report) -> anyhow::Result<Vec<serde_json::Value>> {
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
