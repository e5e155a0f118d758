//! `cargo xtask score`: argument parsing and printing for scoring another tool's predictions;
//! the work is in `eval::score`.

use anyhow::Context;
use std::path::PathBuf;

/// Arguments of `score`.
#[derive(clap::Args)]
pub struct ScoreArgs {
    /// The dataset folder the method was trained on (from `cargo xtask render`).
    pub dataset: PathBuf,
    /// The folder of the method's predictions: nerfstudio's `ns-render dataset --output-path`,
    /// instant-ngp's `--screenshot_dir`, or images named by the views (`r_0.png`, …).
    pub predictions: PathBuf,
    /// The method's name in the report and in `compare`.
    #[arg(long)]
    pub method: String,
    /// Where eval.json, report.json, report.md and the grids go (outside the dataset and the
    /// predictions).
    #[arg(long)]
    pub out: PathBuf,
    /// Split the predictions are for: train, val or test.
    #[arg(long, default_value = "test")]
    pub split: String,
    /// Training seconds, as you measured them (places the method in compare's plot).
    #[arg(long)]
    pub train_seconds: Option<f64>,
    /// Hardware it trained on, in words (recorded as given).
    #[arg(long)]
    pub hardware: Option<String>,
    /// The predictions are at 1/D of the dataset's resolution; scored at that resolution.
    #[arg(long)]
    pub downscale: Option<u32>,
    /// What depth files hold: z (along the camera's -Z axis) or distance (along the ray).
    /// Default: the layout's convention (nerfstudio: distance; images, instant-ngp: z).
    #[arg(long, value_parser = ["z", "distance"])]
    pub depth_kind: Option<String>,
    /// Metres per unit of the depth files (needed for 16-bit PNG depth; replaces the layout's
    /// unit).
    #[arg(long)]
    pub depth_scale: Option<f64>,
    /// Score the views that have predictions; record the missing ones in eval.json.
    #[arg(long)]
    pub allow_missing: bool,
    /// Background the ground truth and predictions with alpha are composited on: white,
    /// black, or R,G,B in [0, 1] (display values). A prediction without alpha must have been
    /// rendered on it.
    #[arg(long, default_value = "white")]
    pub background: String,
    /// The scene the dataset was rendered from, for exact ground truth at even downscales
    /// (default: found through the dataset's render_config.json).
    #[arg(long)]
    pub scene: Option<PathBuf>,
    /// nerfstudio's dataparser_transforms.json (default: looked for in the predictions folder).
    #[arg(long)]
    pub dataparser_transforms: Option<PathBuf>,
    /// Number of views that get a picture grid in the report.
    #[arg(long, default_value_t = 3)]
    pub grids: usize,
    /// The method's mesh or point cloud (PLY or OBJ, e.g. from `ns-export tsdf` or
    /// instant-ngp's `--save_mesh`), scored against the scene like `eval`'s mesh.
    #[arg(long)]
    pub geometry: Option<PathBuf>,
    /// The frame of --geometry: tool (undo the tool's frame as found beside the predictions:
    /// nerfstudio's dataparser_transforms.json, instant-ngp's scale and offset) or dataset.
    #[arg(long, value_parser = ["tool", "dataset"], default_value = "tool", conflicts_with = "to_dataset")]
    pub geometry_frame: String,
    /// A row-major 4x4 affine from --geometry's frame to the dataset's: 16 numbers (or the top
    /// 12) separated by spaces or commas, or a file holding them.
    #[arg(long, allow_hyphen_values = true)]
    pub to_dataset: Option<String>,
    /// Points sampled on each mesh for the geometry metrics (as `eval`).
    #[arg(long, default_value_t = eval::mesh_eval::MeshEvalOptions::standard().samples)]
    pub geometry_samples: usize,
    /// Admit dataset images and scene files outside their folders (symlinks, absolute paths).
    #[arg(long)]
    pub allow_outside: bool,
}

/// Parses `--background`.
fn parse_background(s: &str) -> anyhow::Result<[f32; 3]> {
    match s {
        "white" => return Ok([1.0; 3]),
        "black" => return Ok([0.0; 3]),
        _ => {}
    }
    let v: Vec<f32> = s.split(',').map(|c| c.trim().parse::<f32>()).collect::<Result<_, _>>().map_err(|_| anyhow::anyhow!("--background {s}: white, black or R,G,B"))?;
    match v[..] {
        [r, g, b] if v.iter().all(|c| (0.0..=1.0).contains(c)) => Ok([r, g, b]),
        _ => anyhow::bail!("--background {s}: white, black or three numbers R,G,B in [0, 1]"),
    }
}

