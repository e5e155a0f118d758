//! Lights in physical units: the glTF punctual lights (point, spot, directional), emissive
//! triangles, and a constant environment.
//!
//! - Point: intensity `I` (W/sr); at distance `r` the incident radiance is a delta whose
//!   irradiance on a surface with normal `n` is `E = I · cos θ / r²`.
//! - Spot: a point light times glTF's smooth cone falloff
//!   `a(cd) = clamp((cd − cos θ_outer) / (cos θ_inner − cos θ_outer), 0, 1)²`, with `cd` the
//!   cosine between the spot axis and the direction to the point ([`spot_falloff`]).
//! - Directional: illuminance `E` (lux); irradiance `E · cos θ`.
//! - `range` (glTF) is a hard cutoff: no light beyond it.
//! - Emissive triangles: area lights of radiance `Le = emissive × emissiveTexture`, emitting
//!   from the front face (both faces when double-sided). [`EmissiveTriangles`] picks a
//!   triangle with probability proportional to its power proxy `area × luminance(emissive
//!   factor) × sides` (a CDF, binary search), then a uniform point on it; the solid-angle
//!   density at the receiver is `pmf / area · r² / |cos θ_light|`.
//!   With an emissive texture the proxy is multiplied by the texture's mean luminance (a
//!   cheap per-material estimate; the pdf stays exact because it uses the same table).
//! - [`Environment`]: radiance `scale × map(ω)` from every direction `ω`. Without a map, a
//!   constant sampled uniformly on the sphere (`pdf = 1/4π`). With an [`EnvironmentMap`] (an
//!   equirectangular HDR image), importance sampled in proportion to luminance × sin θ.

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::PathTracerError;
use crate::sampler::{sample_uniform_sphere, sample_uniform_triangle};
use crate::scene::{Light, Scene};
use glam::{Vec2, Vec3};
use std::f32::consts::PI;
use std::path::Path;
use std::sync::Arc;

/// Rec. 709 luminance of linear RGB.
#[inline]
pub fn luminance(c: Vec3) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// glTF's spot cone attenuation for `cos_angle` between the spot axis and the direction to
/// the lit point: `clamp((cd − cos_outer) / max(1e-3, cos_inner − cos_outer), 0, 1)²`
/// (the formula in the `KHR_lights_punctual` specification).
pub fn spot_falloff(cos_angle: f32, inner_cone_angle: f32, outer_cone_angle: f32) -> f32 {
    let cos_outer = outer_cone_angle.cos();
    let cos_inner = inner_cone_angle.cos();
    let scale = 1.0 / (cos_inner - cos_outer).max(1e-3);
    let a = ((cos_angle - cos_outer) * scale).clamp(0.0, 1.0);
    a * a
}

/// Incident light from a punctual light at a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PunctualIncidence {
    /// Unit direction from the point towards the light.
    pub wi: Vec3,
    /// Distance to the light (`f32::INFINITY` for directional lights).
    pub distance: f32,
    /// Irradiance at normal incidence: `I · falloff / r²` or the directional illuminance.
    /// Multiply by the cosine-weighted BSDF (which includes `cos θ`) to get radiance.
    pub irradiance: Vec3,
}

/// The light arriving at `p` (local frame) from a punctual light, or `None` when it
/// contributes nothing there (outside the cone or range, at the light's position).
///
/// Inlined so that the path loop, which calls it at every vertex for every light, compiles
/// it at its own level (AVX2) without a call: the same bits, faster on scenes with several
/// punctual lights (`docs/experiments.md`).
#[inline(always)]
pub fn punctual_incidence(light: &Light, p: Vec3) -> Option<PunctualIncidence> {
    match *light {
        Light::Point { position, intensity, range } => {
            let d = position - p;
            let r2 = d.length_squared();
            let r = r2.sqrt();
            if !(r2 > 0.0) || range.is_some_and(|rg| r > rg) {
                return None;
            }
            Some(PunctualIncidence { wi: d / r, distance: r, irradiance: intensity / r2 })
        }
        Light::Spot { position, direction, intensity, inner_cone_angle, outer_cone_angle, range } => {
            let d = position - p;
            let r2 = d.length_squared();
            let r = r2.sqrt();
            if !(r2 > 0.0) || range.is_some_and(|rg| r > rg) {
                return None;
            }
            let wi = d / r;
            let falloff = spot_falloff(direction.dot(-wi), inner_cone_angle, outer_cone_angle);
            if falloff <= 0.0 {
                return None;
            }
            Some(PunctualIncidence { wi, distance: r, irradiance: intensity * (falloff / r2) })
        }
        Light::Directional { direction, illuminance } => {
            let wi = -direction.normalize_or_zero();
            if wi == Vec3::ZERO {
                return None;
            }
            Some(PunctualIncidence { wi, distance: f32::INFINITY, irradiance: illuminance })
        }
    }
}

