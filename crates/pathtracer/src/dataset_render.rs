//! Rendering a scene into a dataset folder (the layout of `docs/design.md`, "The dataset
//! folder"; its types are [`crate::dataset_folder`]'s), with resume and progress.
//!
//! For every view of the rig (see [`crate::rig`]) the driver writes, atomically:
//! `<split>/r_<k>.png` (8-bit sRGB RGBA, straight alpha), `<split>/r_<k>.exr` (linear RGBA,
//! premultiplied), `<split>/r_<k>_gt.exr` (z-depth, distance, world normal, alpha at the
//! pixel-centre ray), `<split>/r_<k>_depth.npy` (z-depth in metres) and nerfstudio's
//! `<split>/r_<k>_depth_mm.npy` and `<split>/r_<k>_mask.png`. The resolved settings
//! go to `render_config.json` before the first view; the transforms files
//! (`transforms_{train,val,test}.json` with the scene facts, nerfstudio's `transforms.json`) are
//! written last.
//!
//! Resume: a view whose files all exist and read back whole at the view's size is kept, the
//! others (a damaged file included) are rendered. Every view's
//! randomness is keyed by (seed, split, view index) only ([`view_key`]), so a resumed dataset is
//! byte-identical to an uninterrupted one, whatever the thread count. A folder holding a dataset
//! rendered with different settings (or another environment map: its bytes are hashed into
//! `render_config.json`) is refused unless [`RunOptions::force`] is set.
//!
//! The folder's life cycle (which files a view has, refusing or replacing another dataset,
//! stale temporaries, writing a view's files) is the dataset crate's ([`dataset::folder`]);
//! this module decides what to render and records the renderer's identity.
//!
//! The renderer enters through the [`ViewRenderer`] trait: [`render_dataset`] loads the glTF and
//! uses the path tracer; [`render_dataset_with`] takes any implementation (tests use an
//! analytic one).

use crate::PathTracerError;
use crate::dataset_folder::{
    DatasetSummary, RenderRecord, SceneSource, Shard, ViewImages, ViewRenderer, describe_difference, view_files, view_key, write_manifest,
};
use crate::dataset_folder::rig_for;
use crate::rig::Rig;
use crate::scene::Scene;
use dataset::{Camera, FrameRecord, GroundTruth, SceneFacts, SplitKind};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

/// The driver's settings, options and progress reports (defined with the folder's other types).
pub use crate::dataset_folder::{Background, DatasetRenderConfig, Preset, ProgressEvent, RENDER_CONFIG_FILE, RunOptions, parse_rgb};

/// Loads the glTF scene at `scene_path`, places the cameras and renders the dataset into `out`
/// with the path tracer (see the module documentation). Nothing is written when the options
/// are impossible or the scene cannot be loaded.
pub fn render_dataset(
    scene_path: &Path,
    out: &Path,
    cfg: &DatasetRenderConfig,
    opts: &RunOptions,
    progress: &mut dyn FnMut(ProgressEvent),
    cancel: &AtomicBool,
) -> Result<DatasetSummary, PathTracerError> {
    render_dataset_sharded(scene_path, out, cfg, opts, None, progress, cancel)
}

/// [`render_dataset`], or with `shard` only that shard's views and its manifest instead of the
/// transforms files ([`crate::shard`]).
pub(crate) fn render_dataset_sharded(
    scene_path: &Path,
    out: &Path,
    cfg: &DatasetRenderConfig,
    opts: &RunOptions,
    shard: Option<Shard>,
    progress: &mut dyn FnMut(ProgressEvent),
    cancel: &AtomicBool,
) -> Result<DatasetSummary, PathTracerError> {
    cfg.validate()?;
    let import = crate::import::ImportOptions { allow_outside: opts.allow_outside, ..crate::import::ImportOptions::default() };
    let source = SceneSource::from_scene_with(scene_path, &import)?;
    let scene = crate::import::load_gltf(scene_path, &import)?;
    // The import logged its warnings (naming the file) as it found them.
    let mut renderer = crate::render::Renderer::new(scene, &crate::accel::AccelParams::medium_build())?;
    let settings = crate::render::RenderSettings {
        spp: cfg.spp,
        max_bounces: cfg.max_bounces,
        seed: cfg.seed,
        environment: cfg.environment,
        transparent_background: cfg.background != Background::Environment,
        environment_map: cfg.environment_map.clone(),
    };
    settings.validate()?;
    renderer.load_environment_map(&settings)?;
    let adapter = PathTracer { renderer: &renderer, settings };
    render_dataset_part(renderer.scene(), &source, &adapter, out, cfg, opts, shard, progress, cancel)
}

