//! The path loop in lanes: [`PathIntegrator::radiance_batch`] for scenes whose materials are
//! each the same at every point and have no normal map ([`LaneMaterials`]). A bounce's live
//! paths are shaded eight at a time, each step of a vertex one loop over the eight lanes in
//! structure-of-arrays form (the hit point, normals, shading frame and ray origin; the
//! emitter sample's geometry, density and shadow ray; the BSDF's values towards the light
//! samples and its sample), so that the compiler vectorises the arithmetic. Each lane does
//! exactly the operations of the one-path loop in the parent module, so the bits are the
//! same (`vertices_shaded_in_lanes_are_the_one_path_loop_bit_for_bit` in the render tests);
//! what stays scalar is what branches per path: the sampler's numbers, the emitter's choice,
//! the punctual lights' and environment's samples, the ray queries and the additions to the
//! path's radiance (in the one-path loop's order).
//!
//! Only the scenes whose materials qualify use it: elsewhere the scalar work split over
//! several loops costs more than the lanes gain (`docs/experiments.md`).

use super::*;
use crate::light::solid_angle_density;
use crate::material::{BsdfLanes, SampleLane, SampledLanes, evaluate_lanes, sample_lanes};
use crate::sampler::SamplerLanes;

/// Lanes of the loop: eight, the `f32` lanes of an AVX2 register.
const L: usize = 8;

/// Eight `f32` lanes.
type Lanes = [f32; L];
/// Eight 3-vectors, one array per component.
type Lanes3 = [Lanes; 3];

#[inline(always)]
fn get3(a: &Lanes3, k: usize) -> Vec3 {
    Vec3::new(a[0][k], a[1][k], a[2][k])
}

#[inline(always)]
fn set3(a: &mut Lanes3, k: usize, v: Vec3) {
    (a[0][k], a[1][k], a[2][k]) = (v.x, v.y, v.z);
}

/// What the lane loop reads of one material, resolved once.
#[derive(Clone, Copy, Debug)]
pub struct LaneMaterial {
    /// The BSDF (resolved once, [`crate::material::uniform_surface`]) as one lane of the
    /// loops below, less what depends on `wo`.
    bsdf: SampleLane,
    /// Its emission.
    emission: Vec3,
    /// `Material::is_emissive`.
    emissive: bool,
    /// The radiance a light sample on it carries: its emission times its alpha coverage.
    light_radiance: Vec3,
    /// `Material::double_sided`.
    double_sided: bool,
}

/// Per material of a scene, what the lane loop reads; built only where every material is
/// the same at every point and has no normal map ([`LaneMaterials::new`]).
#[derive(Clone, Debug)]
pub struct LaneMaterials(Vec<LaneMaterial>);

impl LaneMaterials {
    /// The table for `scene` whose materials resolve to `uniform` once, or `None` where
    /// some material varies over its surface (`uniform` holds a `None`), has a normal map,
    /// transmits or is layered:
    /// the one-path loop then shades every vertex.
    pub fn new(scene: &Scene, uniform: &[Option<SurfaceMaterial>]) -> Option<Self> {
        let attr = SurfaceAttributes { uv: [Vec2::ZERO; 2], color: Vec4::ONE };
        scene
            .materials
            .iter()
            .zip(uniform)
            .map(|(m, u)| {
                let surf = (*u)?;
                // A normal map, or a BSDF with scalar verbs only (transmissive: rays through
                // the surface; layered: the coat's normal is set per vertex).
                if m.normal_texture.is_some() || matches!(surf.bsdf, crate::material::Bsdf::Transmissive(_) | crate::material::Bsdf::Layered(_)) {
                    return None;
                }
                // What `emitter_pending` computes for a light sample on this material, whose
                // attributes at any point are the defaults (no texture, no vertex colour).
                let coverage = match m.alpha_mode {
                    AlphaMode::Opaque => 1.0,
                    AlphaMode::Mask { cutoff } => {
                        if base_color(m, &scene.textures, &attr).w >= cutoff { 1.0 } else { 0.0 }
                    }
                    AlphaMode::Blend => base_color(m, &scene.textures, &attr).w.clamp(0.0, 1.0),
                };
                Some(LaneMaterial {
                    bsdf: surf.bsdf.at(Vec3::Z).lane(Vec2::ZERO),
                    emission: surf.emission,
                    emissive: m.is_emissive(),
                    light_radiance: emission(m, &scene.textures, &attr) * coverage,
                    double_sided: m.double_sided,
                })
            })
            .collect::<Option<Vec<_>>>()
            .map(Self)
    }
}