/// An equirectangular environment map in Mitsuba 3's `envmap` convention (so the Mitsuba
/// cross-check can load the same file with an identity `to_world`): the direction towards
/// the environment for image coordinates `(u, v) ∈ [0, 1)²` (u to the right, v down from the
/// top row) is, with `φ = 2π u`, `θ = π v`,
/// `ω = (sin φ sin θ, cos θ, −cos φ sin θ)` (world +Y up: the top row is the zenith), and
/// inversely `u = atan2(ω.x, −ω.z) / 2π (mod 1)`, `v = acos(ω.y) / π`.
///
/// Radiance is piecewise constant (nearest texel; texel `(i, j)` covers
/// `[i/W, (i+1)/W) × [j/H, (j+1)/H)`). Sampling: a 2D piecewise-constant distribution with
/// texel weights `w_ij = Y(L_ij) · sin θ_j` (Y luminance, θ_j at the row's centre; a texel
/// with zero luminance but some positive channel gets `10⁻³ × max channel`): a row from the
/// marginal CDF, a texel from that row's conditional CDF, a uniform point inside it. The
/// density per unit area of the unit square is `p(u, v) = W H w_ij / Σ w`, and per steradian
/// `pdf(ω) = p(u, v) / (2π² sin θ)` (the Jacobian of the equirectangular map).
#[derive(Clone, Debug, PartialEq)]
pub struct EnvironmentMap {
    width: u32,
    height: u32,
    /// Linear RGB radiance, row-major from the top row.
    texels: Vec<Vec3>,
    /// Inclusive CDF over rows (normalised), `height` entries.
    marginal_cdf: Vec<f32>,
    /// Per row, the inclusive CDF over its texels (normalised), `width × height` entries.
    conditional_cdf: Vec<f32>,
    /// `W H w_ij / Σ w` per texel: the density over the unit square.
    density: Vec<f32>,
}

impl EnvironmentMap {
    /// A map from `width × height` linear RGB texels (row-major, top row first). Negative or
    /// non-finite channels are read as 0. Errors name what is wrong.
    pub fn from_texels(width: u32, height: u32, texels: Vec<Vec3>) -> Result<Self, String> {
        let (w, h) = (width as usize, height as usize);
        if w == 0 || h == 0 || texels.len() != w * h {
            return Err(format!("environment map of {width}×{height} with {} texels", texels.len()));
        }
        let texels: Vec<Vec3> = texels.into_iter().map(|c| Vec3::from_array(c.to_array().map(|x| if x.is_finite() && x > 0.0 { x } else { 0.0 }))).collect();
        let mut weights = vec![0.0f64; w * h];
        let mut row_sums = vec![0.0f64; h];
        for j in 0..h {
            let sin_t = (PI as f64 * (j as f64 + 0.5) / h as f64).sin();
            for i in 0..w {
                let c = texels[j * w + i];
                let y = luminance(c);
                let y = if y > 0.0 { y } else { 1e-3 * c.max_element() };
                let wt = y as f64 * sin_t;
                weights[j * w + i] = wt;
                row_sums[j] += wt;
            }
        }
        let total: f64 = row_sums.iter().sum();
        let mut marginal_cdf = vec![0.0f32; h];
        let mut conditional_cdf = vec![0.0f32; w * h];
        let mut density = vec![0.0f32; w * h];
        let mut acc = 0.0f64;
        for j in 0..h {
            acc += row_sums[j];
            marginal_cdf[j] = if total > 0.0 { (acc / total) as f32 } else { (j + 1) as f32 / h as f32 };
            let mut racc = 0.0f64;
            for i in 0..w {
                racc += weights[j * w + i];
                conditional_cdf[j * w + i] = if row_sums[j] > 0.0 { (racc / row_sums[j]) as f32 } else { (i + 1) as f32 / w as f32 };
                density[j * w + i] = if total > 0.0 { (weights[j * w + i] * (w * h) as f64 / total) as f32 } else { 0.0 };
            }
            conditional_cdf[j * w + w - 1] = 1.0;
        }
        marginal_cdf[h - 1] = 1.0;
        Ok(Self { width, height, texels, marginal_cdf, conditional_cdf, density })
    }