/// The path tracer behind [`ViewRenderer`].
struct PathTracer<'a> {
    renderer: &'a crate::render::Renderer,
    settings: crate::render::RenderSettings,
}

impl ViewRenderer for PathTracer<'_> {
    fn render_view(&self, camera: &Camera, view_key: u32) -> Result<ViewImages, PathTracerError> {
        let v = self.renderer.render_view(camera, view_key, &self.settings);
        if v.nonfinite_samples > 0 {
            tracing::warn!("view {view_key:#x}: {} non-finite radiance samples replaced by zero", v.nonfinite_samples);
        }
        Ok(ViewImages { color: v.color, ground_truth: v.ground_truth, samples: v.samples })
    }
    fn is_view_dependent(&self) -> bool {
        self.renderer.is_view_dependent()
    }
    fn labels(&self, camera: &Camera, view_key: u32) -> Result<Option<dataset::labels::ViewLabels>, PathTracerError> {
        Ok(Some(self.renderer.labels(camera, view_key, &self.settings)))
    }
}

/// [`render_dataset`] with any renderer: `scene` places the cameras and supplies the facts,
/// `source` identifies it in `render_config.json`.
#[allow(clippy::too_many_arguments)]
pub fn render_dataset_with(
    scene: &Scene,
    source: &SceneSource,
    renderer: &dyn ViewRenderer,
    out: &Path,
    cfg: &DatasetRenderConfig,
    opts: &RunOptions,
    progress: &mut dyn FnMut(ProgressEvent),
    cancel: &AtomicBool,
) -> Result<DatasetSummary, PathTracerError> {
    render_dataset_part(scene, source, renderer, out, cfg, opts, None, progress, cancel)
}

