//! `transforms_*.json` (Blender-synthetic layout + instant-ngp / nerfstudio intrinsics keys +
//! `scene_facts`), nerfstudio's `transforms.json`, and the [`Dataset`] loader.

use crate::io::{atomic_write_json, read};
use crate::{Camera, DatasetError, Intrinsics};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Train, val or test.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SplitKind {
    /// Views the model learns from.
    Train,
    /// Views evaluated during training.
    Val,
    /// Held-out views for the final evaluation.
    Test,
}

impl SplitKind {
    /// All splits in order.
    pub const ALL: [SplitKind; 3] = [SplitKind::Train, SplitKind::Val, SplitKind::Test];
    /// `"train"`, `"val"` or `"test"`.
    pub fn name(self) -> &'static str {
        match self {
            SplitKind::Train => "train",
            SplitKind::Val => "val",
            SplitKind::Test => "test",
        }
    }
    /// The split file name, e.g. `transforms_train.json`.
    pub fn file_name(self) -> String {
        format!("transforms_{}.json", self.name())
    }
}

/// Facts about the scene that a trainer may use to size its model (absent for datasets from
/// elsewhere).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneFacts {
    /// Scene name or file.
    pub scene: String,
    /// World-space bounding box of all geometry, minimum corner (metres).
    pub aabb_min: [f64; 3],
    /// Maximum corner.
    pub aabb_max: [f64; 3],
    /// Suggested near distance along rays, over all views.
    pub near: f64,
    /// Suggested far distance along rays, over all views.
    pub far: f64,
    /// Whether any visible material is view-dependent (non-Lambertian).
    pub view_dependent: bool,
    /// The render settings, as the renderer records them.
    pub render: serde_json::Value,
    /// Renderer name and version.
    pub renderer: String,
    /// The objects the label files number ([`crate::labels`]): object ID `k + 1` is
    /// `objects[k]`. Empty (and absent from the file) for a dataset without labels.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub objects: Vec<ObjectFacts>,
    /// The materials the material label files number: ID `k + 1` is `materials[k]`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub materials: Vec<MaterialFacts>,
}

/// One object of a rendered scene: a glTF node instance with triangles.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ObjectFacts {
    /// Object ID in the label files (index in [`SceneFacts::objects`] + 1).
    pub id: u32,
    /// glTF node index.
    pub node: usize,
    /// Node name.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// glTF mesh index.
    pub mesh: usize,
    /// Mesh name.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh_name: Option<String>,
    /// Material IDs its triangles use (as in the material label files), ascending.
    pub materials: Vec<u32>,
    /// Triangle count.
    pub triangles: u64,
    /// Surface area, square metres (world space).
    pub area: f64,
    /// World-space bounding box, minimum corner.
    pub aabb_min: [f64; 3],
    /// Maximum corner.
    pub aabb_max: [f64; 3],
}

/// One material of a rendered scene.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MaterialFacts {
    /// Material ID in the label files (glTF material index + 1; the glTF default material,
    /// when used, is last).
    pub id: u32,
    /// Material name.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
}

/// One frame entry of a `transforms_*.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameRecord {
    /// Image path relative to the dataset folder, without extension in the Blender layout
    /// (`./train/r_0`), with it in nerfstudio's.
    pub file_path: String,
    /// Camera-to-world, row by row.
    pub transform_matrix: [[f64; 4]; 4],
    /// nerfstudio's depth file (z-depth `.npy`), relative to the dataset folder.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_file_path: Option<String>,
    /// Our ground-truth EXR (depth, distance, normal, alpha), relative to the dataset folder.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gt_file_path: Option<String>,
    /// Our linear-colour EXR, relative to the dataset folder.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exr_file_path: Option<String>,
}

/// A `transforms_*.json` file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TransformsFile {
    /// Horizontal field of view, radians (the only intrinsic in the Blender datasets).
    pub camera_angle_x: f64,
    /// Vertical field of view, radians.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_angle_y: Option<f64>,
    /// Width in pixels (instant-ngp / nerfstudio).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub w: Option<u32>,
    /// Height in pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub h: Option<u32>,
    /// Focal length x, pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fl_x: Option<f64>,
    /// Focal length y, pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fl_y: Option<f64>,
    /// Principal point x, pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cx: Option<f64>,
    /// Principal point y, pixels.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cy: Option<f64>,
    /// The views.
    pub frames: Vec<FrameRecord>,
    /// Scene facts (our datasets only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scene_facts: Option<SceneFacts>,
    /// instant-ngp's world-to-unit-cube scale ([`instant_ngp_fit`]; its default 0.33 clips
    /// scenes wider than about 3 m), written with the scene facts; other readers ignore it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<f64>,
    /// instant-ngp's offset, in our (not its cycled) axis order.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offset: Option<[f64; 3]>,
    /// instant-ngp's `aabb_scale`: 1, a bounded scene inside its unit cube.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aabb_scale: Option<u32>,
}

