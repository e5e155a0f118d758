//! The dataset folder's types, shared by the driver that writes a folder
//! ([`crate::dataset_render`]) and the sharding that splits and merges one ([`crate::shard`]):
//! - what determines a folder's content: [`DatasetRenderConfig`] (from a [`Preset`]), and its
//!   record `render_config.json` ([`RenderRecord`]: the settings, the scene's and environment
//!   map's content hashes ([`SceneSource`]) and the renderer's identity). A folder is resumed or
//!   merged only under an equal record ([`RenderRecord::same_output`]);
//! - how a view is produced: [`ViewRenderer`] renders a camera into [`ViewImages`], its
//!   randomness keyed by [`view_key`]`(split, index) = split_index << 24 | index` only;
//! - shards: [`Shard`] `K/N` owns the views at positions `p ≡ K (mod N)` in the rig's order
//!   (train, val, test); a finished shard folder holds `shard.json` ([`ShardManifest`]);
//! - the driver's options, progress reports and summary ([`RunOptions`], [`ProgressEvent`],
//!   [`DatasetSummary`]).
//!
//! The file names and the folder's life cycle on disk are the dataset crate's
//! ([`dataset::folder`]).

use crate::PathTracerError;
use crate::import::{ImportOptions, ReadFailure};
use crate::rig::{DEFAULT_FOV_X, Rig, RigConfig, RigKind, split_index};
use dataset::{Camera, GroundTruth, RgbaImage, SceneFacts, SplitKind};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Named starting points for [`DatasetRenderConfig`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// 64×64, 20/4/4 views, 16 spp, 4 bounces: seconds, for tests and the demo. Every preset:
    /// seed 0, rig `auto`, transparent background, a faint environment fill of radiance 0.1.
    Quick,
    /// 200×200, 100/10/20 views, 128 spp, 8 bounces: the Blender-synthetic-like dataset.
    Standard,
    /// 800×800 (the Blender-synthetic image size), 100/10/20 views, 128 spp, 8 bounces: the
    /// standard dataset at full resolution (16 times its render time; train with `--downscale`
    /// 2 or 4 for speed, evaluation follows the run's downscale).
    Full,
}

impl Preset {
    /// `quick`, `standard` or `full`.
    pub fn name(self) -> &'static str {
        match self {
            Preset::Quick => "quick",
            Preset::Standard => "standard",
            Preset::Full => "full",
        }
    }
}

impl std::str::FromStr for Preset {
    type Err = PathTracerError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "quick" => Ok(Preset::Quick),
            "standard" => Ok(Preset::Standard),
            "full" => Ok(Preset::Full),
            _ => Err(PathTracerError::Config(format!("unknown preset '{s}' (expected quick, standard or full)"))),
        }
    }
}

/// What pixels whose rays leave the scene show.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Background {
    /// Alpha 0 (colour premultiplied by coverage), like the Blender synthetic scenes.
    Transparent,
    /// The environment radiance, opaque.
    Environment,
    /// A constant linear colour composited behind the scene (`over`), opaque.
    Color([f32; 3]),
}

impl std::str::FromStr for Background {
    type Err = PathTracerError;
    /// `transparent`, `environment` or a linear colour `R,G,B`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "transparent" => Ok(Background::Transparent),
            "environment" => Ok(Background::Environment),
            _ => parse_rgb(s).map(Background::Color).map_err(|m| {
                PathTracerError::Config(format!("background '{s}': {m} (expected transparent, environment or R,G,B)"))
            }),
        }
    }
}

/// Parses a linear colour `R,G,B` of three finite, non-negative numbers.
pub fn parse_rgb(s: &str) -> Result<[f32; 3], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!("'{s}' is not three comma-separated numbers"));
    }
    let mut out = [0.0f32; 3];
    for (o, p) in out.iter_mut().zip(&parts) {
        let v: f32 = p.parse().map_err(|_| format!("'{p}' is not a number"))?;
        if !v.is_finite() || v < 0.0 {
            return Err(format!("{v} must be finite and non-negative"));
        }
        *o = v;
    }
    Ok(out)
}