/// [`render_dataset_with`] for every view (`shard` `None`: then the transforms files are written
/// last) or one shard's views (then `shard.json` is).
#[allow(clippy::too_many_arguments)]
pub(crate) fn render_dataset_part(
    scene: &Scene,
    source: &SceneSource,
    renderer: &dyn ViewRenderer,
    out: &Path,
    cfg: &DatasetRenderConfig,
    opts: &RunOptions,
    shard: Option<Shard>,
    progress: &mut dyn FnMut(ProgressEvent),
    cancel: &AtomicBool,
) -> Result<DatasetSummary, PathTracerError> {
    cfg.validate()?;
    if opts.threads == Some(0) {
        return Err(PathTracerError::Config("--threads 0: at least one thread is needed".into()));
    }
    let rig = rig_for(scene, cfg)?;
    for (what, count) in [("objects (node instances with triangles)", scene.object_count()), ("materials", scene.materials.len())] {
        if count > dataset::labels::MAX_LABEL {
            return Err(PathTracerError::Config(format!(
                "{}: {count} {what}, more than the {} a view's 16-bit label files can number",
                scene.name,
                dataset::labels::MAX_LABEL
            )));
        }
    }
    let environment_map = cfg.environment_map.as_deref().map(SceneSource::from_file).transpose()?;
    let camera_path = cfg.camera_path.as_deref().map(SceneSource::from_file).transpose()?;
    let record = RenderRecord {
        scene: source.clone(),
        renderer: crate::version::renderer_version().to_string(),
        rig_resolved: rig.kind,
        config: cfg.clone(),
        environment_map,
        camera_path,
    };
    let pool = match opts.threads {
        Some(n) => Some(
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| PathTracerError::Config(format!("cannot start {n} threads: {e}")))?,
        ),
        None => None,
    };
    prepare_folder(out, &record, opts.force)?;
    dataset::io::atomic_write_json(&out.join(RENDER_CONFIG_FILE), &record)?;

    let start = std::time::Instant::now();
    let mine = |p: usize| shard.is_none_or(|s| s.owns(p as u64));
    // The views an earlier run finished, read back whole (their ground truth kept for the
    // distance range); a view with a damaged file is rendered again.
    let mut kept: std::collections::HashMap<(SplitKind, u32), GroundTruth> = std::collections::HashMap::new();
    for (split, k, camera) in rig.views().enumerate().filter(|(p, _)| mine(*p)).map(|(_, v)| v) {
        if dataset::folder::view_complete(out, split, k) {
            let files = view_files(split, k).map(|f| out.join(f));
            let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
            match dataset::folder::check_view(&files, w, h) {
                Ok(gt) => {
                    kept.insert((split, k), gt);
                }
                Err(e) => tracing::warn!("{e}: rendering view {} {k} again", split.name()),
            }
        }
    }
    let reused = kept.len() as u64;
    let total = rig.views().enumerate().filter(|(p, _)| mine(*p)).count() as u64;
    progress(ProgressEvent::Started { total, reused, rig: rig.kind });

    let mut range = DistanceRange::default();
    let mut samples = 0u64;
    for (split, k, camera) in rig.views().enumerate().filter(|(p, _)| mine(*p)).map(|(_, v)| v) {
        let files = view_files(split, k).map(|f| out.join(f));
        if let Some(gt) = kept.remove(&(split, k)) {
            range.add(&gt);
            // A kept view without (whole) label files, e.g. one rendered before they existed,
            // gets them without rendering its images again.
            let labels = dataset::labels::label_files(split, k).map(|f| out.join(f));
            let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
            if dataset::labels::read_labels(&labels, w, h).is_err() {
                if cancel.load(Ordering::SeqCst) {
                    return Err(PathTracerError::Interrupted);
                }
                let key = view_key(split, k);
                let computed = match &pool {
                    Some(p) => p.install(|| renderer.labels(camera, key))?,
                    None => renderer.labels(camera, key)?,
                };
                if let Some(l) = computed {
                    dataset::labels::write_labels(&labels, &l)?;
                }
            }
            continue;
        }
        if cancel.load(Ordering::SeqCst) {
            return Err(PathTracerError::Interrupted);
        }
        let key = view_key(split, k);
        let view = match &pool {
            Some(p) => p.install(|| renderer.render_view(camera, key))?,
            None => renderer.render_view(camera, key)?,
        };
        check_view(&view, camera, &files[0])?;
        let labels = match &pool {
            Some(p) => p.install(|| renderer.labels(camera, key))?,
            None => renderer.labels(camera, key)?,
        };
        if let Some(l) = labels {
            dataset::labels::write_labels(&dataset::labels::label_files(split, k).map(|f| out.join(f)), &l)?;
        }
        write_view(&files, &view, cfg.background)?;
        range.add(&view.ground_truth);
        samples += view.samples;
        progress(ProgressEvent::ViewRendered { split, index: k, samples: view.samples });
    }

    let facts = scene_facts(scene, &rig, &range, renderer.is_view_dependent(), &record)?;
    match shard {
        Some(s) => write_manifest(out, cfg, s)?,
        None => {
            write_transforms(out, &rig, &facts)?;
            let manifest = out.join(dataset::folder::SHARD_MANIFEST_FILE);
            if manifest.is_file() {
                // A former shard folder now holds the whole dataset.
                std::fs::remove_file(&manifest).map_err(|e| dataset::DatasetError::write(&manifest, e))?;
            }
        }
    }
    Ok(DatasetSummary {
        out: out.to_path_buf(),
        rig: rig.kind,
        views_total: total,
        views_rendered: total - reused,
        views_reused: reused,
        samples,
        seconds: start.elapsed().as_secs_f64(),
        facts,
    })
}

/// Checks `out` can receive this dataset ([`dataset::folder::prepare`]): empty, missing, or
/// holding a dataset with the same [`RenderRecord`]. With `force`, a different dataset's files
/// are removed first.
fn prepare_folder(out: &Path, record: &RenderRecord, force: bool) -> Result<(), PathTracerError> {
    let difference = |old: &RenderRecord| (!old.same_output(record)).then(|| describe_difference(old, record));
    Ok(dataset::folder::prepare(out, difference, force)?)
}