    /// Reads an equirectangular map: OpenEXR (`.exr`, first RGBA layer) or Radiance HDR
    /// (`.hdr`), linear radiance.
    pub fn load(path: &Path) -> Result<Self, PathTracerError> {
        let err = |m: String| PathTracerError::import(path, m);
        let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).unwrap_or_default();
        let (w, h, texels) = match ext.as_str() {
            "exr" => {
                struct Px {
                    w: usize,
                    data: Vec<Vec3>,
                }
                let img = exr::prelude::read_first_rgba_layer_from_file(
                    path,
                    |res, _| Px { w: res.width(), data: vec![Vec3::ZERO; res.width() * res.height()] },
                    |px: &mut Px, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                        let w = px.w;
                        px.data[pos.y() * w + pos.x()] = Vec3::new(r, g, b);
                    },
                )
                .map_err(|e| err(format!("reading environment map: {e}")))?;
                let size = img.layer_data.size;
                (size.width() as u32, size.height() as u32, img.layer_data.channel_data.pixels.data)
            }
            "hdr" => {
                let img = image::ImageReader::open(path)
                    .map_err(|e| err(format!("reading environment map: {e}")))?
                    .with_guessed_format()
                    .map_err(|e| err(format!("reading environment map: {e}")))?
                    .decode()
                    .map_err(|e| err(format!("decoding environment map: {e}")))?
                    .into_rgb32f();
                let (w, h) = img.dimensions();
                (w, h, img.pixels().map(|p| Vec3::new(p.0[0], p.0[1], p.0[2])).collect())
            }
            _ => return Err(err("environment map must be .exr or .hdr".into())),
        };
        Self::from_texels(w, h, texels).map_err(err)
    }

    /// Width and height in texels.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The direction for image coordinates `uv` (see the type docs).
    pub fn direction(uv: Vec2) -> Vec3 {
        let (phi, theta) = (2.0 * PI * uv.x, PI * uv.y);
        let (st, ct) = theta.sin_cos();
        let (sp, cp) = phi.sin_cos();
        Vec3::new(sp * st, ct, -cp * st)
    }

    /// Image coordinates of a unit direction (inverse of [`EnvironmentMap::direction`]).
    pub fn uv(dir: Vec3) -> Vec2 {
        let u = (dir.x.atan2(-dir.z) / (2.0 * PI)).rem_euclid(1.0);
        let v = dir.y.clamp(-1.0, 1.0).acos() / PI;
        Vec2::new(if u < 1.0 { u } else { 0.0 }, v)
    }

    fn texel_index(&self, uv: Vec2) -> usize {
        let i = ((uv.x * self.width as f32) as usize).min(self.width as usize - 1);
        let j = ((uv.y * self.height as f32) as usize).min(self.height as usize - 1);
        j * self.width as usize + i
    }

    /// Radiance towards unit direction `dir` (nearest texel).
    pub fn radiance(&self, dir: Vec3) -> Vec3 {
        self.texels[self.texel_index(Self::uv(dir))]
    }

    /// Density per steradian with which [`EnvironmentMap::sample`] draws `dir`.
    pub fn pdf(&self, dir: Vec3) -> f32 {
        let uv = Self::uv(dir);
        let sin_t = (dir.x * dir.x + dir.z * dir.z).sqrt();
        if !(sin_t > 0.0) {
            return 0.0;
        }
        self.density[self.texel_index(uv)] / (2.0 * PI * PI * sin_t)
    }

    /// A direction drawn in proportion to luminance × sin θ, and its density per steradian
    /// (`None` at the poles, where the density is undefined).
    pub fn sample(&self, u: Vec2) -> Option<(Vec3, f32)> {
        let (w, h) = (self.width as usize, self.height as usize);
        let j = self.marginal_cdf.partition_point(|&c| c <= u.y).min(h - 1);
        let lo = if j == 0 { 0.0 } else { self.marginal_cdf[j - 1] };
        let fy = ((u.y - lo) / (self.marginal_cdf[j] - lo)).clamp(0.0, 1.0);
        let row = &self.conditional_cdf[j * w..(j + 1) * w];
        let i = row.partition_point(|&c| c <= u.x).min(w - 1);
        let lo = if i == 0 { 0.0 } else { row[i - 1] };
        let fx = ((u.x - lo) / (row[i] - lo)).clamp(0.0, 1.0);
        let fx = if fx.is_finite() { fx } else { 0.5 };
        let fy = if fy.is_finite() { fy } else { 0.5 };
        let uv = Vec2::new((i as f32 + fx) / w as f32, (j as f32 + fy) / h as f32);
        let dir = Self::direction(uv);
        let sin_t = (PI * uv.y).sin();
        let pdf = self.density[j * w + i] / (2.0 * PI * PI * sin_t);
        (pdf > 0.0 && pdf.is_finite()).then_some((dir, pdf))
    }
}