/// Everything that determines a rendered dataset's content (the thread count does not).
/// Written to `render_config.json` and into the scene facts; a resumed run must match it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DatasetRenderConfig {
    /// The preset the values started from (explicit options may have overridden them).
    pub preset: Preset,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Number of train views.
    pub train: u32,
    /// Number of val views.
    pub val: u32,
    /// Number of test views.
    pub test: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// Maximum path length in bounces.
    pub max_bounces: u32,
    /// Seed of all randomness (rig jitter and path sampling).
    pub seed: u64,
    /// Camera rig.
    pub rig: RigKind,
    /// Horizontal field of view of the sphere rigs, radians.
    pub fov_x: f64,
    /// What missed rays show.
    pub background: Background,
    /// Constant environment radiance lighting the scene (linear RGB), or the scale of the
    /// environment map when there is one.
    pub environment: [f32; 3],
    /// Equirectangular environment map (`.exr` or `.hdr`) lighting the scene, scaled by
    /// `environment` (see [`crate::render::RenderSettings::environment_map`]). Its content is
    /// part of the dataset's identity ([`RenderRecord::environment_map`]).
    #[serde(default)]
    pub environment_map: Option<PathBuf>,
    /// A camera path (nerfstudio's `camera_path.json`, [`dataset::CameraPathFile`]) whose
    /// frames are the train views in place of a rig's (then no val or test views). Its content
    /// is part of the dataset's identity ([`RenderRecord::camera_path`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_path: Option<PathBuf>,
}

impl DatasetRenderConfig {
    /// The settings of a preset.
    pub fn preset(preset: Preset) -> Self {
        let (res, counts, spp, max_bounces) = match preset {
            Preset::Quick => (64, [20, 4, 4], 16, 4),
            Preset::Standard => (200, [100, 10, 20], 128, 8),
            Preset::Full => (800, [100, 10, 20], 128, 8),
        };
        Self {
            preset,
            width: res,
            height: res,
            train: counts[0],
            val: counts[1],
            test: counts[2],
            spp,
            max_bounces,
            seed: 0,
            rig: RigKind::Auto,
            fov_x: DEFAULT_FOV_X,
            background: Background::Transparent,
            environment: [0.1; 3],
            environment_map: None,
            camera_path: None,
        }
    }

    /// Checks that the settings describe a renderable dataset; the message names the option.
    pub fn validate(&self) -> Result<(), PathTracerError> {
        let bad = |m: String| Err(PathTracerError::Config(m));
        if self.width == 0 || self.height == 0 {
            return bad(format!("--res {}x{}: the resolution must be at least 1x1", self.width, self.height));
        }
        if self.width > 16384 || self.height > 16384 {
            return bad(format!("--res {}x{}: at most 16384 pixels per side", self.width, self.height));
        }
        if self.train == 0 {
            return bad("--train 0: at least one train view is needed".into());
        }
        if self.camera_path.is_some() {
            if self.val != 0 || self.test != 0 {
                return bad(format!("--val {} --test {}: a camera path's frames are the only views", self.val, self.test));
            }
        } else if self.val == 0 || self.test == 0 {
            return bad(format!(
                "--val {} --test {}: val and test need at least one view each",
                self.val, self.test
            ));
        }
        if let Some(n) = [self.train, self.val, self.test].into_iter().find(|n| *n >= 1 << 24) {
            return bad(format!("{n} views in one split: at most 16777215"));
        }
        if self.spp == 0 {
            return bad("--spp 0: at least one sample per pixel is needed".into());
        }
        if self.max_bounces > 1024 {
            return bad(format!("--max-bounces {}: at most 1024", self.max_bounces));
        }
        if !(self.fov_x.is_finite() && self.fov_x > 0.0 && self.fov_x < std::f64::consts::PI) {
            return bad(format!("field of view {} rad is not in (0, pi)", self.fov_x));
        }
        let colours = [Some(self.environment), match self.background {
            Background::Color(c) => Some(c),
            _ => None,
        }];
        if colours.iter().flatten().flatten().any(|v| !v.is_finite() || *v < 0.0) {
            return bad("colours must be finite and non-negative".into());
        }
        if let Some(path) = &self.environment_map {
            crate::render::check_environment_map_path(path)?;
        }
        Ok(())
    }

