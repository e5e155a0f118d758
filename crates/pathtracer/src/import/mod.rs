//! glTF 2.0 import into the flat render scene ([`Scene`]).
//!
//! [`load_gltf`] reads a `.gltf` (JSON with external or `data:` buffers) or `.glb` file and
//! bakes the selected scene's node hierarchy into one world-space triangle soup:
//!
//! - transforms (TRS or matrix) composed in `f64`; a negative determinant flips the winding,
//!   normals go through the inverse transpose; positions are stored relative to
//!   [`Scene::origin`], the centre of the `f64` bounds;
//! - TRIANGLES, TRIANGLE_STRIP and TRIANGLE_FAN primitives (points and lines are skipped with
//!   a warning), indexed or not, with every component type the spec allows (and
//!   `KHR_mesh_quantization`), sparse accessors and interleaved buffer views, all read by a
//!   bounds-checked reader of our own;
//! - flat normals computed when NORMAL is absent (the spec's requirement);
//! - morph targets at their default weights, then skins at the default pose (joint world
//!   transforms × inverse bind matrices, linear blend skinning; module `skin`);
//! - metallic-roughness materials with their textures (colour textures decoded from sRGB to
//!   linear), `KHR_materials_emissive_strength`, `KHR_materials_specular`,
//!   `KHR_materials_ior` and `KHR_texture_transform` on every texture read;
//! - perspective cameras and `KHR_lights_punctual` lights.
//!
//! Every problem in the file is an [`PathTracerError::Import`] naming the file and the
//! object at fault; the loader never panics on file contents and caps what a file can make it
//! allocate ([`ImportOptions`]). External buffers and images must be regular files inside the
//! scene file's folder once percent-escapes, `..` and symbolic links are resolved, unless
//! [`ImportOptions::allow_outside`]; every file is read through the byte cap, not trusting its
//! length. Recoverable oddities (an unsupported optional extension, a line primitive, an
//! orthographic camera) become [`Scene::warnings`] and `tracing` warnings.

mod accessor;
mod glb;
mod graph;
mod materials;
mod skin;
mod textures;
mod uri;

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{DVec3, Vec2, Vec3, Vec4};
use gltf::json::validation::Checked;

use crate::error::PathTracerError;
use crate::scene::{Material, Scene, SceneCamera, Texture};

/// How to import a glTF file, and the caps that keep a hostile file from exhausting memory.
///
/// `Default` is the glTF specification's behaviour (the file's default scene) with caps far
/// above any scene this project renders on a workstation.
#[derive(Clone, Debug, PartialEq)]
pub struct ImportOptions {
    /// Which scene to import. `None` follows the spec: the file's `scene`, else scene 0, else
    /// every root node when the file has no scenes.
    pub scene: Option<usize>,
    /// Most triangles the whole scene may have (default 20 million).
    pub max_triangles: usize,
    /// Most vertices the whole scene may have (default 30 million).
    pub max_vertices: usize,
    /// Most texels over all decoded textures (default 2²⁶ ≈ 67 million, 1 GiB as RGBA `f32`).
    pub max_texture_texels: u64,
    /// Most bytes over all buffers, external images and the scene file (default 2 GiB).
    pub max_buffer_bytes: u64,
    /// Read external buffers and images that lie outside the scene file's folder (an absolute
    /// URI, `../` or `%2e%2e/`, a symbolic link leading out). `false` (the default) refuses
    /// them naming the scene file and the URI; a command's `--allow-outside` sets it.
    pub allow_outside: bool,
}

impl Default for ImportOptions {
    fn default() -> Self {
        Self {
            scene: None,
            max_triangles: 20_000_000,
            max_vertices: 30_000_000,
            max_texture_texels: 1 << 26,
            max_buffer_bytes: 2 << 30,
            allow_outside: false,
        }
    }
}

/// Extensions whose data we import completely.
const SUPPORTED_EXTENSIONS: &[&str] =
    &[
    "KHR_lights_punctual",
    "KHR_materials_clearcoat",
    "KHR_materials_emissive_strength",
    "KHR_materials_ior",
    "KHR_materials_sheen",
    "KHR_materials_specular",
    "KHR_materials_transmission",
    "KHR_materials_volume",
    "KHR_mesh_quantization",
    "KHR_texture_transform",
];

