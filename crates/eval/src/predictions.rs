//! Finding another tool's predictions for a split's views: which layout a folder holds, which
//! file is which view's colour, depth and opacity, and whether a transforms file beside them
//! describes the same views. Strict: every view exactly once (two files for one view, a file
//! that names no view, a depth for some views but not others are each one error naming the
//! file); missing views are an error unless the caller allows them.
//!
//! Layouts, tried in this order (docs/evaluation.md has the commands that write them):
//! - **nerfstudio** (`ns-render dataset --split S`): `<out>/<S>/<output>/<image name>`, one
//!   folder per rendered output (`scripts/render.py`, `DatasetRender`, nerfstudio 1.1.5), the
//!   image name being the dataset image's path below the split's common folder, with `.jpg`
//!   (the default), `.png`, or `.npy.gz` for `raw-*` outputs. Colour from `raw-rgba`, `rgba`,
//!   `raw-rgb` or `rgb` (first found); depth from `raw-expected_depth` or `raw-depth` (metres:
//!   `ns-render` divides raw depth by the dataparser scale) or `depth/` holding `.npy`,
//!   `.npy.gz` or `.exr` values in nerfstudio's units (divided by `dataparser_transforms.json`'s
//!   scale); opacity from `raw-accumulation`. nerfstudio's depth is the distance along the ray
//!   (its rays have unit directions, `cameras.py`; nerfacto's `depth` is the median and
//!   `expected_depth` the mean termination distance); splatfacto's is z (gsplat's `RGB+ED`).
//! - **images** / **instant-ngp**: files named by the views (`r_<k>`, or the frames' file
//!   stems) in the folder or in its `<S>/` subfolder: colour `<name>.{png,jpg,exr,npy,npy.gz}`,
//!   depth `<name>_depth.*`, opacity `<name>_opacity.*`. instant-ngp's `--screenshot_dir` is
//!   this layout (named by each frame's `file_path` basename, `scripts/run.py`); a transforms
//!   file beside the images with instant-ngp's `scale` / `offset` / `aabb_scale` names the tool
//!   and puts depth in its units (divided by `scale`).

use crate::interop::{InstantNgpTransform, NerfstudioTransform};
use crate::prediction_io::{FileKind, read_regular};
use crate::EvalError;
use dataset::{Frame, SplitKind};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn invalid(message: impl Into<String>) -> EvalError {
    EvalError::Input(message.into())
}

/// The tool whose layout was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tool {
    /// nerfstudio's `ns-render dataset` output.
    Nerfstudio,
    /// instant-ngp's screenshots beside the transforms file they were taken from.
    InstantNgp,
    /// A plain folder of images named by the views.
    Images,
}

impl Tool {
    /// `nerfstudio`, `instant-ngp` or `images`.
    pub fn name(self) -> &'static str {
        match self {
            Tool::Nerfstudio => "nerfstudio",
            Tool::InstantNgp => "instant-ngp",
            Tool::Images => "images",
        }
    }
}

/// Whether a depth file holds z-depth or the distance along the ray.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DepthKind {
    /// Along the camera's −Z axis.
    Z,
    /// Along the pixel-centre ray from the camera centre.
    Distance,
}

impl DepthKind {
    /// `z` or `distance`.
    pub fn name(self) -> &'static str {
        match self {
            DepthKind::Z => "z",
            DepthKind::Distance => "distance",
        }
    }
}

/// One view's prediction files.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewFiles {
    /// Colour (RGB or RGBA).
    pub colour: PathBuf,
    /// Depth, when given.
    pub depth: Option<PathBuf>,
    /// Opacity, when given as its own file.
    pub opacity: Option<PathBuf>,
}

/// What a predictions folder holds.
#[derive(Clone, Debug)]
pub struct Layout {
    /// The tool.
    pub tool: Tool,
    /// The layout in words: folders and file kinds read.
    pub description: String,
    /// Per frame of the split, its files (`None`: missing).
    pub views: Vec<Option<ViewFiles>>,
    /// The depth kind of the layout's convention.
    pub depth_kind: DepthKind,
    /// Metres per unit of a float depth file, and where it comes from.
    pub depth_unit: (f64, String),
    /// The transforms files beside the predictions that were checked against the dataset.
    pub transforms_checked: Vec<PathBuf>,
    /// nerfstudio's dataparser transform, when found.
    pub nerfstudio: Option<NerfstudioTransform>,
    /// instant-ngp's scale and offset, when the tool is instant-ngp.
    pub instant_ngp: Option<InstantNgpTransform>,
    /// What the report should say about the layout.
    pub notes: Vec<String>,
}