/// instant-ngp's `scale` and `offset` for a scene box: it maps a position `p` to
/// `p · scale + offset` (then cycles the axes) and, with `aabb_scale` 1, renders the unit cube,
/// so the box goes centred into the cube with a 10 % margin: `scale = 1 / (1.1 · largest
/// side)`, `offset = 0.5 − scale · centre` (from its `nerf_loader.cu`).
pub fn instant_ngp_fit(aabb_min: [f64; 3], aabb_max: [f64; 3]) -> Option<(f64, [f64; 3])> {
    let side = (0..3).map(|a| aabb_max[a] - aabb_min[a]).fold(0.0f64, f64::max);
    if !(side.is_finite() && side > 0.0) {
        return None;
    }
    let scale = 1.0 / (1.1 * side);
    Some((scale, [0, 1, 2].map(|a| 0.5 - scale * 0.5 * (aabb_min[a] + aabb_max[a]))))
}

impl TransformsFile {
    /// A file with full intrinsics for `intr`.
    pub fn new(intr: &Intrinsics, frames: Vec<FrameRecord>, scene_facts: Option<SceneFacts>) -> Self {
        let fit = scene_facts.as_ref().and_then(|f| instant_ngp_fit(f.aabb_min, f.aabb_max));
        Self {
            camera_angle_x: intr.camera_angle_x(),
            camera_angle_y: Some(intr.camera_angle_y()),
            w: Some(intr.width),
            h: Some(intr.height),
            fl_x: Some(intr.fl_x),
            fl_y: Some(intr.fl_y),
            cx: Some(intr.cx),
            cy: Some(intr.cy),
            frames,
            scale: fit.map(|f| f.0),
            offset: fit.map(|f| f.1),
            aabb_scale: fit.map(|_| 1),
            scene_facts,
        }
    }

    /// Reads and parses a transforms file.
    pub fn read(path: &Path) -> Result<Self, DatasetError> {
        Self::from_slice(&read(path)?, path)
    }

    /// Parses a transforms file's bytes; `path` names it in errors.
    pub fn from_slice(bytes: &[u8], path: &Path) -> Result<Self, DatasetError> {
        serde_json::from_slice(bytes).map_err(|e| DatasetError::Json { path: path.into(), message: json_message(bytes, &e) })
    }

    /// The camera of frame `k` with the intrinsics `intr`: its pose must be a finite rigid
    /// transform. `path` names the file in errors.
    pub fn camera(&self, k: usize, intr: Intrinsics, path: &Path) -> Result<Camera, DatasetError> {
        let rec = self.frames.get(k).ok_or_else(|| DatasetError::invalid(path, format!("frame {k} does not exist")))?;
        let c2w = Camera::c2w_from_rows(&rec.transform_matrix);
        Camera::new(intr, c2w).map_err(|m| DatasetError::invalid(path, format!("frame {k} ({}): {m} (its transform_matrix)", rec.file_path)))
    }

    /// Writes the file atomically.
    pub fn write(&self, path: &Path) -> Result<(), DatasetError> {
        atomic_write_json(path, self)
    }