/// Extensions that only add optional material data (or metadata): the asset renders correctly,
/// if less richly, without them, so they are accepted even when listed as required (with a
/// warning that they are ignored).
const IGNORABLE_EXTENSIONS: &[&str] = &[
    "KHR_materials_iridescence",
    "KHR_materials_anisotropy",
    "KHR_materials_dispersion",
    "KHR_materials_variants",
    "KHR_xmp_json_ld",
];

/// Reads the glTF or GLB file at `path` into a render [`Scene`]; external buffers and images
/// are resolved relative to the file's folder.
pub fn load_gltf(path: &Path, options: &ImportOptions) -> Result<Scene, PathTracerError> {
    let bytes = read_scene_file(path, options)?;
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("glb")) && !glb::is_glb(&bytes) {
        let head: String = bytes.iter().take(4).map(|b| if b.is_ascii_graphic() { *b as char } else { '.' }).collect();
        return Err(PathTracerError::import(path, format!("not a binary glTF (.glb): the file starts with '{head}', not the GLB magic 'glTF'")));
    }
    let base_dir = path.parent().unwrap_or(Path::new(""));
    load_gltf_from_slice(&bytes, Some(base_dir), &path.display().to_string(), options)
}

/// Reads the scene file at `path` itself: a regular file of at most
/// [`ImportOptions::max_buffer_bytes`].
pub(crate) fn read_scene_file(path: &Path, options: &ImportOptions) -> Result<Vec<u8>, PathTracerError> {
    read_limited(path, options.max_buffer_bytes).map_err(|e| {
        PathTracerError::import(
            path,
            match e {
                ReadFailure::TooLarge(len) => format!("scene file is {len} bytes, above the import limit of {} bytes", options.max_buffer_bytes),
                ReadFailure::Io(e) => format!("cannot read scene file: {e}"),
            },
        )
    })
}

/// Why [`read_limited`] read nothing.
pub(crate) enum ReadFailure {
    /// The file has this many bytes (or at least this many), more than the limit.
    TooLarge(u64),
    /// It cannot be opened or read, or is not a regular file.
    Io(std::io::Error),
}

/// Reads the regular file `file` ([`dataset::paths::open_regular`]) if it has at most `limit`
/// bytes: a longer stated length is refused before reading, and the read stops after
/// `limit + 1` bytes whatever the length said.
pub(crate) fn read_limited(file: &Path, limit: u64) -> Result<Vec<u8>, ReadFailure> {
    let f = dataset::paths::open_regular(file).map_err(ReadFailure::Io)?;
    let len = f.metadata().map_err(ReadFailure::Io)?.len();
    if len > limit {
        return Err(ReadFailure::TooLarge(len));
    }
    dataset::paths::read_to_end_capped(f, limit, len).map_err(|e| match e.kind() {
        std::io::ErrorKind::FileTooLarge => ReadFailure::TooLarge(limit.saturating_add(1)),
        _ => ReadFailure::Io(e),
    })
}

/// Refuses the external `file` a scene's `uri` names (resolved against the scene's folder
/// `base_dir`) when it lies outside that folder ([`dataset::paths::is_inside`]) and
/// `allow_outside` is not set: the message names the URI and the folder, nothing of the file.
pub(crate) fn check_inside(base_dir: &Path, uri: &str, file: &Path, allow_outside: bool) -> Result<(), String> {
    if allow_outside || dataset::paths::is_inside(base_dir, file) {
        return Ok(());
    }
    let folder = if base_dir.as_os_str().is_empty() { Path::new(".") } else { base_dir };
    Err(format!(
        "URI '{uri}' leads outside the scene's folder {}; only files inside it are read unless --allow-outside is given",
        folder.display()
    ))
}

/// The external files (buffers and images, not `data:` URIs or the GLB chunk) the glTF or GLB
/// `bytes` reference, as (URI as written, path resolved against `base_dir`), in the order
/// buffers then images. Unparseable JSON or URIs give no entry here: the import reports them.
pub fn external_files(bytes: &[u8], base_dir: &Path) -> Vec<(String, PathBuf)> {
    let json_bytes = if glb::is_glb(bytes) {
        match glb::parse(bytes) {
            Ok(g) => g.json,
            Err(_) => return Vec::new(),
        }
    } else {
        bytes
    };
    let Ok(raw) = serde_json::from_slice::<serde_json::Value>(json_bytes) else { return Vec::new() };
    let mut out = Vec::new();
    for key in ["buffers", "images"] {
        for item in raw.get(key).and_then(|v| v.as_array()).into_iter().flatten() {
            let Some(u) = item.get("uri").and_then(|u| u.as_str()) else { continue };
            if let Ok(uri::UriTarget::File(p)) = uri::resolve(u, Some(base_dir)) {
                out.push((u.to_string(), p));
            }
        }
    }
    out
}

