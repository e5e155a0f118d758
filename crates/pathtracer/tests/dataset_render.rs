//! End-to-end dataset rendering with the real path tracer: file layout, loading back, exact
//! ground truth, thread-count independence, resume, refusal of impossible options, and every
//! committed scene at a tiny size.

use dataset::{Dataset, SplitKind};
use glam::{DVec3, Vec2, Vec3};
use pathtracer::dataset_folder::{DatasetSummary, SceneSource};
use pathtracer::dataset_render::{DatasetRenderConfig, Preset, RunOptions, render_dataset};
use pathtracer::import::{ImportOptions, load_gltf};
use pathtracer::rig::{RigKind, build_rig};
use pathtracer::PathTracerError;
use scenegen::{Light, Material, Mesh, SceneBuilder, Transform};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("pt-dataset-render-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// A 4 m ground quad at y = 0 with a 0.6 m cube standing on it at the origin, lit by a point
/// light; written as glTF into `dir`.
fn tiny_scene(dir: &Path) -> PathBuf {
    let mut s = SceneBuilder::new("tiny");
    let grey = s.add_material(Material::diffuse("grey", [0.5, 0.5, 0.5])).unwrap();
    let red = s.add_material(Material::diffuse("red", [0.8, 0.2, 0.1])).unwrap();
    s.add_mesh("ground", Mesh::quad(Vec2::new(4.0, 4.0), 1.0), grey, Transform::IDENTITY).unwrap();
    s.add_mesh("cube", Mesh::cuboid(Vec3::splat(0.3)), red, Transform::from_translation(Vec3::new(0.0, 0.3, 0.0)))
        .unwrap();
    s.add_light("bulb", Light::Point { color: [1.0; 3], intensity: 4.0 }, Transform::from_translation(Vec3::new(1.0, 2.0, 1.0)))
        .unwrap();
    let path = dir.join("tiny.gltf");
    s.write_gltf(&path).unwrap();
    path
}

fn tiny_config() -> DatasetRenderConfig {
    DatasetRenderConfig { width: 16, height: 16, train: 3, val: 2, test: 2, spp: 4, ..DatasetRenderConfig::preset(Preset::Quick) }
}

fn render(scene: &Path, out: &Path, cfg: &DatasetRenderConfig, threads: usize) -> Result<DatasetSummary, PathTracerError> {
    let opts = RunOptions { threads: Some(threads), force: false, allow_outside: false };
    render_dataset(scene, out, cfg, &opts, &mut |_| {}, &AtomicBool::new(false))
}

use test_support::files;

#[test]
fn tiny_dataset_is_complete_exact_deterministic_and_resumable() {
    let dir = tmp("tiny");
    let scene = tiny_scene(&dir);
    let cfg = tiny_config();
    let (a, b) = (dir.join("a"), dir.join("b"));
    let sum = render(&scene, &a, &cfg, 1).unwrap();
    assert_eq!((sum.views_total, sum.views_rendered, sum.rig), (7, 7, RigKind::Hemisphere));
    assert_eq!(sum.samples, 7 * 16 * 16 * 4);
    render(&scene, &b, &cfg, 2).unwrap();

    // Every file of the layout, and nothing else (no temporaries left behind).
    let fa = files(&a);
    let mut expected = vec![
        "render_config.json".to_string(),
        "transforms.json".into(),
        "transforms_test.json".into(),
        "transforms_train.json".into(),
        "transforms_val.json".into(),
    ];
    for (split, n) in [("train", 3), ("val", 2), ("test", 2)] {
        for k in 0..n {
            for suffix in [".png", ".exr", "_gt.exr", "_depth.npy", "_depth_mm.npy", "_mask.png", "_ids.png", "_material.png", "_coverage.npy"] {
                expected.push(format!("{split}/r_{k}{suffix}"));
            }
        }
    }
    expected.sort();
    assert_eq!(fa.iter().map(|f| f.0.clone()).collect::<Vec<_>>(), expected);
    assert!(fa == files(&b), "1 and 2 threads gave different files");

    // The loader reads it back with the rig's cameras.
    let ds = Dataset::load(&a).unwrap();
    let rig = build_rig(&load_gltf(&scene, &ImportOptions::default()).unwrap(), &cfg.rig_config()).unwrap();
    for split in SplitKind::ALL {
        assert_eq!(ds.split(split).len(), rig.split(split).len());
        for (f, c) in ds.split(split).iter().zip(rig.split(split)) {
            let d = (f.camera.c2w - c.c2w).abs().to_cols_array().into_iter().fold(0.0, f64::max);
            assert!(d < 1e-6, "{split:?} {}: pose differs by {d}", f.name);
            let (x, y) = (f.camera.intrinsics, c.intrinsics);
            assert_eq!((x.width, x.height), (y.width, y.height));
            for (p, q) in [(x.fl_x, y.fl_x), (x.fl_y, y.fl_y), (x.cx, y.cx), (x.cy, y.cy)] {
                assert!((p - q).abs() < 1e-9 * q.abs(), "intrinsics {x:?} vs {y:?}");
            }
        }
    }
    let facts = ds.facts.clone().unwrap();
    assert!((facts.aabb_min[1] - 0.0).abs() < 1e-6 && (facts.aabb_max[1] - 0.6).abs() < 1e-6);
    assert!((facts.aabb_min[0] + 2.0).abs() < 1e-6 && (facts.aabb_max[2] - 2.0).abs() < 1e-6);
    assert!(facts.near > 0.0 && facts.near < facts.far);
    assert_eq!(facts.render["width"], 16);
    assert_eq!(facts.renderer, pathtracer::version::renderer_version());

    // Ground truth: depth is the z-depth of the distance, hit points lie on the ground plane
    // or the cube's surface, and every hit lies within [near, far].
    let mut hits = 0;
    for f in ds.train.iter().chain(&ds.val).chain(&ds.test) {
        let gt = dataset::read_ground_truth(f.gt_path.as_ref().unwrap()).unwrap();
        for j in 0..16u32 {
            for i in 0..16u32 {
                let k = (j * 16 + i) as usize;
                let (depth, dist) = (gt.depth[k] as f64, gt.distance[k] as f64);
                if gt.alpha[k] == 0.0 {
                    assert_eq!((depth, dist), (0.0, 0.0));
                    continue;
                }
                hits += 1;
                let want = f.camera.z_depth_from_distance(i as f64 + 0.5, j as f64 + 0.5, dist);
                assert!((depth - want).abs() <= 1e-6 * want.max(1.0), "depth {depth} vs {want}");
                assert!(dist >= facts.near && dist <= facts.far);
                let r = f.camera.pixel_center_ray(i, j);
                let p = r.origin + r.direction * dist;
                let on_ground = p.y.abs() < 1e-4 && p.x.abs() <= 2.0 + 1e-4 && p.z.abs() <= 2.0 + 1e-4;
                let q = (p - DVec3::new(0.0, 0.3, 0.0)).abs();
                let on_cube = q.max_element() < 0.3 + 1e-4 && q.max_element() > 0.3 - 1e-4;
                assert!(on_ground || on_cube, "hit point {p:?} is on no surface");
            }
        }
    }
    assert!(hits > 7 * 16 * 16 / 10, "only {hits} pixel-centre hits");

    // nerfstudio's transforms.json: every frame's depth is the z-depth in millimetres (its
    // dataparser's default scale is 0.001) and its mask is 255 exactly where the ray hits; no
    // scale key it would ignore.
    let ns: serde_json::Value = serde_json::from_slice(&std::fs::read(a.join("transforms.json")).unwrap()).unwrap();
    assert!(ns.get("depth_unit_scale_factor").is_none());
    let frames = ns["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 7);
    for fr in frames {
        let stem = fr["file_path"].as_str().unwrap().trim_end_matches(".png").to_string();
        let gt = dataset::read_ground_truth(&a.join(format!("{stem}_gt.exr"))).unwrap();
        let mm = read_npy_f32(&a.join(fr["depth_file_path"].as_str().unwrap()));
        assert_eq!(mm.len(), gt.depth.len());
        for (m, d) in mm.iter().zip(&gt.depth) {
            assert!((*m as f64 - 1000.0 * *d as f64).abs() <= 1e-6 * (1000.0 * *d as f64).max(1.0), "{m} mm vs {d} m");
        }
        let mask = dataset::read_png_rgba(&a.join(fr["mask_path"].as_str().unwrap())).unwrap();
        let keep: Vec<bool> = mask.data.chunks_exact(4).map(|p| p[0] == 1.0).collect();
        let hit: Vec<bool> = gt.alpha.iter().map(|a| *a > 0.0).collect();
        assert_eq!(keep, hit, "{stem}: mask against the exact alpha");
        assert!(mask.data.chunks_exact(4).all(|p| p[0] == 0.0 || p[0] == 1.0));
    }

    // Resume: delete one view's files (and the transforms), re-run: identical to the full run.
    // Views whose label files alone are missing or damaged keep their images and get the
    // labels back, the same bytes.
    std::fs::write(b.join("train/r_0_material.png"), b"damaged").unwrap();
    for f in ["val/r_1.png", "val/r_1.exr", "val/r_1_gt.exr", "val/r_1_depth.npy", "train/r_2.exr", "transforms.json", "test/r_0_ids.png", "test/r_1_coverage.npy"] {
        std::fs::remove_file(b.join(f)).unwrap();
    }
    let sum = render(&scene, &b, &cfg, 2).unwrap();
    assert_eq!((sum.views_rendered, sum.views_reused), (2, 5));
    assert!(fa == files(&b), "resumed dataset differs from the uninterrupted one");

    // Different settings in the same folder are refused, and nothing changes.
    let e = render(&scene, &b, &DatasetRenderConfig { seed: 1, ..cfg.clone() }, 1).unwrap_err().to_string();
    assert!(e.contains("different settings") && e.contains("seed"), "{e}");
    assert!(fa == files(&b));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn impossible_options_write_nothing() {
    let dir = tmp("bad");
    let scene = tiny_scene(&dir);
    let out = dir.join("out");
    let cfg = tiny_config();
    for bad in [
        DatasetRenderConfig { width: 0, ..cfg.clone() },
        DatasetRenderConfig { test: 0, ..cfg.clone() },
        DatasetRenderConfig { spp: 0, ..cfg.clone() },
        DatasetRenderConfig { fov_x: 4.0, ..cfg.clone() },
        DatasetRenderConfig { rig: RigKind::Gltf, ..cfg.clone() }, // the scene has no camera
    ] {
        let e = render(&scene, &out, &bad, 1).unwrap_err();
        assert!(matches!(e, PathTracerError::Config(_)), "{e}");
        assert!(!out.exists(), "{e}: wrote something");
    }
    let e = render(&dir.join("missing.gltf"), &out, &cfg, 1).unwrap_err().to_string();
    assert!(e.contains("missing.gltf"), "{e}");
    assert!(!out.exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn every_committed_scene_renders() {
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&scenes)
        .map(|d| d.flatten().map(|e| e.path()).filter(|p| p.extension().is_some_and(|e| e == "gltf" || e == "glb")).collect())
        .unwrap_or_default();
    paths.sort();
    assert!(!paths.is_empty(), "no scenes in {}", scenes.display());
    let dir = tmp("scenes");
    // Exactly what `cargo xtask render <scene> --preset quick` renders (64x64, 20/4/4, 16 spp).
    let cfg = DatasetRenderConfig::preset(Preset::Quick);
    let (w, h) = (cfg.width as usize, cfg.height as usize);
    for p in paths {
        let name = p.file_stem().unwrap().to_string_lossy().into_owned();
        let out = dir.join(&name);
        let sum = render(&p, &out, &cfg, 2).unwrap_or_else(|e| panic!("{name}: {e}"));
        let ds = Dataset::load(&out).unwrap();
        assert_eq!(ds.train.len() + ds.val.len() + ds.test.len(), cfg.total_views() as usize);
        let gt = dataset::read_ground_truth(ds.train[0].gt_path.as_ref().unwrap()).unwrap();
        let covered = gt.alpha.iter().filter(|a| **a > 0.0).count();
        assert!(covered > w * h / 10, "{name}: the first view sees almost nothing ({covered} px)");
        let img = dataset::read_exr_rgba(ds.train[0].exr_path.as_ref().unwrap()).unwrap();
        let mean = img.data.chunks(4).map(|p| (p[0] + p[1] + p[2]) as f64).sum::<f64>() / (3.0 * (w * h) as f64);
        assert!(mean > 1e-3 && mean.is_finite(), "{name}: black or non-finite render (mean {mean})");
        // Scenes with glTF cameras keep them (cornell: closed room; deep: corridor).
        let has_cameras = !load_gltf(&p, &ImportOptions::default()).unwrap().cameras.is_empty();
        if name == "cornell" {
            assert!(has_cameras, "the Cornell room should carry its camera");
        }
        assert_eq!(sum.rig == RigKind::Gltf, has_cameras, "{name}: rig {:?}", sum.rig);
        // A camera inside the scene's box (cornell: a closed room) keeps every view inside it.
        let facts = ds.facts.unwrap();
        let (lo, hi) = (DVec3::from_array(facts.aabb_min), DVec3::from_array(facts.aabb_max));
        let inside = |p: DVec3| p.cmpgt(lo).all() && p.cmplt(hi).all();
        let scene = load_gltf(&p, &ImportOptions::default()).unwrap();
        check_labels(&name, &out, &ds.train[0], &gt, &img, &scene, &facts);
        if scene.cameras.iter().all(|c| inside(c.c2w.w_axis.truncate())) && !scene.cameras.is_empty() {
            for f in ds.train.iter().chain(&ds.val).chain(&ds.test) {
                assert!(inside(f.camera.origin()), "{name}: view {} left the room", f.name);
            }
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The dataset's identity covers the scene's buffers: editing the `.bin` next to the glTF (the
/// glTF file itself untouched) makes a re-render into the same folder refuse to reuse the views,
/// naming the scene; `--force` renders again. A referenced file that is missing is an error
/// naming it.
#[test]
fn editing_a_scene_buffer_refuses_a_resume() {
    let dir = tmp("edited-bin");
    std::fs::create_dir_all(&dir).unwrap();
    let scene = tiny_scene(&dir);
    let cfg = DatasetRenderConfig { train: 1, val: 1, test: 1, ..tiny_config() };
    let out = dir.join("data");
    render(&scene, &out, &cfg, 2).unwrap();
    let bins: Vec<PathBuf> = std::fs::read_dir(&dir).unwrap().flatten().map(|e| e.path()).filter(|p| p.extension().is_some_and(|e| e == "bin")).collect();
    assert_eq!(bins.len(), 1, "the tiny scene keeps its geometry in one .bin: {bins:?}");
    let before = SceneSource::from_scene(&scene).unwrap();
    let mut bytes = std::fs::read(&bins[0]).unwrap();
    // Move the cube's first vertex a little (little-endian f32 at the buffer's start is a
    // position coordinate in scenegen's layout; any changed byte must change the identity).
    bytes[0] ^= 0x01;
    std::fs::write(&bins[0], &bytes).unwrap();
    let after = SceneSource::from_scene(&scene).unwrap();
    assert_ne!(before.hash, after.hash);
    let e = render(&scene, &out, &cfg, 2).unwrap_err().to_string();
    // The refusal names the scene and the files it references, one of which changed.
    let bin = bins[0].file_name().unwrap().to_string_lossy().into_owned();
    assert!(e.contains("content changed") && e.contains(&*scene.to_string_lossy()) && e.contains(&bin) && e.contains("--force"), "{e}");
    let opts = RunOptions { threads: Some(2), force: true, allow_outside: false };
    let sum = render_dataset(&scene, &out, &cfg, &opts, &mut |_| {}, &AtomicBool::new(false)).unwrap();
    assert_eq!(sum.views_rendered, 3);
    std::fs::remove_file(&bins[0]).unwrap();
    let e = SceneSource::from_scene(&scene).unwrap_err().to_string();
    assert!(e.contains("cannot be read") && e.contains(".bin"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The float32 values of a version-1 little-endian `.npy` file (test helper).
fn read_npy_f32(path: &std::path::Path) -> Vec<f32> {
    let b = std::fs::read(path).unwrap();
    assert_eq!(&b[..6], b"\x93NUMPY", "{}", path.display());
    let header_len = u16::from_le_bytes([b[8], b[9]]) as usize;
    let header = std::str::from_utf8(&b[10..10 + header_len]).unwrap();
    assert!(header.contains("'<f4'") && header.contains("'fortran_order': False"), "{header}");
    b[10 + header_len..].chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect()
}

/// The view's label files against its ground truth and image: a pixel whose centre ray hits
/// the scene names an object one of whose triangles holds the depth file's hit point (found by
/// brute force over that object's triangles, not the renderer's BVH), and a material
/// that object uses; a pixel that misses names none; the coverage's background share is
/// 1 − the image's alpha (the same camera samples, transparent background).
fn check_labels(
    name: &str,
    out: &Path,
    frame: &dataset::Frame,
    gt: &dataset::GroundTruth,
    img: &dataset::RgbaImage,
    scene: &pathtracer::scene::Scene,
    facts: &dataset::SceneFacts,
) {
    let (w, h) = (gt.width, gt.height);
    let files = dataset::labels::label_files(SplitKind::Train, 0).map(|f| out.join(f));
    let labels = dataset::labels::read_labels(&files, w, h).unwrap_or_else(|e| panic!("{name}: {e}"));
    assert_eq!(facts.objects.len(), scene.object_count(), "{name}: scene facts list every object");
    assert_eq!(facts.materials.len(), scene.materials.len(), "{name}: scene facts list every material");
    let mut hits = 0;
    for j in 0..h {
        for i in 0..w {
            let p = (j * w + i) as usize;
            let (id, mat) = (labels.object[p] as usize, labels.material[p] as u32);
            if gt.alpha[p] == 0.0 {
                assert_eq!((id, mat), (0, 0), "{name}: pixel {i},{j} misses but is labelled");
            } else {
                hits += 1;
                assert!(id >= 1 && id <= facts.objects.len(), "{name}: pixel {i},{j} hits but has object {id}");
                let o = &facts.objects[id - 1];
                assert!(o.materials.contains(&mat), "{name}: pixel {i},{j}: material {mat} is not one of object {id}'s {:?}", o.materials);
                let ray = frame.camera.pixel_center_ray(i, j);
                let x = ray.origin + ray.direction * gt.distance[p] as f64 - scene.origin;
                let range = match scene.objects.get(id - 1) {
                    Some(so) => so.first_triangle as usize..(so.first_triangle + so.triangles) as usize,
                    None => 0..scene.mesh.indices.len(),
                };
                let d = range
                    .map(|t| {
                        let tri = scene.mesh.indices[t].map(|k| scene.mesh.positions[k as usize].as_dvec3());
                        (pathtracer::nearest::closest_point_on_triangle(x, tri) - x).length()
                    })
                    .fold(f64::INFINITY, f64::min);
                let tol = 1e-4 * (gt.distance[p] as f64).max(1.0);
                assert!(d <= tol, "{name}: pixel {i},{j}: the depth hit lies {d} m from object {id} ({:?})", o.name);
            }
            let c = labels.coverage[p];
            assert!(c[1] >= c[3] && c[1] + c[3] <= 1.0 + 1e-6, "{name}: pixel {i},{j}: coverage {c:?}");
            if c[1] + c[3] >= 1.0 - 1e-6 {
                let background = if c[0] == 0.0 { c[1] } else if c[2] == 0.0 { c[3] } else { 0.0 };
                let alpha = img.data[4 * p + 3];
                assert!((1.0 - background - alpha).abs() < 1e-5, "{name}: pixel {i},{j}: coverage {c:?} against alpha {alpha}");
            }
        }
    }
    assert!(hits > 0);
}