    /// The intrinsics, taking `w h fl_x fl_y cx cy` where present and `camera_angle_x` with
    /// the image size `image_size` otherwise; checks the two agree.
    pub fn intrinsics(&self, path: &Path, image_size: (u32, u32)) -> Result<Intrinsics, DatasetError> {
        if !(self.camera_angle_x.is_finite() && self.camera_angle_x > crate::camera::MIN_FIELD_OF_VIEW && self.camera_angle_x < std::f64::consts::PI) {
            return Err(DatasetError::invalid(
                path,
                format!(
                    "camera_angle_x = {} is not a field of view in ({:e}, pi) radians",
                    self.camera_angle_x,
                    crate::camera::MIN_FIELD_OF_VIEW
                ),
            ));
        }
        let (w, h) = (self.w.unwrap_or(image_size.0), self.h.unwrap_or(image_size.1));
        let from_angle = Intrinsics::from_fov_x(w, h, self.camera_angle_x);
        let fl_x = self.fl_x.unwrap_or(from_angle.fl_x);
        let intr = Intrinsics {
            width: w,
            height: h,
            fl_x,
            fl_y: self.fl_y.unwrap_or(fl_x),
            cx: self.cx.unwrap_or(0.5 * w as f64),
            cy: self.cy.unwrap_or(0.5 * h as f64),
        };
        intr.validate().map_err(|m| DatasetError::invalid(path, m))?;
        let angle = intr.camera_angle_x();
        if (angle - self.camera_angle_x).abs() > 1e-3 * self.camera_angle_x.max(1e-3) {
            return Err(DatasetError::invalid(
                path,
                format!(
                    "inconsistent intrinsics: camera_angle_x = {} but w = {w}, fl_x = {fl_x} give {angle}",
                    self.camera_angle_x
                ),
            ));
        }
        Ok(intr)
    }
}

/// serde's message, plus a word on the commonest cause of "expected value": `NaN` or
/// `Infinity` written by Python's `json`, which are not JSON numbers.
fn json_message(bytes: &[u8], e: &serde_json::Error) -> String {
    let line = bytes.split(|b| *b == b'\n').nth(e.line().saturating_sub(1)).unwrap_or_default();
    let rest = &line[e.column().saturating_sub(1).min(line.len())..];
    let rest = rest.strip_prefix(b"-").unwrap_or(rest);
    if e.is_syntax() && (rest.starts_with(b"NaN") || rest.starts_with(b"Infinity")) {
        format!("{e}: a non-finite number (NaN or Infinity is not valid JSON)")
    } else {
        e.to_string()
    }
}

/// Parses a transforms file's `bytes` and checks what needs no dataset folder: the
/// intrinsics (with `image_size` where the file gives no `w`, `h`) and every frame's pose.
/// Returns the cameras; `path` names the file in errors. [`Dataset::load`] checks the same,
/// and the files; the fuzz target runs this on arbitrary bytes.
pub fn check_transforms(bytes: &[u8], path: &Path, image_size: (u32, u32)) -> Result<Vec<Camera>, DatasetError> {
    let file = TransformsFile::from_slice(bytes, path)?;
    let intr = file.intrinsics(path, image_size)?;
    (0..file.frames.len()).map(|k| file.camera(k, intr, path)).collect()
}

/// How [`Dataset::load_with`] treats the paths a transforms file names.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LoadOptions {
    /// Read frame files (and transforms files) that lie outside the dataset folder once `..`
    /// and symbolic links are resolved ([`crate::paths::is_inside`]); `false`, the default,
    /// refuses them naming the frame (a command's `--allow-outside` sets it).
    pub allow_outside: bool,
}

/// One loaded view.
#[derive(Clone, Debug)]
pub struct Frame {
    /// File stem, e.g. `r_0`.
    pub name: String,
    /// The split it belongs to.
    pub split: SplitKind,
    /// The posed camera.
    pub camera: Camera,
    /// Display-colour image (PNG).
    pub image_path: PathBuf,
    /// Linear-colour EXR, when the dataset has one.
    pub exr_path: Option<PathBuf>,
    /// Ground-truth EXR (depth, distance, normal, alpha), when the dataset has one.
    pub gt_path: Option<PathBuf>,
}

/// A dataset folder: its splits and, for our datasets, the scene facts.
#[derive(Clone, Debug)]
pub struct Dataset {
    /// The folder.
    pub root: PathBuf,
    /// Training views.
    pub train: Vec<Frame>,
    /// Validation views (empty when the dataset has no `transforms_val.json`).
    pub val: Vec<Frame>,
    /// Test views (empty when the dataset has no `transforms_test.json`).
    pub test: Vec<Frame>,
    /// Scene facts from `transforms_train.json`, if any.
    pub facts: Option<SceneFacts>,
}

impl Dataset {
    /// Loads a dataset folder: `transforms_train.json` is required, val and test are read when
    /// present. Every frame's image must exist and have the size the intrinsics say; poses must
    /// be finite rigid transforms. Every file must be a regular file inside the folder
    /// ([`LoadOptions`]'s default).
    pub fn load(root: &Path) -> Result<Self, DatasetError> {
        Self::load_with(root, &LoadOptions::default())
    }

