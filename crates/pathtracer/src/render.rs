//! The shared per-view driver (pbrt's `ImageTileIntegrator` idea): camera rays per pixel,
//! parallelism over rows with rayon, fixed-order accumulation, ground truth at pixel centres.
//!
//! - Colour: the average over the pixel's area of `spp` jittered camera rays, each traced by
//!   [`PathIntegrator::radiance`]. Sample `s` of pixel `(i, j)` of view `v` draws every random
//!   number from `Sampler::new(seed, v, j·width + i, s)` and samples are summed in `f64` in
//!   order `s = 0, 1, …`, so the image is bit-identical for any thread count.
//! - Emitter edges: a pixel that straddles the edge of a directly seen emitter (the emission
//!   seen through its four corners differs by more than [`EDGE_CONTRAST`]) is mostly noise
//!   from how many of its few camera rays land on the emitter (`docs/renderer.md`). There the
//!   camera vertex's emission ([`PathIntegrator::primary_emission`]) is
//!   estimated from `split · spp` camera rays of their own stratified set (keys
//!   `(splitmix64(seed ⊕ EDGE_SEED_KEY), view, pixel, e)`), and each path sample adds the rest
//!   ([`PathIntegrator::radiance_split`]): the same expectation with far less noise, for a
//!   closest hit per extra ray. `split` ([`edge_split`]) is the largest power of two up to
//!   [`EDGE_MAX_SPLIT`] that keeps the extra rays within [`EDGE_RAY_BUDGET`] of the view's
//!   camera samples; views without such pixels (or scenes without emitters) have no split.
//!   The corners are traced once per view, so which pixels are split does not depend
//!   on any random number (the estimate stays unbiased).
//! - Caustics: when the scene has casters that a punctual light reaches and `max_bounces ≥ 2`,
//!   the caustic paths are traced from the lights instead ([`crate::caustics`]; light path `k`
//!   draws from its own stratified set, keyed by `splitmix64(seed ⊕ CAUSTIC_SEED_KEY)` and
//!   the view) and their sum is added to each pixel's mean in `f64`, in path order.
//! - Alpha: with a transparent background, the fraction of the pixel's samples whose camera
//!   ray hit geometry (coverage), and RGB is premultiplied (misses add zero). With an opaque
//!   background, misses add the environment radiance and alpha is 1.
//! - Ground truth: the pixel-centre ray ([`dataset::Camera::pixel_center_ray`]) is traced
//!   once; its hit distance is re-computed in `f64` against the hit triangle
//!   ([`ray_triangle_plane_distance_f64`]) and converted to z-depth with
//!   [`dataset::Camera::z_depth_from_distance`]; the normal is the world shading normal facing
//!   the camera. Misses: depth, distance, normal and alpha 0.
//! - Non-finite radiance samples are replaced by zero and counted.
//! - Every pixel gets `spp` samples (adaptive sampling, tried: `docs/experiments.md`).
//! - Cameras are in true world coordinates (`f64`); rays are moved into the scene's local
//!   frame by subtracting [`Scene::origin`] before conversion to `f32`. The jittered camera
//!   rays of path samples are generated in `f32` from the camera's pose converted once per
//!   view ([`SampleRays`]); the ground truth keeps the `f64` pixel-centre ray.

use crate::PathTracerError;
use crate::accel::{Accel, AccelParams, Hit};
use crate::camera_rays::SampleRays;
use crate::caustics::CausticPaths;
use crate::geometry::{Ray, ray_triangle_plane_distance_f64};
use crate::integrator::{IntegratorSettings, PathIntegrator, RayCounts, interaction};
use crate::light::{EmissiveTriangles, Environment, EnvironmentMap};
use crate::material::SurfaceMaterial;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use crate::sampler::{Sampler, SamplerLanes, splitmix64};
use crate::scene::{Light, Scene};
use dataset::{Camera, GroundTruth, RgbaImage};
use glam::{DVec3, Vec2, Vec3, Vec4};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

mod throughput;
pub use throughput::{PrimaryRayStats, RayQuery, read_ray_file};

/// Pixels of one view whose camera vertex's emission is estimated with extra rays
/// ([`Renderer::emitter_edges`]).
#[derive(Clone, Debug, PartialEq)]
pub struct EmitterEdges {
    /// Per pixel (row-major), whether it is an emitter-edge pixel.
    pub flagged: Vec<bool>,
    /// Emission rays per camera sample in those pixels (a power of two, ≥ 2).
    pub split: u32,
}