/// Imports a glTF (JSON) or GLB file held in memory. `base_dir` resolves external buffers and
/// images (`None`: only `data:` URIs and the GLB chunk are allowed); `name` names the scene in
/// [`Scene::name`] and in every error message.
pub fn load_gltf_from_slice(
    bytes: &[u8],
    base_dir: Option<&Path>,
    name: &str,
    options: &ImportOptions,
) -> Result<Scene, PathTracerError> {
    let path = PathBuf::from(name);
    let err = |msg: String| PathTracerError::import(&path, msg);

    let (json_bytes, bin) = if glb::is_glb(bytes) {
        let g = glb::parse(bytes).map_err(err)?;
        (g.json, g.bin)
    } else {
        (bytes, None)
    };
    let mut root: gltf::json::Root =
        gltf::json::deserialize::from_slice(json_bytes).map_err(|e| err(format!("invalid glTF JSON: {e}")))?;
    let raw: serde_json::Value = serde_json::from_slice(json_bytes).unwrap_or(serde_json::Value::Null);

    check_version(&root.asset).map_err(err)?;
    let mut warnings = Vec::new();
    check_extensions(&root, &mut warnings).map_err(err)?;
    // Our own check replaces the gltf crate's (which only knows its compiled-in features).
    root.extensions_required.clear();
    let document = validate(root, &mut warnings).map_err(err)?;

    let mut importer = Importer {
        path: path.clone(),
        base_dir,
        options,
        warnings: Vec::new(),
        doc: std::rc::Rc::new(document),
        raw,
        buffers: Vec::new(),
        bytes_loaded: bytes.len() as u64,
        textures: Vec::new(),
        texture_cache: HashMap::new(),
        texels_used: 0,
        materials: Vec::new(),
        uses_default_material: false,
        geometry: Geometry::default(),
        lights: Vec::new(),
        cameras: Vec::new(),
        objects: Vec::new(),
    };
    for w in warnings {
        importer.warn(w);
    }
    importer.load_buffers(bin)?;
    importer.load_materials()?;
    importer.traverse()?;
    importer.finish(name)
}

/// Refuses an asset of another major glTF version than 2 (`asset.version`, and
/// `asset.minVersion` when given, are `major.minor`): its meaning may differ from what this
/// importer reads (glTF 2.0 §3.2: a loader rejects a major version it does not support).
fn check_version(asset: &gltf::json::Asset) -> Result<(), String> {
    let major = |v: &str| v.split('.').next().and_then(|m| m.trim().parse::<u32>().ok());
    for (field, v) in [("asset.version", Some(asset.version.as_str())), ("asset.minVersion", asset.min_version.as_deref())] {
        let Some(v) = v else { continue };
        if major(v) != Some(2) {
            return Err(format!("{field} is \"{v}\": only glTF 2.x is supported"));
        }
    }
    Ok(())
}

/// Checks `extensionsRequired` (error for anything unsupported) and `extensionsUsed` (warning
/// for anything we ignore).
fn check_extensions(root: &gltf::json::Root, warnings: &mut Vec<String>) -> Result<(), String> {
    for ext in &root.extensions_required {
        if SUPPORTED_EXTENSIONS.contains(&ext.as_str()) {
            continue;
        }
        if IGNORABLE_EXTENSIONS.contains(&ext.as_str()) {
            warnings.push(format!("required extension {ext} only adds optional material data; ignored"));
            continue;
        }
        return Err(format!(
            "required extension {ext} is not supported (supported: {}; ignorable: {})",
            SUPPORTED_EXTENSIONS.join(", "),
            IGNORABLE_EXTENSIONS.join(", ")
        ));
    }
    for ext in &root.extensions_used {
        if !SUPPORTED_EXTENSIONS.contains(&ext.as_str()) && !root.extensions_required.contains(ext) {
            warnings.push(format!("extension {ext} is used but not supported; ignored"));
        }
    }
    Ok(())
}