/// The environment: radiance `radiance × map(ω)` from every direction ω, or `radiance`
/// everywhere without a map (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct Environment {
    /// Linear RGB radiance (without a map) or scale of the map.
    pub radiance: Vec3,
    /// Optional equirectangular map.
    pub map: Option<Arc<EnvironmentMap>>,
}

impl Environment {
    /// Density of the constant environment's sampling: `1 / 4π` per steradian.
    pub const PDF: f32 = 1.0 / (4.0 * PI);
    /// A constant environment.
    pub fn constant(radiance: Vec3) -> Self {
        Self { radiance, map: None }
    }
    /// Whether the environment emits nothing.
    pub fn is_black(&self) -> bool {
        self.radiance.max_element() <= 0.0
    }
    /// Radiance arriving from unit direction `dir` (pointing away from the scene).
    pub fn eval(&self, dir: Vec3) -> Vec3 {
        match &self.map {
            None => self.radiance,
            Some(m) => self.radiance * m.radiance(dir),
        }
    }
    /// A direction and its density per steradian (uniform without a map, importance sampled
    /// with one).
    pub fn sample(&self, u: Vec2) -> Option<(Vec3, f32)> {
        match &self.map {
            None => Some((sample_uniform_sphere(u), Self::PDF)),
            Some(m) => m.sample(u),
        }
    }
    /// Density of [`Environment::sample`] at `dir`.
    pub fn pdf(&self, dir: Vec3) -> f32 {
        match &self.map {
            None => Self::PDF,
            Some(m) => m.pdf(dir),
        }
    }
}

/// A point sampled on an emissive triangle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EmitterSample {
    /// Triangle index.
    pub prim: u32,
    /// Barycentrics of the point.
    pub b: [f32; 3],
    /// Probability of having picked this triangle.
    pub pmf: f32,
    /// Area of the triangle.
    pub area: f32,
}

/// Narrowest CDF interval whose rescaled number [`EmissiveTriangles::sample`] reuses for the
/// point: `2⁻¹²`, so at least 12 of a uniform `f32`'s 24 bits remain.
pub const MIN_REUSED_INTERVAL: f32 = 1.0 / 4096.0;

/// Largest `f32` below 1.
const ONE_MINUS_EPSILON: f32 = 1.0 - f32::EPSILON / 2.0;

/// The table of emissive triangles, sampled proportionally to power.
#[derive(Clone, Debug, Default)]
pub struct EmissiveTriangles {
    prims: Vec<u32>,
    /// Inclusive normalised CDF over `prims`.
    cdf: Vec<f32>,
    /// Probability of each scene triangle (0 for non-emissive ones).
    pmf_by_prim: Vec<f32>,
    area_by_prim: Vec<f32>,
    total_power: f64,
}