/// Scores another tool's predictions and prints the summary.
pub fn run(args: ScoreArgs) -> anyhow::Result<()> {
    crate::check_out_folder("--out", &args.out)?;
    crate::guard::check_output_folder("--out", &args.out, false)?;
    let (out, preds) = (crate::guard::resolve(&args.out), crate::guard::resolve(&args.predictions));
    if out.starts_with(&preds) {
        anyhow::bail!("--out {}: lies in the predictions folder {}, whose files it would be mixed with; write the report elsewhere", args.out.display(), args.predictions.display());
    }
    crate::guard::check_output_files("--out", &args.out.join("eval.json"), &[args.out.join("eval.json"), args.out.join("report.json"), args.out.join("report.md")], &[])?;
    let split = crate::evaluate::parse_split(&args.split)?;
    let depth_kind = args.depth_kind.as_deref().map(|k| if k == "z" { eval::predictions::DepthKind::Z } else { eval::predictions::DepthKind::Distance });
    anyhow::ensure!(args.downscale != Some(0), "--downscale 0: the downscale must be a positive integer factor");
    let opts = eval::ScoreOptions {
        dataset: args.dataset.clone(),
        predictions: args.predictions.clone(),
        out: args.out.clone(),
        method: args.method.clone(),
        split,
        train_seconds: args.train_seconds,
        hardware: args.hardware.clone(),
        downscale: args.downscale,
        depth_kind,
        depth_scale: args.depth_scale,
        allow_missing: args.allow_missing,
        background: parse_background(&args.background)?,
        scene: crate::render::resolve_scene_option(args.scene.as_deref())?,
        dataparser_transforms: args.dataparser_transforms.clone(),
        grid_views: args.grids,
        geometry: args.geometry.clone(),
        geometry_frame: match (&args.to_dataset, args.geometry_frame.as_str()) {
            (Some(m), _) => eval::GeometryFrame::Matrix(eval::geometry::parse_matrix(m).map_err(|e| anyhow::anyhow!("--to-dataset: {e}"))?),
            (None, "dataset") => eval::GeometryFrame::Dataset,
            (None, _) => eval::GeometryFrame::Tool,
        },
        geometry_samples: args.geometry_samples,
        allow_outside: args.allow_outside,
    };
    let _lock = crate::lock_folder(&args.out)?;
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template("scoring {pos}/{len} views {bar:30} {elapsed}").unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let out = eval::score(&opts, &mut |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })
    .with_context(|| format!("scoring {}", args.predictions.display()))?;
    bar.finish_and_clear();
    let m = &out.report.mean;
    let opt = |v: Option<f64>, d: usize| v.map_or("-".to_string(), |x| format!("{x:.d$}"));
    println!("{} ({}): {}", args.method, out.layout.tool.name(), out.layout.description);
    if let Some(r) = &out.report.resolution {
        println!("scored at {}x{} (downscale {})", r.width, r.height, r.downscale);
    }
    println!("| method | PSNR dB | SSIM | depth MAE | depth δ<1.25 | mask IoU | train s (stated) |");
    println!("|---|---|---|---|---|---|---|");
    println!(
        "| {} | {:.2} | {:.4} | {} | {} | {} | {} |",
        args.method,
        m.psnr,
        m.ssim,
        opt(m.depth_mae, 4),
        opt(m.depth_delta_1_25, 3),
        opt(m.mask_iou, 3),
        opt(args.train_seconds, 1)
    );
    if let Some(mesh) = &out.report.mesh {
        let g = &mesh.metrics;
        let f = g.f_scores.first().map_or("-".to_string(), |f| format!("{:.3} at {:.4} m", f.f_score, f.threshold));
        println!("geometry: Chamfer-L1 {:.4} m, accuracy {:.4} m, completeness {:.4} m, F-score {f}", g.chamfer_l1, g.accuracy, g.completeness);
    }
    for note in &out.report.notes {
        println!("note: {note}");
    }
    println!("report: {}", out.report_md.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backgrounds_by_name_or_value() {
        assert_eq!(parse_background("white").unwrap(), [1.0; 3]);
        assert_eq!(parse_background("0, 0.5,1").unwrap(), [0.0, 0.5, 1.0]);
        for bad in ["grey", "1,2,3", "0.5,0.5", "nan,0,0"] {
            assert!(parse_background(bad).unwrap_err().to_string().starts_with("--background"), "{bad}");
        }
    }
}