/// Runs the gltf crate's validation (every index reference in range, every enum valid), after
/// the pre-checks that keep it from panicking. A missing POSITION `min`/`max` (required by the
/// spec, but we compute bounds ourselves) is downgraded to a warning.
fn validate(root: gltf::json::Root, warnings: &mut Vec<String>) -> Result<gltf::Document, String> {
    // gltf-json's primitive validation indexes `accessors` with the POSITION index unchecked.
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            for (semantic, index) in &prim.attributes {
                if index.value() >= root.accessors.len() {
                    let name = match semantic {
                        Checked::Valid(s) => s.to_string(),
                        Checked::Invalid => "?".to_string(),
                    };
                    return Err(format!(
                        "meshes[{m}].primitives[{p}].attributes[\"{name}\"]: accessor {} does not exist ({} accessors)",
                        index.value(),
                        root.accessors.len()
                    ));
                }
            }
        }
    }
    match gltf::Document::from_json(root.clone()) {
        Ok(doc) => Ok(doc),
        Err(gltf::Error::Validation(errors)) => {
            let (soft, hard): (Vec<_>, Vec<_>) = errors.into_iter().partition(|(path, _)| {
                let p = path.to_string();
                p.contains("POSITION") && (p.ends_with(".min") || p.ends_with(".max"))
            });
            if let Some((path, first)) = hard.first() {
                let more = if hard.len() > 1 { format!(" (and {} more problems)", hard.len() - 1) } else { String::new() };
                return Err(format!("invalid glTF: {path}: {first}{more}"));
            }
            for (path, e) in soft {
                warnings.push(format!("{path}: {e} (bounds are computed from the data)"));
            }
            Ok(gltf::Document::from_json_without_validation(root))
        }
        Err(e) => Err(format!("invalid glTF: {e}")),
    }
}

/// Geometry gathered while traversing, in world space (`f64` positions).
#[derive(Default)]
pub(crate) struct Geometry {
    pub positions: Vec<DVec3>,
    pub normals: Vec<Vec3>,
    pub tangents: Vec<Vec4>,
    pub uv0: Vec<Vec2>,
    pub uv1: Vec<Vec2>,
    pub colors: Vec<Vec4>,
    pub indices: Vec<[u32; 3]>,
    pub material: Vec<u32>,
}

/// A light with its world placement, turned into a [`crate::scene::Light`] once the origin is
/// known.
pub(crate) struct WorldLight {
    pub kind: gltf::khr_lights_punctual::Kind,
    pub color_intensity: Vec3,
    pub range: Option<f32>,
    pub position: DVec3,
    pub direction: DVec3,
}

/// ` ('name')` for an object with a name, else nothing: appended to `node 3` and the like.
pub(crate) fn name_suffix(name: Option<&str>) -> String {
    name.map(|n| format!(" ('{n}')")).unwrap_or_default()
}

/// State of one import.
pub(crate) struct Importer<'a> {
    pub path: PathBuf,
    pub base_dir: Option<&'a Path>,
    pub options: &'a ImportOptions,
    pub warnings: Vec<String>,
    pub doc: std::rc::Rc<gltf::Document>,
    /// The raw JSON, for reading node transforms in full `f64` precision.
    pub raw: serde_json::Value,
    pub buffers: Vec<Vec<u8>>,
    pub bytes_loaded: u64,
    pub textures: Vec<Texture>,
    /// (image index, sRGB) → index into `textures`.
    pub texture_cache: HashMap<(usize, bool), u32>,
    pub texels_used: u64,
    pub materials: Vec<Material>,
    pub uses_default_material: bool,
    pub geometry: Geometry,
    pub lights: Vec<WorldLight>,
    pub cameras: Vec<SceneCamera>,
    /// The node instances that contributed triangles ([`Scene::objects`]).
    pub objects: Vec<crate::scene::SceneObject>,
}

