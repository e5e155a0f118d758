//! Error per object and per material: where a prediction fails, from the dataset's label files
//! ([`dataset::labels`]).
//!
//! Every evaluated pixel belongs to the label its pixel-centre ray hit (the object, or the
//! material, of the hit whose depth the ground truth holds; 0 = the background). Per label,
//! over all evaluated views:
//! - `pixels`, split into interior pixels (all of the pixel's image samples hit that label) and
//!   edge pixels (the soft edge where an exact mask and an anti-aliased image disagree), with
//!   PSNR over each set and over both: `10 log10(1 / MSE)`, the MSE over the pixels' display
//!   RGB values, capped at 100 dB (an exact match);
//! - `depth_mae`: mean |predicted − true z-depth| over its foreground pixels (ground-truth alpha
//!   ≥ [`FOREGROUND_ALPHA`]), as [`crate::metrics::depth_mae`];
//! - `off_surface_mass` and `off_surface_front`: the mean, over its foreground rays, of the
//!   rendering weight farther than the tolerance from the true surface, and of the part in
//!   front of it (floaters between the camera and that object), as
//!   [`crate::metrics::off_surface_split`] (our runs only: other tools' files carry no samples).
//!
//! Labels exist at the dataset's resolution; at an odd downscale the block's centre pixel gives
//! the label and the block's pixel-centre labels the coverage, at an even one they are cast
//! through the scene (when it is found), else the section is omitted with the reason.

pub use crate::evaluate::{LabelError, ObjectsBlock};
use crate::evaluate::ViewInput;
use crate::metrics::FOREGROUND_ALPHA;
use crate::truth::GroundTruthSource;
use dataset::labels::{ViewLabels, coverage_of, read_labels};
use dataset::{Frame, SceneFacts};
use std::collections::BTreeMap;

/// Highest PSNR reported (an exact match would be +∞).
pub const PSNR_CAP_DB: f64 = 100.0;

/// The labels of `frame` at `downscale` (see the module documentation), or why there are none.
pub fn view_labels(frame: &Frame, downscale: u32, source: &GroundTruthSource) -> Result<ViewLabels, String> {
    let full = frame.camera.intrinsics;
    let dir = frame.image_path.parent().unwrap_or(std::path::Path::new("."));
    // The files [`dataset::labels::label_files`] names, beside the frame's image.
    let files = dataset::labels::LABEL_SUFFIXES.map(|suffix| dir.join(format!("{}{suffix}", frame.name)));
    if !files.iter().all(|f| f.is_file()) {
        return Err(format!("the dataset has no object label files ({} is missing: render it again with this version to add them)", files[0].display()));
    }
    if downscale > 1 && downscale % 2 == 0 {
        return match source {
            GroundTruthSource::Scene(r) => {
                Ok(r.labels(&frame.camera.downscaled(downscale), 0, &pathtracer::render::RenderSettings::preview(0)))
            }
            _ => Err(format!("labels at the even downscale {downscale} need the scene the dataset was rendered from, which was not found")),
        };
    }
    let labels = read_labels(&files, full.width, full.height).map_err(|e| e.to_string())?;
    if downscale <= 1 {
        return Ok(labels);
    }
    // Odd factor: the centre pixel of each block, the block's labels as its coverage.
    let f = downscale as usize;
    let (w, h) = (full.width as usize / f, full.height as usize / f);
    let (fw, mut out) = (full.width as usize, ViewLabels { width: w as u32, height: h as u32, object: Vec::new(), material: Vec::new(), coverage: Vec::new() });
    let mut block = Vec::with_capacity(f * f);
    for j in 0..h {
        for i in 0..w {
            let c = (j * f + f / 2) * fw + i * f + f / 2;
            out.object.push(labels.object[c]);
            out.material.push(labels.material[c]);
            block.clear();
            for y in j * f..(j + 1) * f {
                block.extend_from_slice(&labels.object[y * fw + i * f..y * fw + (i + 1) * f]);
            }
            out.coverage.push(coverage_of(&block));
        }
    }
    Ok(out)
}

/// One label's running sums.
#[derive(Clone, Debug, Default)]
struct Tally {
    interior: u64,
    edge: u64,
    sse_interior: f64,
    sse_edge: f64,
    depth_abs: f64,
    depth_n: u64,
    off: f64,
    front: f64,
    rays: u64,
}