/// The prediction files of one folder, matched to frames by name.
struct Matched {
    /// Per frame, every matching file.
    per_frame: Vec<Vec<PathBuf>>,
    /// Files of the role that name no frame.
    extra: Vec<PathBuf>,
}

/// Names a frame answers to: its file stem and, where no other frame has that stem, `r_<k>`.
fn frame_names(frames: &[&Frame]) -> BTreeMap<String, usize> {
    let mut names: BTreeMap<String, usize> = frames.iter().enumerate().map(|(k, f)| (f.name.clone(), k)).collect();
    for k in 0..frames.len() {
        names.entry(format!("r_{k}")).or_insert(k);
    }
    names
}

/// The regular files in `dir` (symlinks followed), sorted by name; hidden files skipped.
fn files_in(dir: &Path) -> Result<Vec<(String, PathBuf)>, EvalError> {
    let entries = std::fs::read_dir(dir).map_err(|source| EvalError::Io { path: dir.to_path_buf(), source })?;
    let mut out = Vec::new();
    for e in entries {
        let e = e.map_err(|source| EvalError::Io { path: dir.to_path_buf(), source })?;
        let name = e.file_name().to_string_lossy().into_owned();
        if name.starts_with('.') || !e.path().is_file() {
            continue;
        }
        out.push((name, e.path()));
    }
    out.sort();
    Ok(out)
}

/// Matches the prediction files of `dir` whose name (less its extension) ends in `suffix` to
/// the frames; with `others`, files with one of those suffixes are another role's and skipped.
fn match_folder(dir: &Path, names: &BTreeMap<String, usize>, n: usize, suffix: &str, others: &[&str]) -> Result<Matched, EvalError> {
    let mut m = Matched { per_frame: vec![Vec::new(); n], extra: Vec::new() };
    for (name, path) in files_in(dir)? {
        let Some((_, stem)) = FileKind::of(&name) else { continue };
        if others.iter().any(|o| !o.is_empty() && stem.ends_with(o)) {
            continue;
        }
        let Some(view) = stem.strip_suffix(suffix) else { continue };
        match names.get(view) {
            Some(&k) => m.per_frame[k].push(path),
            None => m.extra.push(path),
        }
    }
    Ok(m)
}

/// One file per frame: two for one frame or a file naming no frame is an error; a frame
/// without a file is `None`.
fn one_each(m: Matched, what: &str, frames: &[&Frame], split: SplitKind) -> Result<Vec<Option<PathBuf>>, EvalError> {
    if let Some(extra) = m.extra.first() {
        return Err(invalid(format!(
            "{}: names no {} view of the dataset ({} {what} files name views it does not have); remove it or score the split it belongs to",
            extra.display(),
            split.name(),
            m.extra.len()
        )));
    }
    m.per_frame
        .into_iter()
        .enumerate()
        .map(|(k, files)| match &files[..] {
            [] => Ok(None),
            [one] => Ok(Some(one.clone())),
            [a, b, ..] => Err(invalid(format!("two {what} predictions for view {}: {} and {}; keep one", frames[k].name, a.display(), b.display()))),
        })
        .collect()
}

/// Every present view has `what` (`files`), or none has: a partial set is an error naming the
/// first view without one.
fn all_or_none(files: &[Option<PathBuf>], colour: &[Option<PathBuf>], frames: &[&Frame], what: &str, looked: &str) -> Result<bool, EvalError> {
    let with = files.iter().filter(|f| f.is_some()).count();
    if with == 0 {
        return Ok(false);
    }
    for (k, (f, c)) in files.iter().zip(colour).enumerate() {
        match (f, c) {
            (None, Some(c)) => return Err(invalid(format!("view {} has a colour prediction ({}) but no {what} ({looked}), while {with} other views have one; give every view its {what} or none", frames[k].name, c.display()))),
            (Some(f), None) => return Err(invalid(format!("{}: a {what} for view {}, which has no colour prediction", f.display(), frames[k].name))),
            _ => {}
        }
    }
    Ok(true)
}

/// The nerfstudio output folders under `base`, if `base` holds any colour output.
fn nerfstudio_outputs(base: &Path) -> Option<Vec<String>> {
    let entries = std::fs::read_dir(base).ok()?;
    let mut dirs: Vec<String> = entries.flatten().filter(|e| e.path().is_dir()).map(|e| e.file_name().to_string_lossy().into_owned()).collect();
    dirs.sort();
    NERFSTUDIO_COLOUR.iter().any(|c| dirs.iter().any(|d| d == c)).then_some(dirs)
}

