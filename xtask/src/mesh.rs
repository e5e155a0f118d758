//! `cargo xtask mesh`: argument parsing, progress and printing; extraction and metrics are in
//! `eval::mesh_extract` and `eval::mesh_eval`.

use anyhow::Context;
use eval::mesh_eval::{MeshBlock, compare_with_reference, scene_reference};
use eval::mesh_extract::{ExtractOptions, MAX_RESOLUTION, MeshRecord, extract_mesh, spread_cameras};
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `mesh`.
#[derive(clap::Args)]
pub struct MeshArgs {
    /// Run folder (from `cargo xtask train`).
    pub run: PathBuf,
    /// The PLY file to write (binary); a sidecar `<name>.json` records the level and why.
    #[arg(long)]
    pub out: PathBuf,
    /// Grid cells along the longest side of the scene box (1..=2048).
    #[arg(long, default_value_t = 256)]
    pub resolution: usize,
    /// Density level of the surface, 1/m (default: chosen from the data, see the sidecar).
    #[arg(long)]
    pub level: Option<f32>,
    /// Write no vertex colours.
    #[arg(long)]
    pub no_colors: bool,
    /// Skip the metrics against the scene's triangles (taken by default when the scene the
    /// dataset was rendered from is found).
    #[arg(long)]
    pub no_metrics: bool,
    /// The scene the dataset was rendered from: a file, or the name of a scene in `scenes/`
    /// (default: found through its render_config.json).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// Points sampled on each mesh for the metrics.
    #[arg(long, default_value_t = 100_000)]
    pub samples: usize,
    /// Read dataset files (transforms `file_path`, `gt_file_path`, `exr_file_path`) and the
    /// scene's glTF buffers and images that lie outside their folders (`../`, an absolute path,
    /// a symbolic link leading out); refused by default.
    #[arg(long)]
    pub allow_outside: bool,
}

/// The sidecar of `out`: `mesh.ply` → `mesh.json`.
pub fn sidecar(out: &std::path::Path) -> PathBuf {
    out.with_extension("json")
}

/// Extracts the mesh, writes it and its sidecar, and prints the metrics when the scene is found.
pub fn run(args: MeshArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        (1..=MAX_RESOLUTION).contains(&args.resolution),
        "--resolution must be 1..={MAX_RESOLUTION}, not {}",
        args.resolution
    );
    if let Some(l) = args.level {
        anyhow::ensure!(l > 0.0 && l.is_finite(), "--level must be a positive density (1/m), not {l}");
    }
    anyhow::ensure!(args.samples > 0, "--samples must be at least 1");
    anyhow::ensure!(sidecar(&args.out) != args.out, "--out {} would be overwritten by its own sidecar; give it the .ply extension", args.out.display());
    let scene = crate::render::resolve_scene_option(args.scene.as_deref())?;
    crate::guard::check_output_files("--out", &args.out, &[args.out.clone(), sidecar(&args.out)], scene.as_slice())?;
    let _lock = crate::lock_folder(args.out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(std::path::Path::new(".")))?;
    let start = Instant::now();
    let model = nerf::render::RunModel::load(&args.run).with_context(|| format!("loading the run {}", args.run.display()))?;
    let dataset = dataset::Dataset::load_with(model.dataset_dir(), &dataset::LoadOptions { allow_outside: args.allow_outside }).with_context(|| format!("loading the run's dataset {}", model.dataset_dir().display()))?;
    remove_stale_temporaries(&args.out)?;
    let opts = ExtractOptions { level: args.level, colors: !args.no_colors, ..ExtractOptions::at_resolution(args.resolution) };
    let cameras = spread_cameras(&dataset.train, opts.level_views);
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg:>8} {pos}/{len} {bar:30} {elapsed}").unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let extracted = extract_mesh(&model, &cameras, &opts, &mut |stage, done, total| {
        bar.set_message(stage.to_string());
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })?;
    bar.finish_and_clear();
    let seconds = start.elapsed().as_secs_f64();
    let record = MeshRecord::new(&args.run, &model, &extracted, args.resolution, seconds);
    println!(
        "level {:.4} /m ({}): {}",
        extracted.level.level, extracted.level.source, extracted.level.reason
    );
    println!(
        "mesh: {} vertices, {} triangles, area {:.4} m² from a {}x{}x{} grid ({} points evaluated, {} skipped as empty) in {:.1} s",
        record.vertices, record.triangles, record.area, record.grid_dims[0], record.grid_dims[1], record.grid_dims[2], record.evaluated_points, record.skipped_points, seconds
    );
    let metrics = if args.no_metrics {
        None
    } else {
        let import = pathtracer::import::ImportOptions { allow_outside: args.allow_outside, ..Default::default() };
        match scene_reference(&dataset, scene.as_deref(), &import)? {
            Ok(reference) => {
                let (m, fraction) = compare_with_reference(&extracted.mesh, &reference, args.samples)?;
                Some(MeshBlock {
                    metrics: m,
                    predicted_visible_area_fraction: fraction,
                    reference: reference.info,
                    resolution: Some(args.resolution),
                    level: Some(extracted.level.clone()),
                    mesh_file: Some(args.out.display().to_string()),
                    picture: None,
                    input: None,
                })
            }
            Err(why) => {
                println!("no metrics: {why}");
                None
            }
        }
    };
    if let Some(b) = &metrics {
        print_metrics(b);
    }
    extracted.mesh.write_ply(&args.out)?;
    let json = serde_json::json!({ "mesh": record, "metrics": metrics });
    let path = sidecar(&args.out);
    let mut text = serde_json::to_string_pretty(&json)?;
    text.push('\n');
    dataset::io::atomic_write(&path, text.as_bytes()).with_context(|| format!("writing {}", path.display()))?;
    println!("wrote {} and {}", args.out.display(), path.display());
    Ok(())
}

/// Removes the temporaries of `out` and its sidecar that a killed `mesh` left beside them.
fn remove_stale_temporaries(out: &std::path::Path) -> anyhow::Result<()> {
    let names: Vec<String> = [out.to_path_buf(), sidecar(out)].iter().filter_map(|p| Some(p.file_name()?.to_string_lossy().into_owned())).collect();
    let dir = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(std::path::Path::new("."));
    dataset::io::remove_stale_temporaries(dir, |f| names.iter().any(|n| n == f))?;
    Ok(())
}

/// Prints a mesh block's metrics as one table.
pub fn print_metrics(b: &MeshBlock) {
    let m = &b.metrics;
    println!(
        "reference: {} ({} of {} triangles seen by {} cameras, {:.1} % of the area); the cameras see {:.1} % of the mesh's area, which is measured",
        b.reference.scene,
        b.reference.visible_triangles,
        b.reference.triangles,
        b.reference.cameras,
        100.0 * b.reference.visible_area_fraction,
        100.0 * b.predicted_visible_area_fraction
    );
    let nc = m.normal_consistency.map_or("absent".to_string(), |v| format!("{v:.3}"));
    let f: Vec<String> = m.f_scores.iter().map(|f| format!("F@{:.1}% {:.3} (P {:.3} R {:.3})", 100.0 * f.fraction, f.f_score, f.precision, f.recall)).collect();
    println!(
        "accuracy {:.4} m, completeness {:.4} m, Chamfer-L1 {:.4} m (medians {:.4} / {:.4}), normal consistency {}, {}; diagonal {:.3} m, {} samples per mesh",
        m.accuracy, m.completeness, m.chamfer_l1, m.accuracy_median, m.completeness_median, nc, f.join(", "), m.diagonal, m.samples
    );
}