/// Most emission rays per camera sample in an emitter-edge pixel.
pub const EDGE_MAX_SPLIT: u32 = 64;
/// The emission rays of all emitter-edge pixels together are at most this share of the view's
/// camera samples (a closest hit each, against a path of several hits and shadow rays).
/// A quarter lowers `cornell`'s error at no visible cost (`docs/experiments.md`). Views
/// without a directly seen emitter's edge trace no emission rays.
pub const EDGE_RAY_BUDGET: f64 = 0.25;
/// A pixel is an emitter edge when the emission seen at its four corners differs, in some
/// channel, by more than this share of the brightest corner's largest channel.
pub const EDGE_CONTRAST: f32 = 0.05;
/// Mixed into the seed for the emission rays' sampler keys (independent of the path samples').
/// Camera samples of a pixel traced together as one batch of paths
/// ([`PathIntegrator::radiance_batch`]).
pub const PATH_BATCH: usize = 64;

const EDGE_SEED_KEY: u64 = 0x5EED_ED6E_E517_7E12;

/// Emission rays per camera sample for `flagged` emitter-edge pixels out of `pixels`: the
/// largest power of two ≤ [`EDGE_MAX_SPLIT`] whose rays stay within [`EDGE_RAY_BUDGET`];
/// `None` when that is below 2 (one ray per sample gains nothing) or no pixel is flagged.
pub fn edge_split(flagged: usize, pixels: usize) -> Option<u32> {
    if flagged == 0 {
        return None;
    }
    let allowed = (EDGE_RAY_BUDGET * pixels as f64 / flagged as f64).min(EDGE_MAX_SPLIT as f64);
    let split = if allowed >= 1.0 { 1u32 << (allowed.log2().floor() as u32) } else { 0 };
    (split >= 2).then_some(split)
}

/// Settings of one render. All fields are meaningful choices; use a named constructor or
/// spell them out.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderSettings {
    /// Samples (camera rays) per pixel for colour, ≥ 1.
    pub spp: u32,
    /// Maximum scattering events per path (0: emitters only, 1: direct light, …).
    pub max_bounces: u32,
    /// Seed of the counter-based sampler.
    pub seed: u64,
    /// Constant environment radiance (linear RGB, ≥ 0), or the scale of the renderer's
    /// environment map when it has one ([`Renderer::set_environment_map`]); lights the scene
    /// in every case.
    pub environment: [f32; 3],
    /// Whether camera rays that miss are transparent (alpha 0, RGB 0) instead of showing the
    /// environment.
    pub transparent_background: bool,
    /// Equirectangular environment map file (OpenEXR `.exr` or Radiance `.hdr`, linear
    /// radiance, scaled by `environment`), loaded by [`Renderer::load_environment_map`];
    /// `None`: the constant environment. Its orientation is [`EnvironmentMap::direction`]'s
    /// (Mitsuba's `envmap` convention: image top = +Y, image centre = −Z).
    #[serde(default)]
    pub environment_map: Option<PathBuf>,
}

impl RenderSettings {
    /// A quick look: 16 spp, 4 bounces, transparent background, environment radiance 1.
    pub fn preview(seed: u64) -> Self {
        Self { spp: 16, max_bounces: 4, seed, environment: [1.0; 3], transparent_background: true, environment_map: None }
    }
    /// Dataset quality: 256 spp, 8 bounces, transparent background, environment radiance 1.
    pub fn dataset(seed: u64) -> Self {
        Self { spp: 256, max_bounces: 8, seed, environment: [1.0; 3], transparent_background: true, environment_map: None }
    }
    /// Checks the ranges: `spp ≥ 1`, `max_bounces ≤ 1024`, finite non-negative environment,
    /// and that the environment map (if any) is an existing `.exr` or `.hdr` file.
    pub fn validate(&self) -> Result<(), PathTracerError> {
        if let Some(path) = &self.environment_map {
            check_environment_map_path(path)?;
        }
        if self.spp == 0 {
            return Err(PathTracerError::Config("spp must be at least 1".into()));
        }
        if self.max_bounces > 1024 {
            return Err(PathTracerError::Config(format!("max_bounces {} is above 1024", self.max_bounces)));
        }
        if !self.environment.iter().all(|c| c.is_finite() && *c >= 0.0) {
            return Err(PathTracerError::Config(format!("environment {:?} must be finite and >= 0", self.environment)));
        }
        Ok(())
    }
    fn integrator_settings(&self, map: Option<Arc<EnvironmentMap>>) -> IntegratorSettings {
        let env = Vec3::from_array(self.environment.map(|c| if c.is_finite() && c > 0.0 { c } else { 0.0 }));
        IntegratorSettings {
            max_bounces: self.max_bounces.min(1024),
            environment: Environment { radiance: env, map },
            transparent_background: self.transparent_background,
        }
    }
}