impl Importer<'_> {
    /// An import error naming the scene file.
    pub fn error(&self, message: impl Into<String>) -> PathTracerError {
        PathTracerError::import(&self.path, message)
    }

    /// Records a warning (kept in [`Scene::warnings`] and logged).
    pub fn warn(&mut self, message: impl Into<String>) {
        let message = message.into();
        tracing::warn!(file = %self.path.display(), "{message}");
        self.warnings.push(message);
    }

    /// Reads the bytes a `uri` points to (a `data:` URI or a file beside the scene), counting
    /// them against the byte budget. `what` names the referencing object for messages.
    pub fn read_uri(&mut self, uri: &str, what: &str) -> Result<Vec<u8>, PathTracerError> {
        let target = uri::resolve(uri, self.base_dir).map_err(|e| self.error(format!("{what}: {e}")))?;
        let bytes = match target {
            uri::UriTarget::Data { bytes, .. } => bytes,
            uri::UriTarget::File(file) => {
                let base = self.base_dir.unwrap_or(Path::new(""));
                check_inside(base, uri, &file, self.options.allow_outside).map_err(|m| self.error(format!("{what}: {m}")))?;
                let left = self.options.max_buffer_bytes.saturating_sub(self.bytes_loaded);
                return match read_limited(&file, left) {
                    Ok(bytes) => {
                        self.charge_bytes(bytes.len() as u64, what)?;
                        Ok(bytes)
                    }
                    Err(ReadFailure::TooLarge(len)) => Err(self.over_limit(len, what)),
                    Err(ReadFailure::Io(e)) => Err(self.error(format!("{what}: cannot read '{}': {e}", file.display()))),
                };
            }
        };
        self.charge_bytes(bytes.len() as u64, what)?;
        Ok(bytes)
    }

    fn charge_bytes(&mut self, len: u64, what: &str) -> Result<(), PathTracerError> {
        self.bytes_loaded = self.bytes_loaded.saturating_add(len);
        if self.bytes_loaded > self.options.max_buffer_bytes {
            return Err(self.over_limit(len, what));
        }
        Ok(())
    }

    fn over_limit(&self, len: u64, what: &str) -> PathTracerError {
        self.error(format!("{what}: loading {len} bytes exceeds the import limit of {} bytes", self.options.max_buffer_bytes))
    }

    /// Loads every buffer: the GLB BIN chunk, `data:` URIs and external files.
    fn load_buffers(&mut self, bin: Option<&[u8]>) -> Result<(), PathTracerError> {
        let sources: Vec<(usize, Option<String>, u64)> = self
            .doc
            .as_json()
            .buffers
            .iter()
            .enumerate()
            .map(|(i, b)| (i, b.uri.clone(), b.byte_length.0))
            .collect();
        for (i, uri, byte_length) in sources {
            let what = format!("buffer {i}");
            let mut data = match uri {
                Some(uri) => self.read_uri(&uri, &what)?,
                None => match bin {
                    Some(bin) if i == 0 => bin.to_vec(),
                    _ => {
                        return Err(self.error(format!(
                            "{what} has no uri and the file has no GLB binary chunk for it"
                        )));
                    }
                },
            };
            if (data.len() as u64) < byte_length {
                return Err(self.error(format!(
                    "{what}: byteLength is {byte_length} but only {} bytes were found",
                    data.len()
                )));
            }
            // The buffer is its first `byteLength` bytes (a GLB binary chunk is padded to 4
            // bytes, a file may be longer): a bufferView reaching past `byteLength` is out of
            // range, as glTF-Validator reports it, instead of reading the bytes beyond.
            data.truncate(usize::try_from(byte_length).unwrap_or(usize::MAX));
            self.buffers.push(data);
        }
        Ok(())
    }

    /// The texture for glTF image `image`, decoding it on first use.
    pub fn texture_for_image(&mut self, image: usize, srgb: bool) -> Result<u32, PathTracerError> {
        if let Some(&t) = self.texture_cache.get(&(image, srgb)) {
            return Ok(t);
        }
        let source = self.doc.as_json().images.get(image).map(|im| (im.uri.clone(), im.buffer_view.map(|v| v.value())));
        // A file image is named by its URI too (the file a user would open), an embedded one
        // by its buffer view; long `data:` URIs are not quoted.
        let what = match &source {
            Some((Some(uri), _)) if !uri.starts_with("data:") => format!("image {image} ('{uri}')"),
            Some((None, Some(view))) => format!("image {image} (bufferView {view})"),
            _ => format!("image {image}"),
        };
        let bytes = match source {
            Some((Some(uri), _)) => self.read_uri(&uri, &what)?,
            Some((None, Some(view))) => accessor::view_bytes(self.doc.as_json(), &self.buffers, view)
                .map_err(|e| self.error(format!("{what}: {e}")))?
                .0
                .to_vec(),
            Some((None, None)) => return Err(self.error(format!("{what} has neither uri nor bufferView"))),
            None => return Err(self.error(format!("{what} does not exist"))),
        };
        let budget = self.options.max_texture_texels.saturating_sub(self.texels_used);
        let texture = textures::decode(&bytes, srgb, budget).map_err(|e| self.error(format!("{what}: {e}")))?;
        self.texels_used += u64::from(texture.width) * u64::from(texture.height);
        let index = u32::try_from(self.textures.len()).map_err(|_| self.error("too many textures"))?;
        self.textures.push(texture);
        self.texture_cache.insert((image, srgb), index);
        Ok(index)
    }
}

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_skin;