/// The sums of every object and material over the views added so far.
#[derive(Clone, Debug, Default)]
pub struct ObjectTally {
    objects: BTreeMap<u16, Tally>,
    materials: BTreeMap<u16, Tally>,
    views: usize,
    /// The first view's labels and per-pixel squared error, for the picture.
    first: Option<(ViewLabels, Vec<f32>, Vec<f64>)>,
}

impl ObjectTally {
    /// Adds one view: its labels and the metric inputs (same size; a mismatch is an error).
    pub fn add(&mut self, labels: &ViewLabels, v: &ViewInput<'_>, surface_tol: f32) -> Result<(), String> {
        let n = v.width * v.height;
        if labels.object.len() != n || labels.material.len() != n || labels.coverage.len() != n || v.pred_rgb.len() != 3 * n || v.gt_rgb.len() != 3 * n {
            return Err(format!("view {}: labels of {}x{} for a {}x{} evaluation", v.name, labels.width, labels.height, v.width, v.height));
        }
        // A non-finite predicted colour is left out, as the image metrics leave it out.
        let sq: Vec<f64> = (0..n).map(|p| (0..3).map(|c| (v.pred_rgb[3 * p + c] as f64 - v.gt_rgb[3 * p + c] as f64).powi(2)).sum()).collect();
        for (map, ids) in [(&mut self.objects, &labels.object), (&mut self.materials, &labels.material)] {
            for p in 0..n {
                let t = map.entry(ids[p]).or_default();
                if !sq[p].is_finite() {
                    continue;
                }
                if labels.interior(p) {
                    t.interior += 1;
                    t.sse_interior += sq[p];
                } else {
                    t.edge += 1;
                    t.sse_edge += sq[p];
                }
                let fg = v.gt_alpha.is_some_and(|a| a[p] >= FOREGROUND_ALPHA);
                if let (true, Some(d), Some(g)) = (fg, v.pred_depth, v.gt_depth) {
                    let (d, g) = (d[p] as f64, g[p] as f64);
                    if d.is_finite() && g > 0.0 {
                        t.depth_abs += (d - g).abs();
                        t.depth_n += 1;
                    }
                }
            }
            if let (Some(s), Some(dist), Some(alpha)) = (&v.samples, v.gt_distance, v.gt_alpha) {
                let tol = surface_tol as f64;
                for (r, &pix) in s.pixel.iter().enumerate() {
                    if pix >= n || alpha[pix] < FOREGROUND_ALPHA || r + 1 >= s.offsets.len() {
                        continue;
                    }
                    let range = s.offsets[r]..s.offsets[r + 1].min(s.t.len()).min(s.w.len());
                    if let Some((off, front)) = crate::metrics::ray_off_surface(&s.t[range.clone()], &s.w[range], dist[pix] as f64, tol) {
                        let t = map.entry(ids[pix]).or_default();
                        t.off += off;
                        t.front += front;
                        t.rays += 1;
                    }
                }
            }
        }
        if self.first.is_none() {
            self.first = Some((labels.clone(), v.gt_rgb.to_vec(), sq));
        }
        self.views += 1;
        Ok(())
    }

    /// The per-object and per-material table, named from the scene facts; rows sorted by PSNR,
    /// worst first.
    pub fn finish(&self, facts: Option<&SceneFacts>) -> ObjectsBlock {
        let object_name = |id: u16| -> String {
            if id == 0 {
                return "background (no hit)".into();
            }
            match facts.and_then(|f| f.objects.get(id as usize - 1)) {
                Some(o) => o.name.clone().or_else(|| o.mesh_name.clone().map(|m| format!("{m} (node {})", o.node))).unwrap_or_else(|| format!("node {}", o.node)),
                None => format!("object {id}"),
            }
        };
        let material_name = |id: u16| -> String {
            if id == 0 {
                return "background (no hit)".into();
            }
            facts.and_then(|f| f.materials.get(id as usize - 1)).and_then(|m| m.name.clone()).unwrap_or_else(|| format!("material {}", id - 1))
        };
        ObjectsBlock {
            views: self.views,
            objects: rows(&self.objects, object_name),
            materials: rows(&self.materials, material_name),
            picture_psnr: None,
        }
    }