/// nerfstudio's colour outputs, in the order they are preferred: with alpha first (composited
/// on the evaluation background like the ground truth), float before 8-bit.
const NERFSTUDIO_COLOUR: [&str; 4] = ["raw-rgba", "rgba", "raw-rgb", "rgb"];

/// Finds the layout of `pred` for `frames` (the split `split` of the dataset); `dataparser` is
/// nerfstudio's `dataparser_transforms.json` when given.
pub fn detect(pred: &Path, split: SplitKind, frames: &[&Frame], dataparser: Option<&Path>) -> Result<Layout, EvalError> {
    if !pred.is_dir() {
        return Err(invalid(format!("{}: the predictions folder does not exist or is not a folder", pred.display())));
    }
    let names = frame_names(frames);
    let n = frames.len();
    let s = split.name();
    let nerfstudio_transform = match dataparser.map(Path::to_path_buf).or_else(|| Some(pred.join("dataparser_transforms.json")).filter(|p| p.is_file())) {
        Some(p) => Some(NerfstudioTransform::read(&p)?),
        None => None,
    };
    let ns_base = [pred.join(s), pred.to_path_buf()].into_iter().find_map(|b| nerfstudio_outputs(&b).map(|d| (b, d)));
    if let Some((base, dirs)) = ns_base {
        return nerfstudio_layout(pred, &base, &dirs, &names, frames, split, nerfstudio_transform);
    }
    for dir in [pred.to_path_buf(), pred.join(s)] {
        if !dir.is_dir() {
            continue;
        }
        let colour = match_folder(&dir, &names, n, "", &["_depth", "_opacity"])?;
        if colour.per_frame.iter().all(Vec::is_empty) {
            continue;
        }
        let colour = one_each(colour, "colour", frames, split)?;
        let depth = one_each(match_folder(&dir, &names, n, "_depth", &[])?, "depth", frames, split)?;
        let opacity = one_each(match_folder(&dir, &names, n, "_opacity", &[])?, "opacity", frames, split)?;
        let has_depth = all_or_none(&depth, &colour, frames, "depth", "<name>_depth.*")?;
        let has_opacity = all_or_none(&opacity, &colour, frames, "opacity", "<name>_opacity.*")?;
        let transforms = beside_transforms(pred, split)?;
        let ngp = transforms.iter().find(|(_, j)| ["scale", "offset", "aabb_scale"].iter().any(|k| j.get(k).is_some()));
        let instant_ngp = ngp.map(|(p, j)| InstantNgpTransform::from_json(j, p)).transpose()?;
        let tool = if instant_ngp.is_some() { Tool::InstantNgp } else { Tool::Images };
        let depth_unit = match (&instant_ngp, ngp) {
            (Some(t), Some((p, _))) => (1.0 / t.scale, format!("instant-ngp's units: divided by the scale {} of {}", t.scale, p.display())),
            _ => (1.0, "metres, as stored".to_string()),
        };
        let kinds = |files: &[Option<PathBuf>]| -> String {
            let mut k: Vec<String> = files.iter().flatten().filter_map(|p| p.file_name().and_then(|n| FileKind::of(&n.to_string_lossy()).map(|(k, _)| k.extension().to_string()))).collect();
            k.sort();
            k.dedup();
            k.join("/")
        };
        let rel = dir.strip_prefix(pred).ok().filter(|r| !r.as_os_str().is_empty()).map_or(String::new(), |r| format!("{}/", r.display()));
        let mut description = format!("{}: colour {rel}<view>.{}", tool_words(tool), kinds(&colour));
        if has_depth {
            description.push_str(&format!(", depth {rel}<view>_depth.{}", kinds(&depth)));
        }
        if has_opacity {
            description.push_str(&format!(", opacity {rel}<view>_opacity.{}", kinds(&opacity)));
        }
        let views = (0..n)
            .map(|k| colour[k].clone().map(|c| ViewFiles { colour: c, depth: depth[k].clone(), opacity: opacity[k].clone() }))
            .collect();
        let checked = check_transforms(&transforms, frames, split)?;
        return Ok(Layout {
            tool,
            description,
            views,
            depth_kind: DepthKind::Z,
            depth_unit,
            transforms_checked: checked,
            nerfstudio: nerfstudio_transform,
            instant_ngp,
            notes: Vec::new(),
        });
    }
    let examples: Vec<&str> = frames.iter().take(2).map(|f| f.name.as_str()).collect();
    Err(invalid(format!(
        "{}: no predictions found: looked for nerfstudio's `ns-render dataset` output ({s}/rgb/, {s}/rgba/, {s}/raw-rgb/ or {s}/raw-rgba/) and for images named by the {s} views ({}{}, as .png, .jpg, .exr, .npy or .npy.gz) in the folder and in {s}/",
        pred.display(),
        examples.join(", "),
        if n > 2 { ", …" } else { "" }
    )))
}