    /// [`Dataset::load`] with `options` (files outside the folder admitted or not).
    pub fn load_with(root: &Path, options: &LoadOptions) -> Result<Self, DatasetError> {
        if root.is_file() {
            return Err(DatasetError::invalid(root, "is a file, not a dataset folder (give the folder that holds transforms_train.json)"));
        }
        if !root.is_dir() {
            return Err(DatasetError::invalid(root, "dataset folder does not exist"));
        }
        let mut splits: [Vec<Frame>; 3] = Default::default();
        let mut facts = None;
        for (k, split) in SplitKind::ALL.into_iter().enumerate() {
            let path = root.join(split.file_name());
            if !path.exists() {
                if split == SplitKind::Train {
                    return Err(DatasetError::invalid(&path, "missing: a dataset needs transforms_train.json"));
                }
                continue;
            }
            if !options.allow_outside && !crate::paths::is_inside(root, &path) {
                return Err(DatasetError::invalid(
                    &path,
                    format!("leads outside the dataset folder {} (a symbolic link); only files inside it are read unless --allow-outside is given", root.display()),
                ));
            }
            let file = TransformsFile::read(&path)?;
            if split == SplitKind::Train {
                if file.frames.is_empty() {
                    return Err(DatasetError::invalid(&path, "no frames"));
                }
                facts = file.scene_facts.clone();
            }
            splits[k] = load_frames(root, &path, split, &file, options)?;
        }
        let [train, val, test] = splits;
        Ok(Self { root: root.to_path_buf(), train, val, test, facts })
    }

    /// The frames of one split.
    pub fn split(&self, split: SplitKind) -> &[Frame] {
        match split {
            SplitKind::Train => &self.train,
            SplitKind::Val => &self.val,
            SplitKind::Test => &self.test,
        }
    }

    /// Whether the dataset carries ground-truth depth for its frames.
    pub fn has_ground_truth(&self) -> bool {
        self.train.iter().chain(&self.val).chain(&self.test).all(|f| f.gt_path.is_some())
    }
}

fn resolve(root: &Path, rel: &str) -> PathBuf {
    let rel = rel.strip_prefix("./").unwrap_or(rel);
    root.join(rel)
}

/// The file `path` that frame `k` of the transforms file `file` names in its field `field` as
/// `rel`: inside the dataset folder `root` unless `options` allow outside, and a regular file.
/// `what` names it in the message of a missing file.
fn frame_file(root: &Path, file: &Path, k: usize, field: &str, rel: &str, path: PathBuf, what: &str, options: &LoadOptions) -> Result<PathBuf, DatasetError> {
    if !options.allow_outside && !crate::paths::is_inside(root, &path) {
        return Err(DatasetError::invalid(
            file,
            format!(
                "frame {k}: {field} '{rel}' leads outside the dataset folder {}; only files inside it are read unless --allow-outside is given",
                root.display()
            ),
        ));
    }
    match std::fs::metadata(&path) {
        Ok(m) if m.is_file() => Ok(path),
        Ok(_) => Err(DatasetError::invalid(file, format!("frame {k}: {what} {} is not a regular file; only regular files are read", path.display()))),
        Err(_) => Err(DatasetError::invalid(file, format!("frame {k}: {what} {} does not exist", path.display()))),
    }
}

/// The width and height of the image at `path`, from its header, read from a regular file
/// only (the format from the extension, as `image::image_dimensions`).
fn image_size(path: &Path) -> Result<(u32, u32), DatasetError> {
    let file = crate::paths::open_regular(path).map_err(|e| DatasetError::io(path, e))?;
    let mut reader = image::ImageReader::new(std::io::BufReader::new(file));
    if let Ok(format) = image::ImageFormat::from_path(path) {
        reader.set_format(format);
    }
    reader.into_dimensions().map_err(|e| DatasetError::image(path, e))
}