    /// The rig settings these options imply.
    pub fn rig_config(&self) -> RigConfig {
        RigConfig {
            kind: self.rig,
            width: self.width,
            height: self.height,
            fov_x: self.fov_x,
            counts: [self.train, self.val, self.test],
            seed: self.seed,
        }
    }

    /// These settings with the environment map's path blanked (kept as `Some("")` when there
    /// is a map): what must match on resume besides the map's content.
    fn without_environment_map_path(&self) -> DatasetRenderConfig {
        DatasetRenderConfig {
            environment_map: self.environment_map.as_ref().map(|_| PathBuf::new()),
            camera_path: self.camera_path.as_ref().map(|_| PathBuf::new()),
            ..self.clone()
        }
    }

    /// Number of views in all splits.
    pub fn total_views(&self) -> u64 {
        self.train as u64 + self.val as u64 + self.test as u64
    }
}

/// The rig of a dataset render: the camera path's frames as the train split when `cfg` names
/// one (all of one size and field of view: the transforms files hold one intrinsics), else
/// [`crate::rig::build_rig`]'s.
pub fn rig_for(scene: &crate::scene::Scene, cfg: &DatasetRenderConfig) -> Result<Rig, PathTracerError> {
    let Some(path) = &cfg.camera_path else { return crate::rig::build_rig(scene, &cfg.rig_config()) };
    let cams = dataset::CameraPathFile::read(path)?.cameras(path)?;
    let intrinsics = cams[0].intrinsics;
    if let Some(k) = cams.iter().position(|c| c.intrinsics != intrinsics) {
        return Err(PathTracerError::Config(format!(
            "{}: camera_path[{k}].fov differs from camera_path[0].fov; a rendered path has one field of view",
            path.display()
        )));
    }
    if (intrinsics.width, intrinsics.height) != (cfg.width, cfg.height) || cams.len() as u64 != cfg.train as u64 {
        return Err(PathTracerError::Config(format!(
            "{}: {} frames of {}x{}, but the settings say {} views of {}x{} (the file changed?)",
            path.display(),
            cams.len(),
            intrinsics.width,
            intrinsics.height,
            cfg.train,
            cfg.width,
            cfg.height
        )));
    }
    Ok(Rig { kind: RigKind::CameraPath, intrinsics, splits: [cams, Vec::new(), Vec::new()] })
}

/// How to run (does not change the output).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RunOptions {
    /// Worker threads (`None`: rayon's default, one per core).
    pub threads: Option<usize>,
    /// Overwrite a dataset in the output folder rendered with different settings.
    pub force: bool,
    /// Import external buffers and images outside the scene's folder
    /// ([`ImportOptions::allow_outside`]).
    pub allow_outside: bool,
}

/// Progress reports, in order: one `Started`, then one `ViewRendered` per rendered view.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ProgressEvent {
    /// Rendering starts.
    Started {
        /// Views in the dataset.
        total: u64,
        /// Views already finished by an earlier run, kept.
        reused: u64,
        /// The rig actually used.
        rig: RigKind,
    },
    /// A view was rendered and written.
    ViewRendered {
        /// Its split.
        split: SplitKind,
        /// Its index within the split.
        index: u32,
        /// Path samples it took.
        samples: u64,
    },
}