fn tool_words(tool: Tool) -> &'static str {
    match tool {
        Tool::Nerfstudio => "nerfstudio `ns-render dataset` output",
        Tool::InstantNgp => "instant-ngp screenshots (`--screenshot_transforms`, `--screenshot_dir`)",
        Tool::Images => "a folder of images named by the views",
    }
}

fn nerfstudio_layout(
    pred: &Path,
    base: &Path,
    dirs: &[String],
    names: &BTreeMap<String, usize>,
    frames: &[&Frame],
    split: SplitKind,
    transform: Option<NerfstudioTransform>,
) -> Result<Layout, EvalError> {
    let n = frames.len();
    let rel = |d: &str| base.join(d).strip_prefix(pred).map(|p| p.display().to_string()).unwrap_or_else(|_| d.to_string());
    let has = |d: &str| dirs.iter().any(|x| x == d);
    let mut notes = Vec::new();
    let colour_dir = NERFSTUDIO_COLOUR.iter().find(|c| has(c)).copied().unwrap_or("rgb");
    let colour = one_each(match_folder(&base.join(colour_dir), names, n, "", &[])?, "colour", frames, split)?;
    let mut used = vec![colour_dir.to_string()];
    let mut description = format!("{}: colour {}/", tool_words(Tool::Nerfstudio), rel(colour_dir));
    let mut depth = vec![None; n];
    let mut depth_unit = (1.0, "metres: ns-render divides raw depth by the dataparser scale".to_string());
    let depth_dir = ["raw-expected_depth", "raw-depth"].into_iter().find(|d| has(d));
    match depth_dir {
        Some(d) => {
            depth = one_each(match_folder(&base.join(d), names, n, "", &[])?, "depth", frames, split)?;
            all_or_none(&depth, &colour, frames, "depth", &format!("{}/<view>.npy.gz", rel(d)))?;
            description.push_str(&format!(", depth {}/", rel(d)));
            used.push(d.into());
        }
        None if has("depth") => {
            let m = match_folder(&base.join("depth"), names, n, "", &[])?;
            let values = |p: &PathBuf| p.file_name().is_some_and(|n| FileKind::of(&n.to_string_lossy()).is_some_and(|(k, _)| matches!(k, FileKind::Npy | FileKind::NpyGz | FileKind::Exr)));
            if m.per_frame.iter().flatten().chain(&m.extra).any(values) {
                let Some(t) = transform else {
                    return Err(invalid(format!(
                        "{}: depth values in nerfstudio's units need its dataparser_transforms.json (from the run's output folder): put it in {} or give --dataparser-transforms",
                        base.join("depth").display(),
                        pred.display()
                    )));
                };
                depth = one_each(m, "depth", frames, split)?;
                all_or_none(&depth, &colour, frames, "depth", &format!("{}/<view>.npy", rel("depth")))?;
                depth_unit = (1.0 / t.scale, format!("nerfstudio's units: divided by the dataparser scale {}", t.scale));
                description.push_str(&format!(", depth {}/ (nerfstudio's units)", rel("depth")));
                used.push("depth".into());
            } else {
                notes.push(format!(
                    "{}/ holds ns-render's colour-mapped depth pictures, not depth values: depth not scored (render `raw-depth` for it)",
                    rel("depth")
                ));
            }
        }
        None => {}
    }
    let mut opacity = vec![None; n];
    if has("raw-accumulation") {
        opacity = one_each(match_folder(&base.join("raw-accumulation"), names, n, "", &[])?, "opacity", frames, split)?;
        all_or_none(&opacity, &colour, frames, "opacity", &format!("{}/<view>.npy.gz", rel("raw-accumulation")))?;
        description.push_str(&format!(", opacity {}/", rel("raw-accumulation")));
        used.push("raw-accumulation".into());
    }
    let ignored: Vec<&str> = dirs.iter().map(String::as_str).filter(|d| !used.iter().any(|u| u == d)).collect();
    if !ignored.is_empty() {
        description.push_str(&format!(" (not read: {})", ignored.join(", ")));
    }
    let views = (0..n).map(|k| colour[k].clone().map(|c| ViewFiles { colour: c, depth: depth[k].clone(), opacity: opacity[k].clone() })).collect();
    let checked = check_transforms(&beside_transforms(pred, split)?, frames, split)?;
    Ok(Layout {
        tool: Tool::Nerfstudio,
        description,
        views,
        depth_kind: DepthKind::Distance,
        depth_unit,
        transforms_checked: checked,
        nerfstudio: transform,
        instant_ngp: None,
        notes,
    })
}