/// The result of rendering one view.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewOutput {
    /// Linear RGBA. Transparent background: RGB premultiplied by alpha, alpha = coverage
    /// (fraction of the pixel's samples that hit geometry). Opaque background: alpha 1.
    pub color: RgbaImage,
    /// Ground truth at the pixel-centre rays: z-depth, distance, world shading normal facing
    /// the camera, alpha 0/1.
    pub ground_truth: GroundTruth,
    /// Camera samples traced (width · height · spp).
    pub samples: u64,
    /// Radiance samples that were NaN or infinite (replaced by zero).
    pub nonfinite_samples: u64,
    /// Minimum and maximum pixel-centre hit distance (`f64`), `None` when nothing was hit.
    pub distance_range: Option<(f64, f64)>,
    /// The rays the view traced: its path samples', the ground truth's, the emitter-edge
    /// pixels' and the caustic light tracer's (its pilot included). The same for any thread
    /// count.
    pub rays: RayCounts,
}

/// One pixel's exact ground truth: (z-depth, distance, unit normal, `f64` distance).
type PixelTruth = (f32, f32, Vec3, f64);

/// A pixel-centre (ground-truth) hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PrimaryHit {
    /// The BVH hit (triangle, `f32` distance, barycentrics).
    pub hit: Hit,
    /// Distance along the ray re-computed in `f64` against the hit triangle's plane.
    pub distance: f64,
    /// Unit world shading normal facing the ray's origin.
    pub normal: Vec3,
}

/// A scene ready to render: the scene, its BVH and its light tables.
pub struct Renderer {
    scene: Scene,
    accel: Accel,
    emitters: EmissiveTriangles,
    /// Per material, [`crate::material::uniform_surface`].
    uniform_surfaces: Vec<Option<SurfaceMaterial>>,
    lane_materials: Option<crate::integrator::LaneMaterials>,
    caustics: CausticPaths,
    /// Whether [`Renderer::render_view`] traces caustic paths from the lights (default on).
    caustic_light_tracing: bool,
    /// Equirectangular environment map lighting the scene (scaled by
    /// [`RenderSettings::environment`]); `None`: the constant environment.
    environment_map: Option<Arc<EnvironmentMap>>,
}

impl std::fmt::Debug for Renderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Renderer")
            .field("scene", &self.scene.name)
            .field("triangles", &self.scene.mesh.indices.len())
            .field("emissive_triangles", &self.emitters.len())
            .field("caustic_caster_triangles", &self.caustics.caster_triangles())
            .field("accel", &self.accel)
            .finish()
    }
}

/// Checks that `path` names an existing environment map file with a supported extension
/// (`.exr` or `.hdr`, any case); the error names the file.
pub fn check_environment_map_path(path: &Path) -> Result<(), PathTracerError> {
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).unwrap_or_default();
    if ext != "exr" && ext != "hdr" {
        return Err(PathTracerError::import(path, "environment map must be an OpenEXR (.exr) or Radiance (.hdr) file"));
    }
    if !path.is_file() {
        return Err(PathTracerError::import(path, "environment map file does not exist"));
    }
    Ok(())
}

/// Reads an equirectangular environment map ([`EnvironmentMap::load`]: `.exr` or `.hdr`);
/// a missing, unreadable or malformed file is an error naming it.
pub fn load_environment_map(path: &Path) -> Result<EnvironmentMap, PathTracerError> {
    check_environment_map_path(path)?;
    EnvironmentMap::load(path)
}