/// Checks a renderer's output has the camera's size (a broken renderer must not write files
/// the dataset loader then rejects).
fn check_view(view: &ViewImages, camera: &Camera, path: &Path) -> Result<(), PathTracerError> {
    let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
    let n = w as usize * h as usize;
    let gt = &view.ground_truth;
    let ok = view.color.width == w
        && view.color.height == h
        && view.color.data.len() == 4 * n
        && (gt.width, gt.height) == (w, h)
        && gt.depth.len() == n
        && gt.distance.len() == n
        && gt.alpha.len() == n
        && gt.normal.len() == 3 * n;
    if ok {
        Ok(())
    } else {
        Err(PathTracerError::Config(format!(
            "{}: renderer returned images of the wrong size (expected {w}x{h})",
            path.display()
        )))
    }
}

fn write_view(files: &[PathBuf; 6], view: &ViewImages, background: Background) -> Result<(), PathTracerError> {
    let bg = match background {
        Background::Color(c) => Some(c),
        Background::Transparent | Background::Environment => None,
    };
    Ok(dataset::folder::write_view(files, &view.color, &view.ground_truth, bg)?)
}

/// Smallest and largest hit distance over all views.
#[derive(Clone, Copy, Debug)]
struct DistanceRange {
    min: f64,
    max: f64,
}

impl Default for DistanceRange {
    fn default() -> Self {
        Self { min: f64::INFINITY, max: 0.0 }
    }
}

impl DistanceRange {
    fn add(&mut self, gt: &GroundTruth) {
        for (&d, &a) in gt.distance.iter().zip(&gt.alpha) {
            if a > 0.0 && d > 0.0 && d.is_finite() {
                self.min = self.min.min(d as f64);
                self.max = self.max.max(d as f64);
            }
        }
    }
}

/// Scene facts: the true world bounding box; `near` = 0.9 × the smallest hit distance over all
/// views (at least 1e-4 × the bounds' diagonal); `far` = the largest hit distance × 1.1, capped
/// at 1.01 × the distance from a camera to the farthest corner of the bounds (never below the
/// largest hit). With no hit at all, both come from the bounds alone.
fn scene_facts(
    scene: &Scene,
    rig: &Rig,
    range: &DistanceRange,
    view_dependent: bool,
    record: &RenderRecord,
) -> Result<SceneFacts, PathTracerError> {
    let lo = scene.origin + scene.bounds.min.as_dvec3();
    let hi = scene.origin + scene.bounds.max.as_dvec3();
    let diag = (hi - lo).length();
    let mut corner_max = 0.0f64;
    let mut box_min = f64::INFINITY;
    for (_, _, cam) in rig.views() {
        let o = cam.origin();
        let far_corner = (o - lo).abs().max((o - hi).abs());
        corner_max = corner_max.max(far_corner.length());
        box_min = box_min.min((o.clamp(lo, hi) - o).length());
    }
    let (near, far) = if range.max > 0.0 {
        (0.9 * range.min, (1.1 * range.max).min(1.01 * corner_max).max(range.max))
    } else {
        (0.9 * box_min, 1.01 * corner_max)
    };
    let mut render = serde_json::to_value(&record.config)
        .map_err(|e| PathTracerError::Config(format!("cannot record settings: {e}")))?;
    render["rig_resolved"] = serde_json::Value::String(record.rig_resolved.name().into());
    Ok(SceneFacts {
        scene: scene.name.clone(),
        aabb_min: lo.to_array(),
        aabb_max: hi.to_array(),
        near: near.max(1e-4 * diag),
        far,
        view_dependent,
        render,
        renderer: record.renderer.clone(),
        objects: object_facts(scene),
        materials: scene.materials.iter().enumerate().map(|(k, m)| dataset::MaterialFacts { id: k as u32 + 1, name: m.name.clone() }).collect(),
    })
}