/// The transforms files in `pred` (`transforms.json`, `transforms_<split>.json`; another
/// split's file is not this split's), parsed.
fn beside_transforms(pred: &Path, split: SplitKind) -> Result<Vec<(PathBuf, serde_json::Value)>, EvalError> {
    let mut out = Vec::new();
    for name in ["transforms.json".to_string(), split.file_name()] {
        let p = pred.join(&name);
        if !p.is_file() {
            continue;
        }
        let bytes = read_regular(&p, 256 << 20)?;
        let json: serde_json::Value = serde_json::from_slice(&bytes).map_err(|e| invalid(format!("{}: not a transforms file ({e})", p.display())))?;
        out.push((p, json));
    }
    Ok(out)
}

/// Refuses a transforms file beside the predictions that describes other views than the
/// dataset's split (another count, resolution or pose); returns the files checked.
fn check_transforms(files: &[(PathBuf, serde_json::Value)], frames: &[&Frame], split: SplitKind) -> Result<Vec<PathBuf>, EvalError> {
    let s = split.name();
    let mut checked = Vec::new();
    for (p, json) in files {
        let all = json.get("frames").and_then(|f| f.as_array()).ok_or_else(|| invalid(format!("{}: a transforms file without \"frames\"", p.display())))?;
        let listed: Option<Vec<&str>> = json.get(format!("{s}_filenames")).and_then(|v| v.as_array()).map(|a| a.iter().filter_map(|v| v.as_str()).collect());
        let path_of = |f: &serde_json::Value| f.get("file_path").and_then(|v| v.as_str()).unwrap_or("").to_string();
        let norm = |f: &str| f.trim_start_matches("./").to_string();
        let mine: Vec<&serde_json::Value> = match &listed {
            Some(l) => all.iter().filter(|f| l.iter().any(|x| norm(x) == norm(&path_of(f)))).collect(),
            None => all.iter().collect(),
        };
        if mine.len() != frames.len() {
            return Err(invalid(format!(
                "{}: describes {} {s} views, the dataset has {}: these predictions are for another dataset",
                p.display(),
                mine.len(),
                frames.len()
            )));
        }
        let full = frames[0].camera.intrinsics;
        for f in &mine {
            let size = |k: &str| f.get(k).or_else(|| json.get(k)).and_then(|v| v.as_f64());
            if let (Some(w), Some(h)) = (size("w"), size("h"))
                && (w, h) != (f64::from(full.width), f64::from(full.height))
            {
                return Err(invalid(format!(
                    "{}: its views are {w}x{h}, the dataset's are {}x{}: these predictions are for another dataset",
                    p.display(),
                    full.width,
                    full.height
                )));
            }
        }
        for (k, f) in mine.iter().enumerate() {
            let fp = path_of(f);
            let stem = Path::new(&fp).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            let frame = frames.iter().find(|fr| fr.name == stem).unwrap_or(&frames[k]);
            let m: Option<Vec<f64>> = f.get("transform_matrix").and_then(|m| m.as_array()).map(|rows| rows.iter().flat_map(|r| r.as_array().into_iter().flatten().filter_map(|v| v.as_f64())).collect());
            let want: Vec<f64> = frame.camera.rows().iter().flatten().copied().collect();
            let diff = m.as_ref().filter(|m| m.len() == 16).map(|m| m.iter().zip(&want).map(|(a, b)| (a - b).abs() / (1.0 + b.abs())).fold(0.0, f64::max));
            match diff {
                Some(d) if d <= 1e-6 => {}
                Some(d) => {
                    return Err(invalid(format!(
                        "{}: the pose of {fp} differs from the dataset's view {} (by {d:.3e} relative): these predictions are for another dataset",
                        p.display(),
                        frame.name
                    )));
                }
                None => return Err(invalid(format!("{}: frame {fp} has no 4x4 transform_matrix", p.display()))),
            }
        }
        checked.push(p.clone());
    }
    Ok(checked)
}