/// Checks the scene's internal consistency (the importer's output, or a hand-made scene).
pub fn validate_scene(scene: &Scene) -> Result<(), PathTracerError> {
    let m = &scene.mesh;
    let bad = |msg: String| Err(PathTracerError::Config(format!("scene {}: {msg}", scene.name)));
    if !scene.origin.is_finite() {
        return bad("non-finite origin".into());
    }
    if m.material.len() != m.indices.len() {
        return bad(format!("{} triangles but {} material indices", m.indices.len(), m.material.len()));
    }
    let nv = m.positions.len();
    for (name, len) in [("normals", m.normals.len()), ("tangents", m.tangents.len()), ("uv0", m.uv0.len()), ("uv1", m.uv1.len()), ("colors", m.colors.len())] {
        if len != nv && len != 0 {
            return bad(format!("{name} has {len} entries for {nv} vertices"));
        }
    }
    if let Some(k) = m.indices.iter().position(|t| t.iter().any(|&i| i as usize >= nv)) {
        return bad(format!("triangle {k} references a vertex out of range"));
    }
    if let Some(k) = m.material.iter().position(|&i| i as usize >= scene.materials.len()) {
        return bad(format!("triangle {k} references material {} of {}", m.material[k], scene.materials.len()));
    }
    if m.positions.iter().any(|p| !p.is_finite()) {
        return bad("non-finite vertex position".into());
    }
    for (k, mat) in scene.materials.iter().enumerate() {
        let refs = [mat.base_color_texture, mat.emissive_texture, mat.metallic_roughness_texture, mat.normal_texture.map(|t| t.0), mat.occlusion_texture.map(|t| t.0)];
        for r in refs.into_iter().flatten() {
            let ok = scene.textures.get(r.texture as usize).is_some_and(|t| t.texels.len() == t.width as usize * t.height as usize);
            if !ok {
                return bad(format!("material {k} references missing or malformed texture {}", r.texture));
            }
        }
        if !(mat.emissive.is_finite() && mat.emissive.min_element() >= 0.0 && mat.base_color_factor.is_finite()) {
            return bad(format!("material {k} has a non-finite or negative factor"));
        }
    }
    for (k, l) in scene.lights.iter().enumerate() {
        let ok = match *l {
            Light::Point { position, intensity, .. } => position.is_finite() && intensity.is_finite(),
            Light::Spot { position, direction, intensity, inner_cone_angle, outer_cone_angle, .. } => {
                position.is_finite() && direction.is_finite() && intensity.is_finite() && inner_cone_angle.is_finite() && outer_cone_angle.is_finite()
            }
            Light::Directional { direction, illuminance } => direction.is_finite() && direction != Vec3::ZERO && illuminance.is_finite(),
        };
        if !ok {
            return bad(format!("light {k} has non-finite parameters"));
        }
    }
    Ok(())
}

impl Renderer {
    /// Validates the scene, builds its BVH (in parallel) and light tables.
    pub fn new(mut scene: Scene, accel: &AccelParams) -> Result<Renderer, PathTracerError> {
        validate_scene(&scene)?;
        // All-white vertex colours are glTF's default, the same as none (the importer fills
        // white where a primitive has no COLOR_0): dropped, the colour at a hit is exactly 1
        // (not the rounded sum of its barycentrics) and untextured materials resolve once.
        if scene.mesh.colors.iter().all(|c| *c == Vec4::ONE) {
            scene.mesh.colors = Vec::new();
        }
        // Likewise the texture coordinates the importer fills with zeros (an absent
        // TEXCOORD_1), and all of them where no texture reads them: a hit then skips
        // interpolating them (the same bits).
        if scene.textures.is_empty() {
            scene.mesh.uv0 = Vec::new();
        }
        if scene.textures.is_empty() || scene.mesh.uv1.iter().all(|v| *v == Vec2::ZERO) {
            scene.mesh.uv1 = Vec::new();
        }
        let accel = Accel::build(&scene, accel)?;
        let emitters = EmissiveTriangles::build(&scene);
        let caustics = CausticPaths::build(&scene);
        let vertex_colors = !scene.mesh.colors.is_empty();
        let uniform_surfaces: Vec<_> = scene.materials.iter().map(|m| crate::material::uniform_surface(m, vertex_colors)).collect();
        let lane_materials = crate::integrator::LaneMaterials::new(&scene, &uniform_surfaces);
        Ok(Renderer { scene, accel, emitters, uniform_surfaces, lane_materials, caustics, caustic_light_tracing: true, environment_map: None })
    }