fn load_frames(
    root: &Path,
    path: &Path,
    split: SplitKind,
    file: &TransformsFile,
    options: &LoadOptions,
) -> Result<Vec<Frame>, DatasetError> {
    let mut frames = Vec::with_capacity(file.frames.len());
    let mut intr: Option<Intrinsics> = None;
    for (k, rec) in file.frames.iter().enumerate() {
        let mut image_path = resolve(root, &rec.file_path);
        if image_path.extension().is_none() {
            image_path.set_extension("png");
        }
        let image_path = frame_file(root, path, k, "file_path", &rec.file_path, image_path, "image", options)?;
        let size = image_size(&image_path)?;
        let frame_intr = match intr {
            Some(i) => i,
            None => {
                let i = file.intrinsics(path, size)?;
                intr = Some(i);
                i
            }
        };
        if size != (frame_intr.width, frame_intr.height) {
            return Err(DatasetError::invalid(
                &image_path,
                format!(
                    "image is {}x{} but {} says {}x{}",
                    size.0,
                    size.1,
                    path.display(),
                    frame_intr.width,
                    frame_intr.height
                ),
            ));
        }
        let camera = file.camera(k, frame_intr, path)?;
        let optional = |field: &str, p: &Option<String>| -> Result<Option<PathBuf>, DatasetError> {
            p.as_ref().map(|rel| frame_file(root, path, k, field, rel, resolve(root, rel), "file", options)).transpose()
        };
        let name = image_path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        frames.push(Frame {
            name,
            split,
            camera,
            exr_path: optional("exr_file_path", &rec.exr_file_path)?,
            gt_path: optional("gt_file_path", &rec.gt_file_path)?,
            image_path,
        });
    }
    Ok(frames)
}

/// Writes `transforms_<split>.json` in the Blender layout with intrinsics and scene facts.
pub fn write_split_transforms(
    dir: &Path,
    split: SplitKind,
    intr: &Intrinsics,
    frames: Vec<FrameRecord>,
    facts: Option<SceneFacts>,
) -> Result<(), DatasetError> {
    TransformsFile::new(intr, frames, facts).write(&dir.join(split.file_name()))
}

/// Writes nerfstudio's `transforms.json`: every frame with its image file name (with
/// extension), plus `train_filenames` / `val_filenames` / `test_filenames`. `frames` carry
/// Blender-layout paths (without extension); `.png` is appended. A frame with a depth file
/// (`<stem>_depth.npy`, metres, our tools') points nerfstudio at `<stem>_depth_mm.npy` and
/// `<stem>_mask.png` instead ([`nerfstudio_files`]): nerfstudio 1.1's dataparser multiplies
/// depth by its `depth_unit_scale_factor` option (default 0.001, millimetres) and never reads
/// that key from the file, so the depth it is given is z-depth in millimetres, and its masks
/// are single-channel with 0 = ignore. The caller writes those files.
pub fn write_nerfstudio_transforms(
    dir: &Path,
    intr: &Intrinsics,
    splits: &[(SplitKind, Vec<FrameRecord>)],
) -> Result<(), DatasetError> {
    let mut frames = Vec::new();
    let mut names: [Vec<String>; 3] = Default::default();
    for (split, recs) in splits {
        for rec in recs {
            let rel = rec.file_path.strip_prefix("./").unwrap_or(&rec.file_path);
            let file = if Path::new(rel).extension().is_some() { rel.to_string() } else { format!("{rel}.png") };
            let mut entry = serde_json::json!({
                "file_path": file,
                "transform_matrix": rec.transform_matrix,
            });
            if rec.depth_file_path.is_some() {
                let [depth_mm, mask] = nerfstudio_files(rel);
                entry["depth_file_path"] = serde_json::Value::String(depth_mm);
                entry["mask_path"] = serde_json::Value::String(mask);
            }
            frames.push(entry);
            let idx = SplitKind::ALL.iter().position(|s| s == split).unwrap_or(0);
            names[idx].push(file);
        }
    }
    let json = serde_json::json!({
        "camera_model": "OPENCV",
        "w": intr.width,
        "h": intr.height,
        "fl_x": intr.fl_x,
        "fl_y": intr.fl_y,
        "cx": intr.cx,
        "cy": intr.cy,
        "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
        "frames": frames,
        "train_filenames": names[0],
        "val_filenames": names[1],
        "test_filenames": names[2],
    });
    atomic_write_json(&dir.join("transforms.json"), &json)
}