    /// The first view's picture: every pixel coloured by its object's PSNR (bright = low), over
    /// a grey copy of the true image; `None` before any view. Returns (width, height, RGB) and
    /// the PSNR range the colours span.
    pub fn picture(&self) -> Option<(u32, u32, Vec<u8>, (f64, f64))> {
        let (labels, gt, _) = self.first.as_ref()?;
        let block = self.finish(None);
        let psnr: BTreeMap<u32, f64> = block.objects.iter().map(|r| (r.id, r.psnr)).collect();
        let lo = psnr.values().copied().fold(f64::INFINITY, f64::min);
        let hi = psnr.values().copied().fold(f64::NEG_INFINITY, f64::max);
        let (lo, hi) = if lo.is_finite() && hi > lo { (lo, hi) } else { (lo.min(0.0), lo.max(0.0) + 1.0) };
        let mut rgb = Vec::with_capacity(labels.object.len() * 3);
        for (p, &id) in labels.object.iter().enumerate() {
            let grey = (0.2126 * gt[3 * p] + 0.7152 * gt[3 * p + 1] + 0.0722 * gt[3 * p + 2]).clamp(0.0, 1.0) as f64;
            let tint = crate::colormap::Colormap::Inferno.map(hi - psnr.get(&(id as u32)).copied().unwrap_or(hi), 0.0, hi - lo);
            for c in tint {
                rgb.push((0.7 * c as f64 + 0.3 * 255.0 * grey).round().clamp(0.0, 255.0) as u8);
            }
        }
        Some((labels.width, labels.height, rgb, (lo, hi)))
    }
}

fn psnr(sse: f64, pixels: u64) -> Option<f64> {
    (pixels > 0).then(|| {
        let mse = sse / (3 * pixels) as f64;
        if mse <= 0.0 { PSNR_CAP_DB } else { (-10.0 * mse.log10()).min(PSNR_CAP_DB) }
    })
}

fn rows(map: &BTreeMap<u16, Tally>, name: impl Fn(u16) -> String) -> Vec<LabelError> {
    let mut out: Vec<LabelError> = map
        .iter()
        .map(|(&id, t)| LabelError {
            id: id as u32,
            name: name(id),
            pixels: t.interior + t.edge,
            edge_pixels: t.edge,
            psnr: psnr(t.sse_interior + t.sse_edge, t.interior + t.edge).unwrap_or(f64::NAN),
            psnr_interior: psnr(t.sse_interior, t.interior),
            psnr_edge: psnr(t.sse_edge, t.edge),
            depth_mae: (t.depth_n > 0).then(|| t.depth_abs / t.depth_n as f64),
            off_surface_mass: (t.rays > 0).then(|| t.off / t.rays as f64),
            off_surface_front: (t.rays > 0).then(|| t.front / t.rays as f64),
            mesh_accuracy: None,
            mesh_completeness: None,
        })
        .collect();
    out.sort_by(|a, b| a.psnr.total_cmp(&b.psnr).then(a.id.cmp(&b.id)));
    out
}

/// Fills the objects' mesh accuracy and completeness from the mesh metrics split by object
/// ([`crate::mesh_metrics::label_distances`]).
pub fn add_mesh_distances(block: &mut ObjectsBlock, by_object: &[crate::mesh_metrics::LabelDistance]) {
    for r in &mut block.objects {
        if let Some(d) = by_object.iter().find(|d| d.label as u32 == r.id) {
            (r.mesh_accuracy, r.mesh_completeness) = (d.accuracy, d.completeness);
        }
    }
}

/// Puts the per-object section into `report` (or a note saying why there is none) and writes
/// its picture into `out_dir`.
pub fn attach(report: &mut crate::EvalReport, tally: &Result<ObjectTally, String>, facts: Option<&SceneFacts>, out_dir: &std::path::Path) -> Result<(), crate::EvalError> {
    match tally {
        Ok(t) if t.views > 0 => {
            let mut block = t.finish(facts);
            if let Some((w, h, rgb, (lo, hi))) = t.picture() {
                crate::io::write_png_atomic(&out_dir.join(OBJECTS_PICTURE), w, h, rgb)?;
                block.picture_psnr = Some([lo, hi]);
            }
            report.objects = Some(block);
        }
        Ok(_) => {}
        Err(why) => report.notes.push(format!("no error per object: {why}")),
    }
    Ok(())
}