    /// Turns the caustic light tracer ([`crate::caustics`]) on (the default) or off: off,
    /// every path is estimated by the path tracer (the same expectation, with the caustics'
    /// noise; for tests and comparisons).
    pub fn set_caustic_light_tracing(&mut self, on: bool) {
        self.caustic_light_tracing = on;
    }

    /// The caustic light tracer's casters and lights.
    pub fn caustics(&self) -> &CausticPaths {
        &self.caustics
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The acceleration structure.
    pub fn accel(&self) -> &Accel {
        &self.accel
    }

    /// The emissive-triangle table.
    pub fn emitters(&self) -> &EmissiveTriangles {
        &self.emitters
    }

    /// Whether any material that some triangle uses is view-dependent (metallic, or a
    /// dielectric specular layer rougher than nothing; the rule and its threshold are
    /// [`crate::material::is_view_dependent`]).
    pub fn is_view_dependent(&self) -> bool {
        crate::material::scene_is_view_dependent(&self.scene)
    }

    /// Lights the scene with an equirectangular environment map (e.g.
    /// [`EnvironmentMap::load`]), scaled by [`RenderSettings::environment`]; `None` restores
    /// the constant environment.
    pub fn set_environment_map(&mut self, map: Option<Arc<EnvironmentMap>>) {
        self.environment_map = map;
    }

    /// The environment map, if any.
    pub fn environment_map(&self) -> Option<&Arc<EnvironmentMap>> {
        self.environment_map.as_ref()
    }

    /// Loads `settings.environment_map` ([`load_environment_map`]) and lights the scene with
    /// it, or restores the constant environment when the settings name none. Call it before
    /// rendering with settings that name a map: [`Renderer::render_view`] uses the map loaded
    /// here, not the path.
    pub fn load_environment_map(&mut self, settings: &RenderSettings) -> Result<(), PathTracerError> {
        self.environment_map = match &settings.environment_map {
            Some(path) => Some(Arc::new(load_environment_map(path)?)),
            None => None,
        };
        Ok(())
    }

    /// The path integrator for `settings`.
    pub fn integrator(&self, settings: &RenderSettings) -> PathIntegrator<'_> {
        self.integrator_with(settings.integrator_settings(self.environment_map.clone()))
    }