/// What [`crate::dataset_render::render_dataset`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetSummary {
    /// The dataset folder.
    pub out: PathBuf,
    /// The rig used.
    pub rig: RigKind,
    /// Views in the dataset.
    pub views_total: u64,
    /// Views rendered by this run.
    pub views_rendered: u64,
    /// Views kept from an earlier run.
    pub views_reused: u64,
    /// Path samples taken by this run.
    pub samples: u64,
    /// Wall time of this run's rendering and writing, seconds.
    pub seconds: f64,
    /// The scene facts written into the transforms files.
    pub facts: SceneFacts,
}

/// One rendered view, as a [`ViewRenderer`] returns it.
#[derive(Clone, Debug)]
pub struct ViewImages {
    /// Linear RGBA, premultiplied by alpha (coverage).
    pub color: RgbaImage,
    /// Exact ground truth at the pixel-centre rays.
    pub ground_truth: GroundTruth,
    /// Path samples taken.
    pub samples: u64,
}

/// Renders one view of a scene. Implementations must be deterministic in (`camera`, `view_key`)
/// whatever the thread count.
pub trait ViewRenderer: Sync {
    /// Renders `camera`; `view_key` keys the view's randomness (see [`view_key`]).
    fn render_view(&self, camera: &Camera, view_key: u32) -> Result<ViewImages, PathTracerError>;
    /// Whether any material is view-dependent (non-Lambertian).
    fn is_view_dependent(&self) -> bool;
    /// The view's object and material labels ([`dataset::labels`]), `None` when this renderer
    /// has none (then no label files are written).
    fn labels(&self, _camera: &Camera, _view_key: u32) -> Result<Option<dataset::labels::ViewLabels>, PathTracerError> {
        Ok(None)
    }
}

/// The randomness key of view `index` of `split`: `split_index << 24 | index`, independent of
/// the other splits' sizes and of which views are already done.
pub fn view_key(split: SplitKind, index: u32) -> u32 {
    ((split_index(split) as u32) << 24) | (index & 0x00ff_ffff)
}

/// The scene as recorded in `render_config.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneSource {
    /// The scene file as given.
    pub path: String,
    /// FNV-1a 64 hash (hex) of the scene's content — the file and every buffer and image it
    /// references ([`SceneSource::from_scene`]) — to notice an edited scene on resume.
    pub hash: String,
}

impl SceneSource {
    /// Reads a file (e.g. an environment map) to hash its bytes: a regular file of at most
    /// [`dataset::io::MAX_FILE_BYTES`].
    pub fn from_file(path: &Path) -> Result<Self, PathTracerError> {
        let bytes = dataset::paths::read_capped(path, dataset::io::MAX_FILE_BYTES).map_err(|e| PathTracerError::import(path, e.to_string()))?;
        Ok(Self { path: path.display().to_string(), hash: format!("{:016x}", fnv1a(FNV_OFFSET, &bytes)) })
    }

    /// [`SceneSource::from_scene_with`] under the default import options (external files
    /// confined to the scene's folder).
    pub fn from_scene(path: &Path) -> Result<Self, PathTracerError> {
        Self::from_scene_with(path, &ImportOptions::default())
    }