/// The scene's objects as the label files number them ([`crate::scene::Scene::object_of`]):
/// for a scene without object records, the whole mesh as one.
fn object_facts(scene: &Scene) -> Vec<dataset::ObjectFacts> {
    let m = &scene.mesh;
    let whole = [crate::scene::SceneObject { node: 0, name: None, mesh: 0, mesh_name: None, first_triangle: 0, triangles: m.indices.len() as u32 }];
    let objects = if scene.objects.is_empty() { &whole[..] } else { &scene.objects[..] };
    objects
        .iter()
        .enumerate()
        .map(|(k, o)| {
            let range = o.first_triangle as usize..(o.first_triangle as usize + o.triangles as usize).min(m.indices.len());
            let (mut lo, mut hi, mut area) = (glam::DVec3::INFINITY, glam::DVec3::NEG_INFINITY, 0.0f64);
            let mut materials = std::collections::BTreeSet::new();
            for t in range.clone() {
                let p = m.indices[t].map(|i| m.positions.get(i as usize).copied().unwrap_or_default().as_dvec3() + scene.origin);
                for q in p {
                    lo = lo.min(q);
                    hi = hi.max(q);
                }
                area += 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length();
                materials.insert(m.material.get(t).copied().unwrap_or(0) + 1);
            }
            let (lo, hi) = if range.is_empty() { (scene.origin, scene.origin) } else { (lo, hi) };
            dataset::ObjectFacts {
                id: k as u32 + 1,
                node: o.node,
                name: o.name.clone(),
                mesh: o.mesh,
                mesh_name: o.mesh_name.clone(),
                materials: materials.into_iter().collect(),
                triangles: range.len() as u64,
                area,
                aabb_min: lo.to_array(),
                aabb_max: hi.to_array(),
            }
        })
        .collect()
}

/// The frame records of one split.
pub fn frame_records(split: SplitKind, cameras: &[Camera]) -> Vec<FrameRecord> {
    cameras
        .iter()
        .enumerate()
        .map(|(k, cam)| {
            let stem = format!("{}/r_{k}", split.name());
            FrameRecord {
                file_path: format!("./{stem}"),
                transform_matrix: cam.rows(),
                depth_file_path: Some(format!("{stem}_depth.npy")),
                gt_file_path: Some(format!("{stem}_gt.exr")),
                exr_file_path: Some(format!("{stem}.exr")),
            }
        })
        .collect()
}