/// The file of the per-object error picture in a report folder.
pub const OBJECTS_PICTURE: &str = "objects_error.png";

/// `report.md`'s section: the two tables (at most `max_rows` rows each, worst first).
pub fn markdown(block: &ObjectsBlock, max_rows: usize) -> String {
    let f = |x: Option<f64>, digits: usize| x.map_or("–".to_string(), |v| format!("{v:.digits$}"));
    let mut md = format!("## Error per object and per material ({} views)\n\n", block.views);
    md.push_str("Each pixel counts for the object (material) its centre ray hits; edge pixels are those not every image sample of which hits it. Worst PSNR first.\n\n");
    for (title, rows) in [("Object", &block.objects), ("Material", &block.materials)] {
        md.push_str(&format!(
            "| {title} | ID | pixels | edge | PSNR | interior | edge | depth MAE | off-surface | in front | mesh acc. | mesh compl. |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n"
        ));
        for r in rows.iter().take(max_rows) {
            md.push_str(&format!(
                "| {} | {} | {} | {} | {:.2} | {} | {} | {} | {} | {} | {} | {} |\n",
                r.name.replace('|', "/"),
                r.id,
                r.pixels,
                r.edge_pixels,
                r.psnr,
                f(r.psnr_interior, 2),
                f(r.psnr_edge, 2),
                f(r.depth_mae, 4),
                f(r.off_surface_mass, 3),
                f(r.off_surface_front, 3),
                f(r.mesh_accuracy, 4),
                f(r.mesh_completeness, 4)
            ));
        }
        if rows.len() > max_rows {
            md.push_str(&format!("\n({} more in eval.json)\n", rows.len() - max_rows));
        }
        md.push('\n');
    }
    if let Some([lo, hi]) = block.picture_psnr {
        md.push_str(&format!("![per-object error]({OBJECTS_PICTURE})\n\nThe first view, each object tinted by its PSNR (inferno: bright = {lo:.1} dB, dark = {hi:.1} dB).\n\n"));
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view<'a>(pred: &'a [f32], gt: &'a [f32], w: usize, h: usize) -> ViewInput<'a> {
        ViewInput {
            name: "r_0",
            width: w,
            height: h,
            pred_rgb: pred,
            gt_rgb: gt,
            pred_depth: None,
            gt_depth: None,
            gt_distance: None,
            gt_alpha: None,
            pred_opacity: None,
            samples: None,
            render_s: f64::NAN,
        }
    }

    /// Two objects side by side; the prediction is exact on object 1 and off by 0.1 on
    /// object 2: object 2 gets 20 dB, object 1 the cap, and an edge pixel is counted apart.
    #[test]
    fn error_lands_on_the_object_that_has_it() {
        let (w, h) = (4usize, 2usize);
        let object = vec![1, 1, 2, 2, 1, 1, 2, 2];
        let mut coverage: Vec<[f32; 4]> = object.iter().map(|&o| [o as f32, 1.0, 0.0, 0.0]).collect();
        coverage[2] = [2.0, 0.75, 1.0, 0.25];
        let labels = ViewLabels { width: w as u32, height: h as u32, material: object.clone(), object, coverage };
        let gt = vec![0.5f32; w * h * 3];
        let pred: Vec<f32> = (0..w * h * 3).map(|k| if labels.object[k / 3] == 2 { 0.6 } else { 0.5 }).collect();
        let mut t = ObjectTally::default();
        t.add(&labels, &view(&pred, &gt, w, h), 0.01).unwrap();
        let b = t.finish(None);
        assert_eq!(b.objects.len(), 2);
        let (worst, best) = (&b.objects[0], &b.objects[1]);
        assert_eq!((worst.id, worst.pixels, worst.edge_pixels), (2, 4, 1));
        assert!((worst.psnr - 20.0).abs() < 1e-4, "{}", worst.psnr);
        assert!((worst.psnr_edge.unwrap() - 20.0).abs() < 1e-4);
        assert_eq!((best.id, best.psnr), (1, PSNR_CAP_DB));
        assert_eq!(b.materials, b.objects.iter().map(|r| LabelError { name: format!("material {}", r.id - 1), ..r.clone() }).collect::<Vec<_>>());
        // A size mismatch is refused, not mis-attributed.
        assert!(t.add(&labels, &view(&pred[..12], &gt[..12], 2, 2), 0.01).is_err());
    }
}