    /// Reads a glTF / GLB scene to hash its content: the file's bytes and every external buffer
    /// and image it references (each URI and its file's bytes, in the file's order), so editing
    /// a `.bin` or a texture changes the hash as editing the glTF does. The files are read as
    /// the import reads them (`options`: inside the scene's folder unless allowed outside,
    /// regular files, within the byte cap); a referenced file that cannot be read is an error
    /// naming it.
    pub fn from_scene_with(path: &Path, options: &ImportOptions) -> Result<Self, PathTracerError> {
        let bytes = crate::import::read_scene_file(path, options)?;
        let mut h = fnv1a(FNV_OFFSET, &bytes);
        let mut left = options.max_buffer_bytes.saturating_sub(bytes.len() as u64);
        let base = path.parent().unwrap_or(Path::new(""));
        for (uri, file) in crate::import::external_files(&bytes, base) {
            crate::import::check_inside(base, &uri, &file, options.allow_outside).map_err(|m| PathTracerError::import(path, m))?;
            let data = crate::import::read_limited(&file, left).map_err(|e| {
                let why = match e {
                    ReadFailure::TooLarge(len) => format!("it has {len} bytes, above the import limit of {} bytes", options.max_buffer_bytes),
                    ReadFailure::Io(e) => e.to_string(),
                };
                PathTracerError::import(path, format!("references '{uri}' ({}), which cannot be read: {why}", file.display()))
            })?;
            left -= data.len() as u64;
            h = fnv1a(fnv1a(h, uri.as_bytes()), &data);
        }
        Ok(Self { path: path.display().to_string(), hash: format!("{h:016x}") })
    }
}

pub(crate) const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

/// FNV-1a 64, continuing from `h`.
pub(crate) fn fnv1a(h: u64, bytes: &[u8]) -> u64 {
    bytes.iter().fold(h, |h, b| (h ^ *b as u64).wrapping_mul(0x0100_0000_01b3))
}

/// The content of `render_config.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderRecord {
    /// The scene.
    pub scene: SceneSource,
    /// Renderer name and version.
    pub renderer: String,
    /// The rig actually used.
    pub rig_resolved: RigKind,
    /// The settings.
    pub config: DatasetRenderConfig,
    /// The environment map file (path as given, hash of its bytes), if any: a resumed run must
    /// use a map with the same content (its path may differ).
    #[serde(default)]
    pub environment_map: Option<SceneSource>,
    /// The camera path file (path as given, hash of its bytes), if any: a resumed run must use
    /// a path with the same content.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_path: Option<SceneSource>,
}

impl RenderRecord {
    /// Whether a dataset rendered under `self` can be resumed under `other` (same scene content,
    /// renderer and settings; the scene's path may differ).
    pub fn same_output(&self, other: &RenderRecord) -> bool {
        let hash = |r: &RenderRecord| r.environment_map.as_ref().map(|m| m.hash.clone());
        self.scene.hash == other.scene.hash
            && self.renderer == other.renderer
            && self.rig_resolved == other.rig_resolved
            && self.config.without_environment_map_path() == other.config.without_environment_map_path()
            && hash(self) == hash(other)
            && self.camera_path.as_ref().map(|m| &m.hash) == other.camera_path.as_ref().map(|m| &m.hash)
    }
}

pub use dataset::folder::{RENDER_CONFIG_FILE, SHARD_MANIFEST_FILE, view_files};

/// What differs between two records, for the error that refuses to mix their views.
pub(crate) fn describe_difference(old: &RenderRecord, new: &RenderRecord) -> String {
    if old.scene.hash != new.scene.hash {
        return scene_difference(&old.scene, &new.scene);
    }
    if old.renderer != new.renderer {
        return format!("renderer {} (now {})", old.renderer, new.renderer);
    }
    let map_hash = |r: &RenderRecord| r.environment_map.as_ref().map(|m| m.hash.clone());
    if map_hash(old) != map_hash(new) {
        let name = |r: &RenderRecord| r.environment_map.as_ref().map_or("none".to_string(), |m| m.path.clone());
        return format!("environment map {} (now {}) differs", name(old), name(new));
    }
    if old.camera_path.as_ref().map(|m| &m.hash) != new.camera_path.as_ref().map(|m| &m.hash) {
        let name = |r: &RenderRecord| r.camera_path.as_ref().map_or("none".to_string(), |m| m.path.clone());
        return format!("camera path {} (now {}) differs", name(old), name(new));
    }
    let a = serde_json::to_value(&old.config).unwrap_or_default();
    let b = serde_json::to_value(&new.config).unwrap_or_default();
    let mut diffs = Vec::new();
    if let (Some(a), Some(b)) = (a.as_object(), b.as_object()) {
        for (k, v) in a {
            if b.get(k) != Some(v) {
                diffs.push(format!("{k} was {v}, now {}", b.get(k).cloned().unwrap_or_default()));
            }
        }
    }
    if old.rig_resolved != new.rig_resolved {
        diffs.push(format!("rig was {}, now {}", old.rig_resolved.name(), new.rig_resolved.name()));
    }
    diffs.join(", ")
}