/// A light sample of a lane that stays scalar (a punctual light or the environment map).
struct OtherLight {
    lane: usize,
    /// A punctual light (added before the emitter sample) or the environment (after).
    punctual: bool,
    light: PendingLight,
}

impl PathIntegrator<'_> {
    /// [`PathIntegrator::radiance_batch`]'s loop with the vertices shaded in lanes (the same
    /// bits).
    #[inline(always)]
    pub(super) fn radiance_lanes(&self, mats: &LaneMaterials, rays: &[Ray], samplers: &mut [Sampler], primary_emission: bool, out: &mut [RadianceSample]) {
        let mut stack = TraversalStack::default();
        let (mut paths, mut active) = self.camera_vertices(&mut stack, rays, out);
        let mut next: Vec<u32> = Vec::with_capacity(active.len());
        let mut others: Vec<OtherLight> = Vec::new();
        let mut other_values: Vec<(Vec3, f32)> = Vec::new();
        while !active.is_empty() {
            next.clear();
            for chunk in active.chunks(L) {
                self.vertices_in_lanes(&mut stack, &mats.0, chunk, &mut paths, samplers, primary_emission, out, &mut next, &mut others, &mut other_values);
            }
            std::mem::swap(&mut active, &mut next);
        }
    }

    /// Shades the vertices of the paths `chunk` (at most [`L`]), traces their shadow rays and
    /// continues them; the paths that go on are pushed on `next`, the others' radiance
    /// written to `out`.
    #[allow(clippy::too_many_arguments, clippy::needless_range_loop)]
    #[inline(always)]
    fn vertices_in_lanes(&self, stack: &mut TraversalStack, mats: &[LaneMaterial], chunk: &[u32], paths: &mut [PathState], samplers: &mut [Sampler], primary_emission: bool, out: &mut [RadianceSample], next: &mut Vec<u32>, others: &mut Vec<OtherLight>, other_values: &mut Vec<(Vec3, f32)>) {
        let scene = self.scene;
        let m = &scene.mesh;
        let max_bounces = self.settings.max_bounces;
        let n = chunk.len();
        debug_assert!(n <= L);

        // The lanes' triangles, normals, barycentrics and ray directions. Lanes whose path
        // ends before shading (past the last bounce without emission) stay idle.
        let mut live = [false; L];
        let mut mat = [0usize; L];
        let mut pos = [[[0.0f32; L]; 3]; 3];
        let mut nrm = [[[0.0f32; L]; 3]; 3];
        let mut bary = [[0.0f32; L]; 3];
        let mut dir = [[0.0f32; L]; 3];
        for (k, &id) in chunk.iter().enumerate() {
            let path = &paths[id as usize];
            let prim = path.hit.prim as usize;
            let material = m.material.get(prim).copied().unwrap_or(0) as usize;
            let ok = match mats.get(material) {
                None => false,
                Some(lm) => path.depth < max_bounces || lm.emissive,
            };
            if !ok {
                out[id as usize].radiance = path.l;
                continue;
            }
            live[k] = true;
            mat[k] = material;
            let idx = m.indices[prim];
            for v in 0..3 {
                set3(&mut pos[v], k, m.positions[idx[v] as usize]);
                set3(&mut nrm[v], k, m.normals.get(idx[v] as usize).copied().unwrap_or(Vec3::ZERO));
                bary[v][k] = path.hit.b[v];
            }
            set3(&mut dir, k, path.ray.direction);
        }

        // In lanes: `interaction`, `vertex_bsdf`'s frame (no normal map) and the rays' origin.
        let mut point = [[0.0f32; L]; 3];
        let mut ng = [[0.0f32; L]; 3];
        let mut ng_front = [[0.0f32; L]; 3];
        let mut fs = [[0.0f32; L]; 3];
        let mut ft = [[0.0f32; L]; 3];
        let mut fnn = [[0.0f32; L]; 3];
        let mut wo_l = [[0.0f32; L]; 3];
        let mut origin = [[0.0f32; L]; 3];
        for k in 0..L {
            let p = [get3(&pos[0], k), get3(&pos[1], k), get3(&pos[2], k)];
            let b = [bary[0][k], bary[1][k], bary[2][k]];
            let d = get3(&dir, k);
            let h = hit_geometry(p, [get3(&nrm[0], k), get3(&nrm[1], k), get3(&nrm[2], k)], b, d);
            let wo = -d;
            let frame = shading_frame(h.ns_front, h.n.dot(h.ns_front) < 0.0, wo);
            set3(&mut point, k, h.p);
            set3(&mut ng, k, h.ng);
            set3(&mut ng_front, k, h.ng_front);
            set3(&mut fs, k, frame.s);
            set3(&mut ft, k, frame.t);
            set3(&mut fnn, k, frame.n);
            set3(&mut wo_l, k, frame.to_local(wo));
            set3(&mut origin, k, offset_ray_origin(h.p, h.p_err, h.ng, h.ng));
        }
        let frame_of = |k: usize| Frame { s: get3(&fs, k), t: get3(&ft, k), n: get3(&fnn, k) };

        // Per lane: the emission seen, the sampler's block, the BSDF's lane, the punctual
        // lights and environment samples, and the emitter's choice.
        let mut shading = [false; L];
        let mut dims = [0u32; L];
        let mut x = BsdfLanes::default();
        let mut sl = SamplerLanes::default();
        let mut e_sampled = [false; L];
        let mut e_pos = [[[0.0f32; L]; 3]; 3];
        let mut e_bary = [[0.0f32; L]; 3];
        let mut e_double = [false; L];
        let mut e_le = [[0.0f32; L]; 3];
        let mut e_pmf = [0.0f32; L];
        let mut e_area = [0.0f32; L];
        others.clear();
        for (k, &id) in chunk.iter().enumerate() {
            if !live[k] {
                continue;
            }
            let path = &mut paths[id as usize];
            let lm = &mats[mat[k]];
            self.add_emission_seen(path, lm.emission, get3(&ng_front, k), primary_emission);
            if path.depth >= max_bounces {
                out[id as usize].radiance = path.l;
                continue;
            }
            shading[k] = true;
            let sampler = &mut samplers[id as usize];
            dims[k] = sampler.skip(VERTEX_DIMENSIONS);
            sl.set(k, sampler);
        }
        // The vertices' numbers, in lanes.
        let at = |off: u32| dims.map(|d| d + off);
        let u_emitter = sl.get_2d(&at(DIM_EMITTER_POINT));
        let u_spare = sl.get_1d(&at(DIM_EMITTER_SPARE));
        let u_env = if self.samples_environment() { sl.get_2d(&at(DIM_ENVIRONMENT)) } else { [[0.0; L]; 2] };
        let u_bsdf = sl.get_2d(&at(DIM_BSDF));
        let u_roulette = sl.get_1d(&at(DIM_ROULETTE));
        // Per lane: the punctual lights and environment samples, and the emitter's choice.
        for (k, &id) in chunk.iter().enumerate() {
            if !shading[k] {
                continue;
            }
            let path = &mut paths[id as usize];
            let lm = &mats[mat[k]];
            let frame = frame_of(k);
            x.set(k, &lm.bsdf.with_wo(get3(&wo_l, k)));
            let p = get3(&point, k);
            let g = get3(&ng, k);
            let o = get3(&origin, k);
            if !self.caustic_vertex(path, mat[k] as u32) {
                self.punctual_samples(p, g, o, None, &frame, |light| others.push(OtherLight { lane: k, punctual: true, light }));
            }
            if !self.emitters.is_empty()
                && let Some(es) = self.emitters.sample(Vec2::new(u_emitter[0][k], u_emitter[1][k]), || u_spare[k])
            {
                let idx = m.indices[es.prim as usize];
                let lmat = m.material.get(es.prim as usize).and_then(|&q| mats.get(q as usize));
                if let Some(lmat) = lmat {
                    e_sampled[k] = true;
                    for v in 0..3 {
                        set3(&mut e_pos[v], k, m.positions[idx[v] as usize]);
                        e_bary[v][k] = es.b[v];
                    }
                    e_double[k] = lmat.double_sided;
                    set3(&mut e_le, k, lmat.light_radiance);
                    e_pmf[k] = self.emitters.pmf(es.prim);
                    e_area[k] = self.emitters.area(es.prim);
                }
            }
            if self.samples_environment()
                && let Some(light) = self.environment_sample(Vec2::new(u_env[0][k], u_env[1][k]), g, o, None, &frame)
            {
                others.push(OtherLight { lane: k, punctual: false, light });
            }
        }

        // In lanes: what the BSDFs compute once from `wo` (`Bsdf::at`).
        for k in 0..L {
            x.set_wo_terms(k);
        }
        let all_diffuse = (0..n).all(|k| !shading[k] || x.is_lambertian(k));

        // In lanes: the emitter sample (`emitter_pending`) and the BSDF's value towards it.
        let mut e_ok = [false; L];
        let mut e_wi_l = [[0.0f32; L]; 3];
        let mut e_pdf = [0.0f32; L];
        let mut e_dir = [[0.0f32; L]; 3];
        let mut e_tmax = [0.0f32; L];
        let mut e_f = [[0.0f32; L]; 3];
        let mut e_bsdf_pdf = [0.0f32; L];
        if e_sampled.contains(&true) {
            for k in 0..L {
                let p = [get3(&e_pos[0], k), get3(&e_pos[1], k), get3(&e_pos[2], k)];
                let b = [e_bary[0][k], e_bary[1][k], e_bary[2][k]];
                let sp = get3(&point, k);
                let g = get3(&ng, k);
                let (q, q_err) = hit_point_error(p, b);
                let n_l = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero();
                let d = q - sp;
                let dist = d.length();
                let wi = d / dist;
                let cos_l = n_l.dot(-wi);
                let le = get3(&e_le, k);
                let light_pdf = solid_angle_density(e_pmf[k], e_area[k], dist, cos_l);
                let target = offset_ray_origin(q, q_err, n_l, -wi);
                let seg = target - get3(&origin, k);
                let len = seg.length();
                set3(&mut e_wi_l, k, frame_of(k).to_local(wi));
                set3(&mut e_dir, k, seg / len);
                e_tmax[k] = len * (1.0 - SHADOW_EPSILON);
                e_pdf[k] = light_pdf;
                e_ok[k] = e_sampled[k] & (dist > 0.0) & !(wi.dot(g) <= 0.0) & (e_double[k] | !(cos_l <= 0.0)) & !(le.max_element() <= 0.0) & (light_pdf > 0.0) & light_pdf.is_finite() & (len > 0.0);
            }
            evaluate_lanes(&x, all_diffuse, &e_wi_l, &mut e_f, &mut e_bsdf_pdf);
        }
        // The other light samples' BSDF values, eight at a time in lanes.
        other_values.clear();
        for group in others.chunks(L) {
            let mut y = BsdfLanes::default();
            let mut wi = [[0.0f32; L]; 3];
            for (j, o) in group.iter().enumerate() {
                y.set(j, &x.get(o.lane, Vec2::ZERO));
                set3(&mut wi, j, o.light.wi_l);
            }
            let mut f = [[0.0f32; L]; 3];
            let mut pdf = [0.0f32; L];
            evaluate_lanes(&y, group.iter().all(|o| x.is_lambertian(o.lane)), &wi, &mut f, &mut pdf);
            other_values.extend((0..group.len()).map(|j| (get3(&f, j), pdf[j])));
        }

        // The light samples' estimates, in the one-path code's order per path: punctual
        // lights, the emitter, the environment.
        let mut cursor = 0;
        for (k, &id) in chunk.iter().enumerate() {
            if !shading[k] {
                continue;
            }
            let path = &mut paths[id as usize];
            while cursor < others.len() && others[cursor].lane == k && others[cursor].punctual {
                self.add_light_estimate(stack, path, &others[cursor].light, other_values[cursor]);
                cursor += 1;
            }
            if e_ok[k] {
                // `add_light_estimate` with the shadow ray traced before the light sample is
                // gathered into a `PendingLight` (the same bits): the query then reads its ray
                // from registers, not back from the record's memory just written.
                let (f, shadow) = (get3(&e_f, k), Ray::new(get3(&origin, k), get3(&e_dir, k)));
                if traces_shadow_ray(f) && !self.occluded_in(stack, &shadow, e_tmax[k]) {
                    let e = PendingLight { vertex: 0, wi_l: get3(&e_wi_l, k), radiance: get3(&e_le, k), light_pdf: Some(e_pdf[k]), shadow, t_max: e_tmax[k], light: LIGHT_EMITTERS };
                    Self::add_unblocked(path, &e, f, e_bsdf_pdf[k]);
                }
            }
            while cursor < others.len() && others[cursor].lane == k {
                self.add_light_estimate(stack, path, &others[cursor].light, other_values[cursor]);
                cursor += 1;
            }
        }

        // In lanes: the BSDF samples, their world directions.
        let mut sampled = SampledLanes::default();
        sample_lanes(&x, all_diffuse, &u_bsdf, &mut sampled);
        let mut s_wi = [[0.0f32; L]; 3];
        for k in 0..L {
            set3(&mut s_wi, k, frame_of(k).to_world(get3(&sampled.wi, k)).normalize());
        }

        // Per lane: `continue_path` (Russian roulette, the next ray traced).
        for (k, &id) in chunk.iter().enumerate() {
            if !shading[k] {
                continue;
            }
            let path = &mut paths[id as usize];
            let goes_on = sampled.ok[k] && self.continue_along(stack, path, get3(&origin, k), get3(&ng, k), get3(&s_wi, k), get3(&sampled.weight, k), sampled.pdf[k], || u_roulette[k]);
            if goes_on {
                next.push(id);
            } else {
                out[id as usize].radiance = path.l;
            }
        }
    }
}