impl EmissiveTriangles {
    /// Collects the emissive triangles of `scene` (indices assumed validated).
    pub fn build(scene: &Scene) -> Self {
        let mesh = &scene.mesh;
        let n = mesh.indices.len();
        let mut prims = Vec::new();
        let mut weights = Vec::new();
        let mut area_by_prim = vec![0.0f32; n];
        // Mean luminance of each emissive material's emissive texture (1 without one).
        let tex_mean: Vec<f64> = scene
            .materials
            .iter()
            .map(|m| {
                let Some(t) = m.emissive_texture.filter(|_| m.is_emissive()).and_then(|r| scene.textures.get(r.texture as usize)) else { return 1.0 };
                if t.texels.is_empty() {
                    return 1.0;
                }
                t.texels.iter().map(|c| luminance(c.truncate().max(Vec3::ZERO)) as f64).sum::<f64>() / t.texels.len() as f64
            })
            .collect();
        for (k, idx) in mesh.indices.iter().enumerate() {
            let Some(m) = mesh.material.get(k).and_then(|&m| scene.materials.get(m as usize)) else { continue };
            if !m.is_emissive() {
                continue;
            }
            let p = idx.map(|i| mesh.positions[i as usize]);
            let area = 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length();
            if !(area > 0.0) || !area.is_finite() {
                continue;
            }
            area_by_prim[k] = area;
            let sides = if m.double_sided { 2.0 } else { 1.0 };
            let tex = tex_mean[mesh.material[k] as usize];
            let w = area as f64 * luminance(m.emissive.max(Vec3::ZERO)) as f64 * tex * sides * std::f64::consts::PI;
            if w > 0.0 && w.is_finite() {
                prims.push(k as u32);
                weights.push(w);
            }
        }
        let total: f64 = weights.iter().sum();
        let mut cdf = Vec::with_capacity(weights.len());
        let mut pmf_by_prim = vec![0.0f32; n];
        let mut acc = 0.0f64;
        for (i, &w) in weights.iter().enumerate() {
            acc += w;
            cdf.push((acc / total) as f32);
            pmf_by_prim[prims[i] as usize] = (w / total) as f32;
        }
        if let Some(last) = cdf.last_mut() {
            *last = 1.0;
        }
        Self { prims, cdf, pmf_by_prim, area_by_prim, total_power: total }
    }

    /// Whether there are no emissive triangles.
    pub fn is_empty(&self) -> bool {
        self.prims.is_empty()
    }

    /// Number of emissive triangles.
    pub fn len(&self) -> usize {
        self.prims.len()
    }

    /// Sum of the power proxies (W: emissive factors × mean emissive-texture luminance).
    pub fn total_power(&self) -> f64 {
        self.total_power
    }

    /// Probability of picking triangle `prim`.
    pub fn pmf(&self, prim: u32) -> f32 {
        self.pmf_by_prim.get(prim as usize).copied().unwrap_or(0.0)
    }

    /// Area of triangle `prim` (0 for non-emissive ones).
    pub fn area(&self, prim: u32) -> f32 {
        self.area_by_prim.get(prim as usize).copied().unwrap_or(0.0)
    }

    /// Picks a triangle and a uniform point on it from one 2D sample `u`: `u.x` picks the
    /// triangle through the CDF and, rescaled to `[0, 1)` within the picked triangle's CDF
    /// interval, is reused with `u.y` for the point (pbrt's sample reuse). So the points of a
    /// stratified 2D set stay stratified over the whole emitting surface, not only over each
    /// triangle: with a separate number for the choice, the samples landing on one triangle
    /// would be an arbitrary subset of the 2D set, no better spread than random points (a
    /// quad light, two triangles, lost its stratification that way).
    ///
    /// Where the picked interval is narrower than [`MIN_REUSED_INTERVAL`] (one triangle among
    /// thousands), the rescaled `u.x` would keep too few bits to place a point, so `spare()`
    /// (an independent uniform number) replaces it. Either way the point is uniform on the
    /// triangle, so the estimate is unbiased.
    #[inline(always)]
    pub fn sample(&self, u: Vec2, spare: impl FnOnce() -> f32) -> Option<EmitterSample> {
        if self.prims.is_empty() {
            return None;
        }
        let i = self.cdf.partition_point(|&c| c <= u.x).min(self.prims.len() - 1);
        let prim = self.prims[i];
        let lo = if i == 0 { 0.0 } else { self.cdf[i - 1] };
        let width = self.cdf[i] - lo;
        let ux = if width >= MIN_REUSED_INTERVAL { ((u.x - lo) / width).clamp(0.0, ONE_MINUS_EPSILON) } else { spare() };
        Some(EmitterSample { prim, b: sample_uniform_triangle(Vec2::new(ux, u.y)), pmf: self.pmf(prim), area: self.area(prim) })
    }