    /// The path integrator over this renderer's scene with `settings`.
    fn integrator_with(&self, settings: IntegratorSettings) -> PathIntegrator<'_> {
        PathIntegrator::new(&self.scene, &self.accel, &self.emitters, &self.uniform_surfaces, self.lane_materials.as_ref(), settings)
    }

    /// A world-space (`f64`) ray moved into the scene's local `f32` frame.
    pub fn local_ray(&self, ray: &dataset::Ray) -> Ray {
        let o = ray.origin - self.scene.origin;
        Ray::new(o.as_vec3(), ray.direction.as_vec3().normalize_or_zero())
    }

    /// Traces a world-space ray (e.g. a pixel-centre ray) and returns its exact ground truth:
    /// the hit, its `f64` distance and the shading normal facing the ray.
    pub fn trace_primary(&self, ray: &dataset::Ray) -> Option<PrimaryHit> {
        let local = self.local_ray(ray);
        // Closest hits only: no settings or environment map are read (none is cloned).
        let integ = self.integrator_with(RenderSettings::preview(0).integrator_settings(None));
        let hit = integ.intersect(&local)?;
        let m = &self.scene.mesh;
        let p = m.indices[hit.prim as usize].map(|i| m.positions[i as usize]);
        let o64: DVec3 = ray.origin - self.scene.origin;
        let d64 = ray.direction.normalize();
        let distance = ray_triangle_plane_distance_f64(p, o64, d64)
            .filter(|t| *t > 0.0 && (*t - hit.t as f64).abs() <= 1e-3 * (hit.t as f64).max(1.0))
            .unwrap_or(hit.t as f64);
        let si = interaction(&self.scene, &local, &hit);
        Some(PrimaryHit { hit, distance, normal: si.n })
    }

    /// The exact ground truth of pixel (`i`, `j`)'s centre ray: (z-depth, distance, normal,
    /// `f64` distance), `None` when the ray hits nothing.
    fn pixel_ground_truth(&self, camera: &Camera, i: u32, j: u32) -> Option<PixelTruth> {
        self.trace_primary(&camera.pixel_center_ray(i, j)).map(|ph| {
            let depth = camera.z_depth_from_distance(i as f64 + 0.5, j as f64 + 0.5, ph.distance);
            (depth as f32, ph.distance as f32, ph.normal, ph.distance)
        })
    }

    /// The exact ground truth (z-depth, distance, normal, alpha) at every pixel-centre ray of
    /// `camera`, with no colour: the same values [`Self::render_view`] writes, for any camera
    /// (e.g. a dataset camera downscaled by an even factor, whose pixel centres fall between
    /// the full-resolution ones).
    pub fn ground_truth(&self, camera: &Camera) -> GroundTruth {
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let rows: Vec<Vec<Option<PixelTruth>>> =
            (0..h).into_par_iter().map(|j| (0..w).map(|i| self.pixel_ground_truth(camera, i, j)).collect()).collect();
        let n = w as usize * h as usize;
        let mut gt = GroundTruth { width: w, height: h, depth: vec![0.0; n], distance: vec![0.0; n], normal: vec![0.0; 3 * n], alpha: vec![0.0; n] };
        for (k, px) in rows.iter().flatten().enumerate() {
            if let Some((depth, dist, normal, _)) = px {
                gt.depth[k] = *depth;
                gt.distance[k] = *dist;
                gt.normal[3 * k..3 * k + 3].copy_from_slice(&normal.to_array());
                gt.alpha[k] = 1.0;
            }
        }
        gt
    }

    /// The object and material labels of view `view_index` of `camera`
    /// ([`dataset::labels`]): the pixel-centre ray's hit (the ray and hit of
    /// [`Self::ground_truth`]) gives the object ID ([`Scene::object_of`] + 1) and the material
    /// index + 1; the coverage counts the labels the pixel's `settings.spp` image samples hit:
    /// the camera rays [`Self::render_view`] traces (the same sampler, sub-pixel positions and
    /// alpha-tested closest hits), so its background share is 1 − the image's alpha under a
    /// transparent background. With `spp` 0 the coverage is the centre ray's alone.
    pub fn labels(&self, camera: &Camera, view_index: u32, settings: &RenderSettings) -> dataset::labels::ViewLabels {
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let integ = self.integrator_with(RenderSettings::preview(0).integrator_settings(None));
        let rays = SampleRays::new(camera, self.scene.origin);
        let object_id = |prim: u32| self.scene.object_of(prim).map_or(0, |o| (o + 1).min(dataset::labels::MAX_LABEL) as u16);
        let spp = settings.spp;
        let rows: Vec<Vec<(u16, u16, [f32; 4])>> = (0..h)
            .into_par_iter()
            .map(|j| {
                let mut ids = Vec::with_capacity(spp as usize);
                (0..w)
                    .map(|i| {
                        let centre = self.trace_primary(&camera.pixel_center_ray(i, j));
                        let (object, material) = centre.map_or((0, 0), |ph| {
                            let m = self.scene.mesh.material.get(ph.hit.prim as usize).map_or(0, |&m| (m as usize + 1).min(dataset::labels::MAX_LABEL));
                            (object_id(ph.hit.prim), m as u16)
                        });
                        ids.clear();
                        let pixel_sampler = Sampler::new(settings.seed, view_index, j as u64 * w as u64 + i as u64, 0);
                        for s in 0..spp {
                            let u = pixel_sampler.with_sample(s).next_2d();
                            ids.push(integ.intersect(&rays.ray(i as f32 + u.x, j as f32 + u.y)).map_or(0, |hit| object_id(hit.prim)));
                        }
                        if spp == 0 {
                            ids.push(object);
                        }
                        (object, material, dataset::labels::coverage_of(&ids))
                    })
                    .collect()
            })
            .collect();
        let px = rows.into_iter().flatten();
        let (mut object, mut material, mut coverage) = (Vec::new(), Vec::new(), Vec::new());
        for (o, m, c) in px {
            object.push(o);
            material.push(m);
            coverage.push(c);
        }
        dataset::labels::ViewLabels { width: w, height: h, object, material, coverage }
    }

    /// Renders one view (see the module docs). `settings` should have passed
    /// [`RenderSettings::validate`]; out-of-range values are clamped (spp 0 renders no
    /// samples: black, alpha 0; a negative or non-finite environment is treated as 0).
    pub fn render_view(&self, camera: &Camera, view_index: u32, settings: &RenderSettings) -> ViewOutput {
        /// A batch's camera rays, samplers and results, reused across a row's pixels.
        #[derive(Default)]
        struct PathBatch {
            rays: Vec<Ray>,
            samplers: Vec<Sampler>,
            out: Vec<crate::integrator::RadianceSample>,
        }
        let (w, h) = (camera.intrinsics.width, camera.intrinsics.height);
        let mut integ = self.integrator(settings);
        let spp = settings.spp;
        // Caustic paths from the light's side ([`crate::caustics`]), left out of the path
        // tracer's estimate when there are any.
        let rays = SampleRays::new(camera, self.scene.origin);
        let light_paths = if self.caustic_light_tracing { self.caustics.paths_for_view(&integ, &rays, (w, h), settings.seed, view_index, spp) } else { 0 };
        if light_paths > 0 {
            integ.caustics = Some(self.caustics.vertices());
        }
        let edges = self.emitter_edges(camera, &integ, spp);
        let edge_seed = splitmix64(settings.seed ^ EDGE_SEED_KEY);
        struct PixelOut {
            /// The mean radiance of the pixel's path samples.
            rgb: [f64; 3],
            alpha: f32,
            gt: Option<PixelTruth>,
            nonfinite: u64,
        }
        let rows: Vec<Vec<PixelOut>> = (0..h)
            .into_par_iter()
            .map(|j| {
                integ.tallied(|| {
                    let mut batch = PathBatch::default();
                    (0..w)
                        .map(|i| {
                            let pixel = j as u64 * w as u64 + i as u64;
                            let mut sum = [0.0f64; 3];
                            let mut hits = 0u32;
                            let mut nonfinite = 0u64;
                            // Emitter-edge pixels: the camera vertex's emission from `split` rays per
                            // sample (their own stratified set), the rest of each path as usual.
                            let split = edges.as_ref().filter(|e| e.flagged[pixel as usize]).map(|e| e.split);
                            if let Some(m) = split {
                                let edge_sampler = Sampler::new(edge_seed, view_index, pixel, 0);
                                for e in 0..spp * m {
                                    let u = edge_sampler.with_sample(e).next_2d();
                                    let le = integ.primary_emission(&rays.ray(i as f32 + u.x, j as f32 + u.y)) / m as f32;
                                    if le.is_finite() {
                                        sum[0] += le.x as f64;
                                        sum[1] += le.y as f64;
                                        sum[2] += le.z as f64;
                                    } else {
                                        nonfinite += 1;
                                    }
                                }
                            }
                            let pixel_sampler = Sampler::new(settings.seed, view_index, pixel, 0);
                            // The pixel's samples traced as batches of paths (the same bits as one
                            // path at a time), summed in sample order.
                            for s0 in (0..spp).step_by(PATH_BATCH) {
                                let n = (spp - s0).min(PATH_BATCH as u32) as usize;
                                batch.samplers.clear();
                                batch.rays.clear();
                                // Each sample's first two numbers (`next_2d`) place its camera ray:
                                // eight samples' at a time in lanes, at the SIMD level of the path
                                // loop.
                                integ.accel.at_level(
                                    #[inline(always)]
                                    || {
                                        for first in (s0..s0 + n as u32).step_by(8) {
                                            let count = (s0 + n as u32 - first).min(8) as usize;
                                            let mut lanes = SamplerLanes::default();
                                            let mut samplers: [Sampler; 8] = std::array::from_fn(|k| pixel_sampler.with_sample(first + k as u32));
                                            // The dimensions `next_2d` would draw.
                                            let dims = std::array::from_fn(|k| samplers[k].skip(2));
                                            for (k, sampler) in samplers.iter().enumerate() {
                                                lanes.set(k, sampler);
                                            }
                                            let u = lanes.get_2d(&dims);
                                            for (k, sampler) in samplers.into_iter().take(count).enumerate() {
                                                batch.rays.push(rays.ray(i as f32 + u[0][k], j as f32 + u[1][k]));
                                                batch.samplers.push(sampler);
                                            }
                                        }
                                    },
                                );
                                batch.out.resize(n, crate::integrator::RadianceSample { radiance: Vec3::ZERO, primary_hit: false });
                                integ.radiance_batch(&batch.rays, &mut batch.samplers, split.is_none(), &mut batch.out);
                                for r in &batch.out {
                                    let mut rad = r.radiance;
                                    if !rad.is_finite() {
                                        nonfinite += 1;
                                        rad = Vec3::ZERO;
                                    }
                                    if r.primary_hit {
                                        hits += 1;
                                    }
                                    sum[0] += rad.x as f64;
                                    sum[1] += rad.y as f64;
                                    sum[2] += rad.z as f64;
                                }
                            }
                            let inv = if spp > 0 { 1.0 / spp as f64 } else { 0.0 };
                            let alpha = if settings.transparent_background { hits as f64 * inv } else if spp > 0 { 1.0 } else { 0.0 };
                            let gt = self.pixel_ground_truth(camera, i, j);
                            PixelOut { rgb: [sum[0] * inv, sum[1] * inv, sum[2] * inv], alpha: alpha as f32, gt, nonfinite }
                        })
                        .collect()
                })
            })
            .collect();
        let (caustic, caustic_nonfinite) = self.caustics.render(&integ, &rays, (w, h), settings.seed, view_index, light_paths);
        let n = w as usize * h as usize;
        let mut color = RgbaImage::new(w, h);
        let mut gt = GroundTruth { width: w, height: h, depth: vec![0.0; n], distance: vec![0.0; n], normal: vec![0.0; 3 * n], alpha: vec![0.0; n] };
        let mut nonfinite = 0u64;
        let mut range: Option<(f64, f64)> = None;
        for (j, row) in rows.iter().enumerate() {
            for (i, px) in row.iter().enumerate() {
                let k = j * w as usize + i;
                // The path samples' mean plus the light paths' (zero without them).
                for (out, (pt, lt)) in color.data[4 * k..4 * k + 3].iter_mut().zip(px.rgb.iter().zip(&caustic[k])) {
                    *out = (pt + lt) as f32;
                }
                color.data[4 * k + 3] = px.alpha;
                nonfinite += px.nonfinite;
                if let Some((depth, dist, normal, d64)) = px.gt {
                    gt.depth[k] = depth;
                    gt.distance[k] = dist;
                    gt.normal[3 * k..3 * k + 3].copy_from_slice(&normal.to_array());
                    gt.alpha[k] = 1.0;
                    range = Some(match range {
                        None => (d64, d64),
                        Some((lo, hi)) => (lo.min(d64), hi.max(d64)),
                    });
                }
            }
        }
        ViewOutput {
            color,
            ground_truth: gt,
            samples: n as u64 * spp as u64,
            nonfinite_samples: nonfinite + caustic_nonfinite,
            distance_range: range,
            rays: integ.rays_traced(),
        }
    }

    /// The pixels of `camera` on an edge of a directly seen emitter, and how many camera rays
    /// per sample estimate their camera vertex's emission (see the module docs): `None` when
    /// the scene has no emitters or no pixel qualifies within the budget.
    pub fn emitter_edges(&self, camera: &Camera, integ: &PathIntegrator<'_>, spp: u32) -> Option<EmitterEdges> {
        if self.emitters.is_empty() || spp == 0 {
            return None;
        }
        let (w, h) = (camera.intrinsics.width as usize, camera.intrinsics.height as usize);
        // The emission seen along the ray through every pixel corner.
        let corners: Vec<Vec<Vec3>> = (0..=h)
            .into_par_iter()
            .map(|j| integ.tallied(|| (0..=w).map(|i| integ.primary_emission(&self.local_ray(&camera.pixel_ray(i as f64, j as f64)))).collect()))
            .collect();
        let flagged: Vec<bool> = (0..w * h)
            .map(|k| {
                let (i, j) = (k % w, k / w);
                let c = [corners[j][i], corners[j][i + 1], corners[j + 1][i], corners[j + 1][i + 1]];
                let (lo, hi) = c.iter().fold((c[0], c[0]), |(lo, hi), &v| (lo.min(v), hi.max(v)));
                // Not finite: the path samples count it; no contrast: nothing to gain.
                hi.is_finite() && lo.is_finite() && (hi - lo).max_element() > EDGE_CONTRAST * hi.max_element()
            })
            .collect();
        let count = flagged.iter().filter(|&&f| f).count();
        let split = edge_split(count, w * h)?;
        Some(EmitterEdges { flagged, split })
    }
}

#[cfg(test)]
mod tests;