fn write_transforms(out: &Path, rig: &Rig, facts: &SceneFacts) -> Result<(), PathTracerError> {
    let mut all = Vec::new();
    for split in SplitKind::ALL {
        let recs = frame_records(split, rig.split(split));
        dataset::write_split_transforms(out, split, &rig.intrinsics, recs.clone(), Some(facts.clone()))?;
        all.push((split, recs));
    }
    dataset::write_nerfstudio_transforms(out, &rig.intrinsics, &all)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset_folder::*;
    use crate::rig::build_rig;
    use dataset::RgbaImage;
    use crate::scene::{Aabb, Material, Mesh};
    use glam::{DVec3, Vec3};

    /// A scene whose only geometry is the corners of a box (the driver needs only bounds).
    fn scene() -> Scene {
        let positions = vec![Vec3::new(-0.5, -0.4, -0.3), Vec3::new(0.5, 0.4, 0.3), Vec3::new(0.5, -0.4, 0.3)];
        let bounds = positions.iter().fold(Aabb::EMPTY, |a, p| a.union_point(*p));
        Scene {
            name: "box".into(),
            origin: DVec3::new(1.0, 2.0, 3.0),
            mesh: Mesh { positions, indices: vec![[0, 1, 2]], material: vec![0], ..Default::default() },
            materials: vec![Material::gltf_default()],
            textures: vec![],
            lights: vec![],
            cameras: vec![],
            bounds,
            warnings: vec![],
            objects: vec![],
        }
    }

    /// Exact analytic renderer: a sphere of radius 0.4 at the scene centre. Colour is a hash of
    /// (key, pixel) so any change of key shows; parallel over rows to exercise thread pools.
    struct SphereRenderer {
        centre: DVec3,
    }

    impl ViewRenderer for SphereRenderer {
        fn render_view(&self, cam: &Camera, key: u32) -> Result<ViewImages, PathTracerError> {
            use rayon::prelude::*;
            let (w, h) = (cam.intrinsics.width, cam.intrinsics.height);
            let rows: Vec<(Vec<f32>, Vec<[f32; 6]>)> = (0..h)
                .into_par_iter()
                .map(|j| {
                    let mut c = Vec::new();
                    let mut g = Vec::new();
                    for i in 0..w {
                        let r = cam.pixel_center_ray(i, j);
                        let oc = r.origin - self.centre;
                        let b = oc.dot(r.direction);
                        let disc = b * b - (oc.length_squared() - 0.16);
                        let t = if disc > 0.0 { -b - disc.sqrt() } else { 0.0 };
                        let a = if t > 0.0 { 1.0 } else { 0.0 };
                        let v = (crate::rig::split_index(SplitKind::Train) as u32 + key * 31 + i * 7 + j) % 17;
                        let v = a * v as f32 / 16.0;
                        c.extend_from_slice(&[v, 0.5 * v, 0.25, a]);
                        let n = if a > 0.0 { (oc + t * r.direction).normalize().as_vec3() } else { Vec3::ZERO };
                        let depth = cam.z_depth_from_distance(i as f64 + 0.5, j as f64 + 0.5, t) as f32;
                        g.push([depth * a, t as f32 * a, n.x, n.y, n.z, a]);
                    }
                    (c, g)
                })
                .collect();
            let mut color = RgbaImage::new(w, h);
            color.data = rows.iter().flat_map(|r| r.0.clone()).collect();
            let g: Vec<[f32; 6]> = rows.into_iter().flat_map(|r| r.1).collect();
            let ground_truth = GroundTruth {
                width: w,
                height: h,
                depth: g.iter().map(|x| x[0]).collect(),
                distance: g.iter().map(|x| x[1]).collect(),
                normal: g.iter().flat_map(|x| [x[2], x[3], x[4]]).collect(),
                alpha: g.iter().map(|x| x[5]).collect(),
            };
            Ok(ViewImages { color, ground_truth, samples: w as u64 * h as u64 * 4 })
        }
        fn is_view_dependent(&self) -> bool {
            false
        }
    }

    fn tmp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("pt-dsr-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    fn tiny() -> DatasetRenderConfig {
        DatasetRenderConfig { width: 12, height: 10, train: 3, val: 2, test: 2, spp: 4, ..DatasetRenderConfig::preset(Preset::Quick) }
    }

    fn run(out: &Path, cfg: &DatasetRenderConfig, threads: usize, force: bool) -> Result<DatasetSummary, PathTracerError> {
        let s = scene();
        let r = SphereRenderer { centre: s.origin };
        let src = SceneSource { path: "box.gltf".into(), hash: "1".into() };
        let opts = RunOptions { threads: Some(threads), force, allow_outside: false };
        render_dataset_with(&s, &src, &r, out, cfg, &opts, &mut |_| {}, &AtomicBool::new(false))
    }

    use test_support::files;

    #[test]
    fn writes_the_layout_resumes_identically_and_loads_back() {
        let (a, b) = (tmp("a"), tmp("b"));
        let cfg = tiny();
        let sum = run(&a, &cfg, 1, false).unwrap();
        assert_eq!((sum.views_total, sum.views_rendered, sum.views_reused), (7, 7, 0));
        run(&b, &cfg, 2, false).unwrap();
        let fa = files(&a);
        // 7 views × 6 files + 3 split files + transforms.json + render_config.json.
        assert_eq!(fa.len(), 7 * 6 + 5);
        assert_eq!(fa, files(&b), "thread count changed the output");

        // Delete one view's PNG and another's GT, and damage three more views' files (an EXR
        // cut short, a PNG of garbage, a depth array one value short): the rerun renders just
        // those five.
        std::fs::remove_file(b.join("val/r_1.png")).unwrap();
        std::fs::remove_file(b.join("train/r_0_gt.exr")).unwrap();
        let exr = std::fs::read(b.join("train/r_1.exr")).unwrap();
        std::fs::write(b.join("train/r_1.exr"), &exr[..exr.len() / 2]).unwrap();
        std::fs::write(b.join("test/r_0.png"), b"not a png").unwrap();
        let npy = std::fs::read(b.join("val/r_0_depth.npy")).unwrap();
        std::fs::write(b.join("val/r_0_depth.npy"), &npy[..npy.len() - 4]).unwrap();
        std::fs::remove_file(b.join("transforms.json")).unwrap();
        std::fs::write(b.join("val/.r_1.png.99999.tmp"), b"half a png").unwrap();
        let mut events = Vec::new();
        let s = scene();
        let src = SceneSource { path: "elsewhere/box.gltf".into(), hash: "1".into() };
        let opts = RunOptions { threads: Some(2), force: false, allow_outside: false };
        let r = SphereRenderer { centre: s.origin };
        let sum = render_dataset_with(&s, &src, &r, &b, &cfg, &opts, &mut |e| events.push(e), &AtomicBool::new(false)).unwrap();
        assert_eq!((sum.views_rendered, sum.views_reused), (5, 2));
        assert_eq!(events.len(), 1 + 5, "Started, then one ViewRendered per view rendered");
        let fb: Vec<_> = files(&b).into_iter().filter(|f| f.0 != RENDER_CONFIG_FILE).collect();
        let fa2: Vec<_> = fa.iter().filter(|f| f.0 != RENDER_CONFIG_FILE).cloned().collect();
        assert_eq!(fa2, fb, "resumed output differs");

        // The dataset loader reads it back with our cameras and facts.
        let ds = dataset::Dataset::load(&a).unwrap();
        let rig = build_rig(&scene(), &cfg.rig_config()).unwrap();
        for split in SplitKind::ALL {
            for (f, c) in ds.split(split).iter().zip(rig.split(split)) {
                assert!((f.camera.c2w - c.c2w).abs().to_cols_array().iter().all(|d| *d < 1e-12));
                assert_eq!(f.camera.intrinsics, c.intrinsics);
            }
        }
        let facts = ds.facts.unwrap();
        for (got, want) in facts.aabb_min.iter().chain(&facts.aabb_max).zip([0.5, 1.6, 2.7, 1.5, 2.4, 3.3]) {
            assert!((got - want).abs() < 1e-6, "bounds {:?} {:?}", facts.aabb_min, facts.aabb_max);
        }
        // The sphere of radius 0.4 at the centre: near ≈ 0.9 × (camera distance − 0.4).
        let d = (rig.splits[0][0].origin() - scene().origin).length();
        assert!((facts.near - 0.9 * (d - 0.4)).abs() < 0.02 * d, "near {} vs {}", facts.near, d - 0.4);
        assert!(facts.far > d && facts.far < 1.1 * (d + 0.4) + 1e-9);
        assert_eq!(facts.render["spp"], 4);
        assert_eq!(facts.render["rig_resolved"], "sphere");

        // Ground truth and display colour as specified.
        let f = &ds.val[1];
        let gt = dataset::read_ground_truth(f.gt_path.as_ref().unwrap()).unwrap();
        let png = dataset::read_png_rgba(&f.image_path).unwrap();
        let exr = dataset::read_exr_rgba(f.exr_path.as_ref().unwrap()).unwrap();
        assert!(gt.alpha.iter().any(|a| *a > 0.0) && gt.alpha.contains(&0.0));
        for k in 0..gt.alpha.len() {
            let a = exr.data[4 * k + 3];
            assert_eq!(png.data[4 * k + 3], a);
            if a > 0.0 {
                let want = dataset::linear_to_srgb(exr.data[4 * k] / a);
                assert!((png.data[4 * k] - want).abs() <= 0.5 / 255.0 + 1e-6);
            }
        }
        for d in [&a, &b] {
            std::fs::remove_dir_all(d).unwrap();
        }
    }

    #[test]
    fn the_environment_map_content_is_part_of_the_identity() {
        let out = tmp("envmap");
        let maps = tmp("envmap-files");
        std::fs::create_dir_all(&maps).unwrap();
        let (a, a_copy, b) = (maps.join("a.hdr"), maps.join("a_copy.hdr"), maps.join("b.hdr"));
        std::fs::write(&a, "sky a").unwrap();
        std::fs::write(&a_copy, "sky a").unwrap();
        std::fs::write(&b, "sky b").unwrap();
        let with = |p: &Path| DatasetRenderConfig { environment_map: Some(p.to_path_buf()), ..tiny() };
        let missing = with(&maps.join("none.exr"));
        let e = run(&out, &missing, 1, false).unwrap_err().to_string();
        assert!(e.contains("none.exr") && e.contains("does not exist"), "{e}");
        assert!(!out.exists());
        run(&out, &with(&a), 1, false).unwrap();
        let rec: RenderRecord = serde_json::from_slice(&std::fs::read(out.join(RENDER_CONFIG_FILE)).unwrap()).unwrap();
        assert_eq!(rec.environment_map.as_ref().map(|m| m.hash.clone()), Some(format!("{:016x}", fnv1a(FNV_OFFSET, b"sky a"))));
        // The same content under another path resumes (nothing to render).
        assert_eq!(run(&out, &with(&a_copy), 1, false).unwrap().views_rendered, 0);
        // Another map, or none, is refused.
        let e = run(&out, &with(&b), 1, false).unwrap_err().to_string();
        assert!(e.contains("environment map") && e.contains("b.hdr"), "{e}");
        let e = run(&out, &tiny(), 1, false).unwrap_err().to_string();
        assert!(e.contains("environment map"), "{e}");
        // Editing the file in place is noticed too.
        std::fs::write(&a, "sky a, edited").unwrap();
        assert!(run(&out, &with(&a), 1, false).is_err());
        // Records written before the field existed read as "no map".
        let old = r#"{"scene":{"path":"s","hash":"1"},"renderer":"r","rig_resolved":"sphere","config":"#.to_string()
            + &serde_json::to_string(&tiny()).unwrap().replace(",\"environment_map\":null", "")
            + "}";
        let rec: RenderRecord = serde_json::from_str(&old).unwrap();
        assert_eq!((rec.environment_map, rec.config.environment_map), (None, None));
        std::fs::remove_dir_all(&out).unwrap();
        std::fs::remove_dir_all(&maps).unwrap();
    }

    #[test]
    fn refuses_other_settings_and_impossible_options() {
        let out = tmp("c");
        let cfg = tiny();
        for bad in [
            DatasetRenderConfig { width: 0, ..cfg.clone() },
            DatasetRenderConfig { train: 0, ..cfg.clone() },
            DatasetRenderConfig { spp: 0, ..cfg.clone() },
            DatasetRenderConfig { background: Background::Color([f32::NAN, 0.0, 0.0]), ..cfg.clone() },
        ] {
            assert!(matches!(run(&out, &bad, 1, false), Err(PathTracerError::Config(_))));
            assert!(!out.exists(), "an impossible option wrote something");
        }
        run(&out, &cfg, 1, false).unwrap();
        std::fs::write(out.join("notes.txt"), "mine").unwrap();
        let other = DatasetRenderConfig { spp: 8, ..cfg.clone() };
        let e = run(&out, &other, 1, false).unwrap_err().to_string();
        assert!(e.contains("spp was 4, now 8") && e.contains("--force"), "{e}");
        let sum = run(&out, &other, 1, true).unwrap();
        assert_eq!(sum.views_reused, 0);
        assert!(out.join("notes.txt").is_file(), "--force removed a file it does not own");
        // Cancelled before the first view: interrupted, the view files are absent.
        let out2 = tmp("d");
        let s = scene();
        let r = SphereRenderer { centre: s.origin };
        let src = SceneSource { path: "box.gltf".into(), hash: "1".into() };
        let opts = RunOptions { threads: Some(1), force: false, allow_outside: false };
        let e = render_dataset_with(&s, &src, &r, &out2, &cfg, &opts, &mut |_| {}, &AtomicBool::new(true));
        assert!(matches!(e, Err(PathTracerError::Interrupted)));
        assert!(!out2.join("train/r_0.png").exists());
        std::fs::remove_dir_all(&out).unwrap();
        std::fs::remove_dir_all(&out2).unwrap();
    }

    #[test]
    fn parsing_and_names() {
        assert_eq!("transparent".parse::<Background>().unwrap(), Background::Transparent);
        assert_eq!("1, 0.5,0".parse::<Background>().unwrap(), Background::Color([1.0, 0.5, 0.0]));
        assert!("1,2".parse::<Background>().is_err());
        assert!("-1,0,0".parse::<Background>().is_err());
        assert_eq!("Quick".parse::<Preset>().unwrap(), Preset::Quick);
        for p in [Preset::Quick, Preset::Standard, Preset::Full] {
            assert_eq!(p.name().parse::<Preset>().unwrap(), p);
        }
        let full = DatasetRenderConfig::preset(Preset::Full);
        assert_eq!((full.width, full.height, full.spp), (800, 800, 128));
        assert_eq!(view_key(SplitKind::Test, 5), (2 << 24) | 5);
        assert_eq!(view_files(SplitKind::Val, 3)[2], "val/r_3_gt.exr");
    }
}