/// The files nerfstudio reads for the view whose image stem is `stem` (e.g. `train/r_3`):
/// z-depth in millimetres (float32 `.npy`) and the coverage mask (8-bit PNG, 255 where the
/// pixel-centre ray hits the scene).
pub fn nerfstudio_files(stem: &str) -> [String; 2] {
    let stem = stem.strip_prefix("./").unwrap_or(stem);
    [format!("{stem}_depth_mm.npy"), format!("{stem}_mask.png")]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{RgbaImage, write_png_rgba};
    use glam::DVec3;

    #[test]
    fn write_and_load_round_trip() {
        let dir = std::env::temp_dir().join(format!("dataset-tf-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let intr = Intrinsics { width: 8, height: 6, fl_x: 7.5, fl_y: 7.25, cx: 4.1, cy: 2.9 };
        let mut recs = Vec::new();
        for k in 0..3 {
            let eye = DVec3::new(k as f64, 1.0, 3.0);
            let cam = Camera::new(intr, Camera::look_at(eye, DVec3::ZERO, DVec3::Y)).unwrap();
            write_png_rgba(&dir.join(format!("train/r_{k}.png")), &RgbaImage::new(8, 6)).unwrap();
            recs.push(FrameRecord {
                file_path: format!("./train/r_{k}"),
                transform_matrix: cam.rows(),
                depth_file_path: None,
                gt_file_path: None,
                exr_file_path: None,
            });
        }
        write_split_transforms(&dir, SplitKind::Train, &intr, recs.clone(), None).unwrap();
        // nerfstudio's file: frame 1 with a depth file, the others without.
        let mut ns_recs = recs.clone();
        ns_recs[1].depth_file_path = Some("train/r_1_depth.npy".into());
        write_nerfstudio_transforms(&dir, &intr, &[(SplitKind::Train, ns_recs.clone())]).unwrap();
        let ds = Dataset::load(&dir).unwrap();
        assert_eq!(ds.train.len(), 3);
        assert!(ds.val.is_empty());
        for (f, r) in ds.train.iter().zip(&recs) {
            assert_eq!(f.camera.intrinsics, intr);
            let m = Camera::c2w_from_rows(&r.transform_matrix);
            assert!((f.camera.c2w - m).abs().to_cols_array().iter().all(|d| *d < 1e-12));
        }
        let ns: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.join("transforms.json")).unwrap()).unwrap();
        assert_eq!(ns["train_filenames"][2], "train/r_2.png");
        assert!(ns.get("depth_unit_scale_factor").is_none());
        for (k, f) in ns["frames"].as_array().unwrap().iter().enumerate() {
            // Frames with depth point at the millimetre file and the mask; the others at none.
            if ns_recs[k].depth_file_path.is_some() {
                assert_eq!(f["depth_file_path"], format!("train/r_{k}_depth_mm.npy"));
                assert_eq!(f["mask_path"], format!("train/r_{k}_mask.png"));
            } else {
                assert!(f.get("depth_file_path").is_none() && f.get("mask_path").is_none());
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The instant-ngp fit puts the scene box, centred, inside the unit cube with a margin.
    #[test]
    fn instant_ngp_fit_maps_the_box_into_the_unit_cube() {
        let (lo, hi) = ([-1.0, 0.0, -3.0], [1.0, 0.66, 5.0]);
        let (scale, offset) = instant_ngp_fit(lo, hi).unwrap();
        for a in 0..3 {
            let (p, q) = (lo[a] * scale + offset[a], hi[a] * scale + offset[a]);
            assert!(p > 0.0 && q < 1.0 && ((p + q) / 2.0 - 0.5).abs() < 1e-12, "axis {a}: {p}..{q}");
        }
        assert!(((hi[2] - lo[2]) * scale - 1.0 / 1.1).abs() < 1e-12, "the largest side fills 1/1.1");
        assert!(instant_ngp_fit([0.0; 3], [0.0; 3]).is_none());
    }

    #[test]
    fn blender_layout_uses_camera_angle_and_image_size() {
        let dir = std::env::temp_dir().join(format!("dataset-blender-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        write_png_rgba(&dir.join("train/r_0.png"), &RgbaImage::new(10, 10)).unwrap();
        let json = r#"{"camera_angle_x": 0.6911112070083618, "frames": [{"file_path": "./train/r_0",
            "rotation": 0.0126, "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}]}"#;
        std::fs::write(dir.join("transforms_train.json"), json).unwrap();
        let ds = Dataset::load(&dir).unwrap();
        let k = ds.train[0].camera.intrinsics;
        assert!((k.fl_x - 5.0 / (0.5f64 * 0.6911112070083618).tan()).abs() < 1e-9);
        assert_eq!((k.cx, k.cy), (5.0, 5.0));
        assert!(ds.facts.is_none() && !ds.has_ground_truth());

        // Wrongly sized image, inconsistent intrinsics, missing image, bad pose: named errors.
        let bad = json.replace("\"frames\"", "\"w\": 12, \"frames\"");
        std::fs::write(dir.join("transforms_train.json"), bad).unwrap();
        let e = Dataset::load(&dir).unwrap_err().to_string();
        assert!(e.contains("r_0.png") && e.contains("10x10"), "{e}");
        let bad = json.replace("\"frames\"", "\"fl_x\": 3.0, \"frames\"");
        std::fs::write(dir.join("transforms_train.json"), bad).unwrap();
        let e = Dataset::load(&dir).unwrap_err().to_string();
        assert!(e.contains("inconsistent intrinsics"), "{e}");
        std::fs::write(dir.join("transforms_train.json"), json.replace("r_0", "r_9")).unwrap();
        let e = Dataset::load(&dir).unwrap_err().to_string();
        assert!(e.contains("does not exist") && e.contains("transforms_train.json"), "{e}");
        std::fs::write(dir.join("transforms_train.json"), json.replace("[1,0,0,0]", "[0,0,0,0]")).unwrap();
        let e = Dataset::load(&dir).unwrap_err().to_string();
        assert!(e.contains("invertible") || e.contains("rotation"), "{e}");
        std::fs::write(dir.join("transforms_train.json"), json.replace("0.6911112070083618", "1e-30")).unwrap();
        let e = Dataset::load(&dir).unwrap_err().to_string();
        assert!(e.contains("transforms_train.json") && e.contains("camera_angle_x") && e.contains("not a field of view"), "{e}");
        std::fs::write(dir.join("transforms_train.json"), json.replace("[0,0,1,4]", "[0,0,1,1e300]")).unwrap();
        let e = Dataset::load(&dir).unwrap_err().to_string();
        assert!(e.contains("transforms_train.json") && e.contains("frame 0") && e.contains("transform_matrix") && e.contains("translation"), "{e}");
        std::fs::write(dir.join("transforms_train.json"), "{\"frames\": []}").unwrap();
        let e = Dataset::load(&dir).unwrap_err().to_string();
        assert!(e.contains("camera_angle_x"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A dataset whose frame 0 names its files by `file_path`, `gt_file_path` (and, when
    /// given, `exr_file_path`) as written; its one image is `train/r_0.png`.
    fn hostile(dir: &Path, file_path: &str, gt: Option<&str>) {
        let _ = std::fs::remove_dir_all(dir);
        write_png_rgba(&dir.join("train/r_0.png"), &RgbaImage::new(4, 4)).unwrap();
        let gt = gt.map_or(String::new(), |g| format!(", \"gt_file_path\": {}", serde_json::to_string(g).unwrap()));
        let json = format!(
            r#"{{"camera_angle_x": 0.7, "frames": [{{"file_path": {}{gt}, "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}}]}}"#,
            serde_json::to_string(file_path).unwrap()
        );
        std::fs::write(dir.join("transforms_train.json"), json).unwrap();
    }

    /// Frame paths that lead outside the dataset folder (`..`, absolute, a symbolic link) are
    /// refused naming the frame, the field and the folder, without a byte of the outside file
    /// in the message; `allow_outside` admits them. Devices, FIFOs and folders are refused as
    /// not regular files, promptly.
    #[test]
    fn frame_paths_are_confined_to_the_dataset_folder_and_regular_files() {
        let base = std::env::temp_dir().join(format!("dataset-confined-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        let dir = base.join("ds");
        // An image outside the folder, of the right size, whose bytes must never be quoted.
        let outside = base.join("outside.png");
        write_png_rgba(&outside, &RgbaImage::new(4, 4)).unwrap();
        let secret = std::fs::read(&outside).unwrap();
        let escapes = ["../outside.png", "./../outside", "train/../../outside.png", outside.to_str().unwrap()];
        for rel in escapes {
            hostile(&dir, rel, None);
            let e = Dataset::load(&dir).unwrap_err().to_string();
            assert!(e.contains("frame 0: file_path") && e.contains("outside the dataset folder") && e.contains("--allow-outside"), "{rel}: {e}");
            assert!(e.contains("transforms_train.json") && e.contains(rel), "{rel}: {e}");
            assert!(!e.as_bytes().windows(8).any(|w| secret.windows(8).any(|s| s == w)), "{rel}: the error quotes the outside file: {e}");
            let ds = Dataset::load_with(&dir, &LoadOptions { allow_outside: true }).unwrap();
            assert_eq!(std::fs::canonicalize(&ds.train[0].image_path).unwrap(), std::fs::canonicalize(&outside).unwrap());
        }
        // The same for the ground-truth file, and an escape like ../../etc/passwd.
        hostile(&dir, "./train/r_0", Some("../../../../../../../../etc/passwd"));
        let e = Dataset::load(&dir).unwrap_err().to_string();
        assert!(e.contains("gt_file_path") && e.contains("outside the dataset folder") && !e.contains("root:"), "{e}");
        #[cfg(unix)]
        {
            // A symbolic link inside the folder to a file outside, and a linked folder.
            hostile(&dir, "./train/link", None);
            std::os::unix::fs::symlink(&outside, dir.join("train/link.png")).unwrap();
            let e = Dataset::load(&dir).unwrap_err().to_string();
            assert!(e.contains("outside the dataset folder"), "{e}");
            assert!(Dataset::load_with(&dir, &LoadOptions { allow_outside: true }).is_ok());
            hostile(&dir, "./up/outside.png", None);
            std::os::unix::fs::symlink(&base, dir.join("up")).unwrap();
            let e = Dataset::load(&dir).unwrap_err().to_string();
            assert!(e.contains("outside the dataset folder"), "{e}");
            // A transforms file that is itself a link to a file outside.
            hostile(&dir, "./train/r_0", None);
            std::fs::rename(dir.join("transforms_train.json"), base.join("elsewhere.json")).unwrap();
            std::os::unix::fs::symlink(base.join("elsewhere.json"), dir.join("transforms_train.json")).unwrap();
            let e = Dataset::load(&dir).unwrap_err().to_string();
            assert!(e.contains("transforms_train.json") && e.contains("outside the dataset folder"), "{e}");
            assert!(Dataset::load_with(&dir, &LoadOptions { allow_outside: true }).is_ok());
            // Devices (with allow_outside: still refused, as not regular files), a FIFO and a
            // folder inside: refused before anything is opened for reading.
            let start = std::time::Instant::now();
            for dev in ["/dev/zero", "/dev/urandom"] {
                hostile(&dir, "./train/r_0", Some(dev));
                let e = Dataset::load_with(&dir, &LoadOptions { allow_outside: true }).unwrap_err().to_string();
                assert!(e.contains("not a regular file"), "{dev}: {e}");
            }
            hostile(&dir, "./train/pipe.png", None);
            assert!(std::process::Command::new("mkfifo").arg(dir.join("train/pipe.png")).status().unwrap().success());
            let e = Dataset::load(&dir).unwrap_err().to_string();
            assert!(e.contains("not a regular file"), "{e}");
            assert!(start.elapsed() < std::time::Duration::from_secs(5), "took {:?}", start.elapsed());
        }
        hostile(&dir, "./train/r_0", Some("train"));
        let e = Dataset::load(&dir).unwrap_err().to_string();
        assert!(e.contains("not a regular file"), "{e}");
        // Inside, by a detour: fine.
        hostile(&dir, "../ds/train/r_0.png", Some("train/./r_0.png"));
        assert!(Dataset::load(&dir).is_ok());
        std::fs::remove_dir_all(&base).unwrap();
    }

    /// The fuzz target's seeds (`fuzz/corpus/transforms/seed_*`; the fuzzer's own finds there
    /// are not kept) through [`check_transforms`]: `seed_ok_*` pass, `seed_bad_*` are refused
    /// naming the file, none panics.
    #[test]
    fn transforms_fuzz_corpus_parses_or_is_refused_as_named() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/corpus/transforms");
        let mut seen = 0;
        for e in std::fs::read_dir(&dir).unwrap().flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let Some(kind) = name.strip_prefix("seed_") else { continue };
            let bytes = std::fs::read(e.path()).unwrap();
            let r = check_transforms(&bytes, Path::new(&name), (64, 48));
            if kind.starts_with("ok_") {
                assert!(!r.unwrap_or_else(|e| panic!("{name}: {e}")).is_empty(), "{name}: no cameras");
            } else {
                assert!(kind.starts_with("bad_"), "{name}: seeds are named seed_ok_* or seed_bad_*");
                let e = r.err().unwrap_or_else(|| panic!("{name} accepted")).to_string();
                assert!(e.contains(&name), "{name}: the error does not name the file: {e}");
            }
            seen += 1;
        }
        assert!(seen >= 6, "only {seen} seeds in {}", dir.display());
    }
}