/// How the scene's content differs: the scene file and every file it references, of which one
/// changed (the record holds one hash over all of them, so which one cannot be told).
fn scene_difference(old: &SceneSource, new: &SceneSource) -> String {
    let path = Path::new(&new.path);
    let referenced = std::fs::read(path).map(|b| crate::import::external_files(&b, path.parent().unwrap_or(Path::new("")))).unwrap_or_default();
    let files = match referenced.len() {
        0 => format!("the scene file {}", new.path),
        _ => format!(
            "one of the scene file {} and the files it references ({})",
            new.path,
            referenced.iter().map(|(_, p)| p.display().to_string()).collect::<Vec<_>>().join(", ")
        ),
    };
    let recorded = if old.path == new.path { String::new() } else { format!(" from {}", old.path) };
    format!("the scene's content changed since this folder was rendered{recorded}: {files} is not what it was (content hash {}, recorded {})", new.hash, old.hash)
}

/// Shard `index` of `count` (zero-based): the views at positions `p` with `p % count == index`
/// in the rig's order over all splits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    /// Which shard, `0..count`.
    pub index: u32,
    /// How many shards.
    pub count: u32,
}

impl Shard {
    /// Whether the view at `position` (over all splits, in the rig's order) is this shard's.
    pub fn owns(&self, position: u64) -> bool {
        position % self.count as u64 == self.index as u64
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl std::str::FromStr for Shard {
    type Err = String;
    /// `K/N` with `0 ≤ K < N`.
    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("--shard '{s}': expected K/N with 0 <= K < N (e.g. 0/4), shards numbered from 0");
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        let (index, count): (u32, u32) = (k.trim().parse().map_err(|_| bad())?, n.trim().parse().map_err(|_| bad())?);
        if count == 0 || index >= count {
            return Err(bad());
        }
        Ok(Self { index, count })
    }
}

/// The content of `shard.json`: which shard the folder holds and its views, written once every
/// one of them is finished.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShardManifest {
    /// The shard.
    pub shard: Shard,
    /// Its views as `<split>/r_<k>`, in the rig's order.
    pub views: Vec<String>,
}

/// Every view of a dataset rendered with `cfg`, in the rig's order: (position, split, index).
fn positions(cfg: &DatasetRenderConfig) -> Vec<(u64, SplitKind, u32)> {
    let counts = [cfg.train, cfg.val, cfg.test];
    let mut out = Vec::new();
    for (s, split) in SplitKind::ALL.into_iter().enumerate() {
        for k in 0..counts[s] {
            out.push((out.len() as u64, split, k));
        }
    }
    out
}

/// The views of `shard` for a dataset rendered with `cfg`, as `<split>/r_<k>`.
pub fn shard_views(cfg: &DatasetRenderConfig, shard: Shard) -> Vec<String> {
    positions(cfg).into_iter().filter(|(p, _, _)| shard.owns(*p)).map(|(_, s, k)| format!("{}/r_{k}", s.name())).collect()
}

/// Writes `shard.json` for a finished shard folder.
pub(crate) fn write_manifest(out: &Path, cfg: &DatasetRenderConfig, shard: Shard) -> Result<(), PathTracerError> {
    let manifest = ShardManifest { shard, views: shard_views(cfg, shard) };
    Ok(dataset::io::atomic_write_json(&out.join(SHARD_MANIFEST_FILE), &manifest)?)
}