    /// Solid-angle density at a receiver of sampling point on `prim` at `distance` whose
    /// emitter-side cosine is `cos_light`: `pmf / area · r² / |cos|`.
    pub fn pdf_solid_angle(&self, prim: u32, distance: f32, cos_light: f32) -> f32 {
        solid_angle_density(self.pmf(prim), self.area(prim), distance, cos_light)
    }
}

/// The solid-angle density at a receiver of a point drawn uniformly on a triangle of area
/// `area` picked with probability `pmf`, at `distance`, whose emitter-side cosine is
/// `cos_light`: `pmf / area · r² / |cos|` (0 where any factor is not positive).
#[inline(always)]
pub(crate) fn solid_angle_density(pmf: f32, area: f32, distance: f32, cos_light: f32) -> f32 {
    let c = cos_light.abs();
    if pmf <= 0.0 || area <= 0.0 || c <= 0.0 {
        return 0.0;
    }
    pmf / area * distance * distance / c
}

impl EnvironmentMap {
    /// The linear RGB texels, row-major from the top row (`width × height`), as loaded (for
    /// exporting the map to another renderer).
    pub fn texels(&self) -> &[Vec3] {
        &self.texels
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::sampler::Sampler;

    /// A 16 × 8 map with a bright spot, a gradient and a black texel.
    fn test_map() -> EnvironmentMap {
        let (w, h) = (16u32, 8u32);
        let mut t = Vec::new();
        for j in 0..h {
            for i in 0..w {
                let mut c = Vec3::new(0.2 + 0.05 * i as f32, 0.1 + 0.1 * j as f32, 0.3);
                if (i, j) == (5, 2) {
                    c = Vec3::new(50.0, 40.0, 30.0);
                }
                if (i, j) == (9, 6) {
                    c = Vec3::ZERO;
                }
                t.push(c);
            }
        }
        EnvironmentMap::from_texels(w, h, t).unwrap()
    }

    #[test]
    fn environment_map_directions_round_trip_in_mitsuba_orientation() {
        // Top row is +Y; u = 0 looks down −Z, u = 1/4 down +X (Mitsuba 3 envmap).
        assert!((EnvironmentMap::direction(Vec2::new(0.3, 0.0)) - Vec3::Y).length() < 1e-6);
        assert!((EnvironmentMap::direction(Vec2::new(0.0, 0.5)) - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-6);
        assert!((EnvironmentMap::direction(Vec2::new(0.25, 0.5)) - Vec3::X).length() < 1e-6);
        for k in 0..1000u64 {
            let uv = Sampler::new(1, 0, k, 0).next_2d() * 0.998 + Vec2::splat(0.001);
            let back = EnvironmentMap::uv(EnvironmentMap::direction(uv));
            assert!((back - uv).length() < 1e-4, "{uv} -> {back}");
        }
    }

    #[test]
    fn environment_map_pdf_integrates_to_one_and_matches_sampling() {
        let m = test_map();
        // ∫ pdf dω = ∫∫ pdf sin θ dθ dφ by the midpoint rule on a (θ, φ) grid aligned with the
        // texels (8 × 8 points per texel), so the piecewise-constant density is integrated
        // exactly up to the sin θ quadrature: 1.
        let (nt, np) = (8 * 8, 16 * 8);
        let mut total = 0.0f64;
        for a in 0..nt {
            for b in 0..np {
                let (t, phi) = (PI * (a as f32 + 0.5) / nt as f32, 2.0 * PI * (b as f32 + 0.5) / np as f32);
                let d = EnvironmentMap::direction(Vec2::new(phi / (2.0 * PI), t / PI));
                total += (m.pdf(d) * t.sin()) as f64;
            }
        }
        total *= (PI as f64 / nt as f64) * (2.0 * std::f64::consts::PI / np as f64);
        assert!((total - 1.0).abs() < 1e-4, "∫pdf = {total}");
        // Sampled pdf equals pdf(dir); the importance-sampled estimate of ∫ L dω equals the
        // exact sum Σ L_ij ΔΩ_ij with ΔΩ_ij = (2π/W)(cos θ_j − cos θ_j+1), within 4σ.
        let (w, h) = m.size();
        let mut exact = 0.0f64;
        for j in 0..h {
            let (t0, t1) = (PI * j as f32 / h as f32, PI * (j + 1) as f32 / h as f32);
            let dw = 2.0 * std::f64::consts::PI / w as f64 * (t0.cos() - t1.cos()) as f64;
            for i in 0..w {
                exact += luminance(m.texels[(j * w + i) as usize]) as f64 * dw;
            }
        }
        let n = 200_000u64;
        let (mut s1, mut s2) = (0.0f64, 0.0f64);
        for k in 0..n {
            let Some((d, pdf)) = m.sample(Sampler::new(2, 0, k, 0).next_2d()) else { continue };
            assert!((m.pdf(d) - pdf).abs() <= 1e-3 * pdf, "{} vs {pdf}", m.pdf(d));
            let v = luminance(m.radiance(d)) as f64 / pdf as f64;
            s1 += v;
            s2 += v * v;
        }
        let mean = s1 / n as f64;
        let se = ((s2 / n as f64 - mean * mean).max(0.0) / n as f64).sqrt();
        assert!((mean - exact).abs() < 4.0 * se + 1e-6 * exact, "{mean} ± {se} vs {exact}");
        // The bright texel (1/128 of the texels) is sampled in proportion to its weight.
        let hits = (0..10_000u64).filter(|&k| m.sample(Sampler::new(3, 0, k, 0).next_2d()).is_some_and(|(d, _)| {
            let uv = EnvironmentMap::uv(d);
            ((uv.x * 16.0) as u32, (uv.y * 8.0) as u32) == (5, 2)
        })).count();
        // Its probability is its weight share, density / (W H) (binomial 4σ).
        let p = m.density[(2 * w + 5) as usize] as f64 / (w * h) as f64;
        let sd = (p * (1.0 - p) / 10_000.0).sqrt();
        assert!(p > 0.4 && (hits as f64 / 10_000.0 - p).abs() < 4.0 * sd, "{hits} vs {p}");
        // A black texel is never sampled; bad inputs are errors.
        assert_eq!(m.pdf(EnvironmentMap::direction(Vec2::new(9.5 / 16.0, 6.5 / 8.0))), 0.0);
        assert!(EnvironmentMap::from_texels(2, 2, vec![Vec3::ONE; 3]).is_err());
    }

    #[test]
    fn spot_falloff_matches_gltf_formula() {
        let (inner, outer) = (0.2f32, 0.5f32);
        assert_eq!(spot_falloff(1.0, inner, outer), 1.0);
        assert_eq!(spot_falloff(0.3f32.cos(), inner, 0.3), 0.0);
        let mid = 0.5 * (inner.cos() + outer.cos());
        assert!((spot_falloff(mid, inner, outer) - 0.25).abs() < 1e-5);
        assert_eq!(spot_falloff(0.6f32.cos(), inner, outer), 0.0);
    }

    #[test]
    fn point_light_is_inverse_square_with_range_cutoff() {
        let l = Light::Point { position: Vec3::new(0.0, 2.0, 0.0), intensity: Vec3::splat(8.0), range: Some(3.0) };
        let s = punctual_incidence(&l, Vec3::ZERO).unwrap();
        assert_eq!(s.wi, Vec3::Y);
        assert!((s.irradiance - Vec3::splat(2.0)).abs().max_element() < 1e-6);
        assert!(punctual_incidence(&l, Vec3::new(0.0, -2.0, 0.0)).is_none());
        let d = Light::Directional { direction: -Vec3::Y, illuminance: Vec3::splat(3.0) };
        let s = punctual_incidence(&d, Vec3::ZERO).unwrap();
        assert_eq!((s.wi, s.distance, s.irradiance), (Vec3::Y, f32::INFINITY, Vec3::splat(3.0)));
    }
}
