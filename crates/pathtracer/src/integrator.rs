//! The integrator: the radiance arriving along ONE ray. Tiling, parallelism and accumulation
//! live in [`crate::render`].
//!
//! [`PathIntegrator::radiance`] is a unidirectional path tracer:
//! - Next-event estimation at every vertex: every punctual light deterministically (they are
//!   delta lights, so no MIS), one sample of the emissive triangles and, for an environment
//!   map, one of the environment, each combined with BSDF sampling by multiple importance
//!   sampling with the power heuristic (Veach 1997). A BSDF-sampled ray that hits an emitter or
//!   escapes to the environment adds the complementary MIS-weighted term. A constant
//!   environment is reached by BSDF sampling alone (weight 1): its light sampling (uniform
//!   over the sphere) is nearly always the worse strategy against the BSDF's (for a Lambertian
//!   surface, cosine sampling of a constant environment has no variance but visibility) and
//!   would cost a shadow ray per vertex, usually occluded in closed scenes.
//!   (A shadow ray to ONE punctual light per vertex, picked in proportion to the luminance of
//!   its unoccluded contribution, as Mitsuba traces one ray to one sampled emitter, gave
//!   5–15 % more samples/s on the multi-light scenes but 1.05x (`materials`, glTF) to 2.7x
//!   (`thin`, Lambert) the error at 64 spp, from penumbrae, where the lights' visibilities
//!   differ; at equal error it lost on 22 of those scenes' 24 rows. Measured at stop 55
//!   with `xtask bench render` (15 renders per row); not kept.)
//!   (Stop 67: one punctual light only at the vertices after the camera vertex, picked in
//!   proportion to the luminance of its irradiance times `cos θ` at the geometric normal, a
//!   number of its own in the vertex's block, every light at the camera vertex: `xtask bench
//!   render --no-mitsuba`, 15 renders per row, MSE × time against the same day's run of the
//!   kept code: `deep` (four lights) 3–5 % better, `materials` (three) 3–4 % worse,
//!   `tabletop` (two) 10–14 % worse; samples/s `deep` +6–8 %, the others within ±3 %. Not
//!   kept.)
//! - Where `cornell`'s error is, and what did not lower it (stop 56, `xtask bench render
//!   --scenes cornell --no-mitsuba`, 5 renders per row, 128 px, 64 spp, MSE against the same
//!   build's 1024-spp reference less that reference's noise; each change unbiased, the
//!   references' means equal to 1e-5):
//!   - 16 emitter samples instead of one at every vertex after the first: MSE −11 % (glTF)
//!     and −12 % (Lambert) at 4.3x the time. Light sampling at the bounces is not where the
//!     error is.
//!   - The BSDF numbers of vertices 0 and 1 (and 2 and 3) as one 4-D Owen-scrambled Sobol'
//!     point (shared shuffled index, Sobol' dimensions 0–3) instead of two padded 2-D ones:
//!     MSE −3 % and −4 %, less than its cost.
//!   - Path guiding: a grid of 8³ to 32³ cells over the scene, each a histogram of incident
//!     radiance (luminance / sampling density) over 16 × 8 equal-solid-angle direction bins
//!     with a 10 % uniform floor, learned from a 4- or 64-spp camera pre-pass, sampled in a
//!     one-sample mixture with the BSDF (guide probability ½ × the diffuse lobe's) and the
//!     mixture density used in every MIS weight. MSE **+9 % to +28 %** at every setting,
//!     +9 % even with the 64-spp, 32³-cell guide. Cosine sampling is already close to
//!     incident radiance × cosine in a closed, diffusely lit room, and what error is left
//!     sits in shadow and wall edges finer than a cell and a bin; the mixture spends half
//!     the well-stratified BSDF samples on the coarse guide.
//!   - (stop 58, the same bench) The error by path length, glTF: MSE 3.1e-6 with
//!     `max_bounces` 0, 4.9e-6 with 1, 8.1e-5 with 2, 1.70e-4 with 4. **97 % of `cornell`'s
//!     error is indirect light**, about half of it the first indirect bounce; 16 emitter
//!     samples at the camera vertex alone: MSE −0.7 %.
//!   - Splitting at the camera vertex: `n` continuations per camera ray, the continuation's
//!     numbers from sample `s·n + k` of the pixel's sequence (so the `spp·n` continuations of
//!     a pixel are one stratified set), radiance their mean. With `spp` camera rays (n× the
//!     paths) the MSE fell as 1/n (×0.455 at n = 2, ×0.217 at 4: what the camera sample
//!     decides is almost error-free at 64 Sobol' camera samples), but the time rose almost as
//!     much: the camera vertex is 13 % of a sample's time on `cornell`, which bounds the gain
//!     (MSE × time 1.17x and 1.2x). With `spp` paths as `spp / n` camera rays, MSE × time at
//!     n = 2 (glTF / Lambert): `cornell` 0.97 / 0.99x, `deep` 1.29 / 1.14x, `materials`
//!     1.79 / 1.31x, `tabletop` 1.13 / 1.21x, **`thin` 0.79 / 0.69x** (its error is the
//!     anti-aliasing of thin geometry, which fewer camera rays worsen); n = 4 was worse than
//!     2 on 8 of 10 rows. Choosing n per view needs a pilot: variances from independent
//!     samples (between and within a camera sample) misjudged every scene (the Sobol' points
//!     remove most of the camera part's error and much of a short continuation's: it chose
//!     n = 8 everywhere, 0.46–0.78x); two replicates per candidate at the render's own `spp`
//!     on 128 pixels (3 % of the time) chose right on `cornell` and `thin` but single
//!     fireflies decided it on `materials` and `tabletop`, and the path loop split into a
//!     camera vertex and a continuation cost 2.6 % more instructions at n = 1. Not kept.
//! - Light sampling alone (weight 1) at the last scattering vertex, so that its BSDF
//!   continuation ray, traced only to find an emitter's MIS-weighted share, is skipped: the
//!   same MSE on every scene (within 0.4 %) and within ±5 % samples/s (the run-to-run noise);
//!   not kept (stop 56).
//! - The path loop is bound by latency, not by instruction count: stop 57 cut the
//!   instructions of a quick view by 10 % on `cornell` and 6 % on `deep` (callgrind, one
//!   thread: materials resolved once, unread attributes dropped, no interaction past the
//!   last bounce, one validity test per query ray, the watertight ray by swizzle), for
//!   +3 % samples per CPU-second on `cornell` and none measurable on `deep` (alternating
//!   runs). What is left per vertex is chains of dependent square roots and divisions
//!   (normalisations) and the traversal's pointer chasing.
//!   A wavefront gave no more (stop 58): the camera rays of a whole row (or 64 of them) at
//!   once, every path's closest hit in one loop over the batch and every path's vertex
//!   shaded in another, until no path was left (the same bits, the queries of a loop
//!   independent of each other) ran 0–7 % slower than this loop (`cornell` −3 to −7 %,
//!   `deep` −4 %, the others within ±3 %), and sorting each batch's rays by direction (octant,
//!   then 8³ bins) before intersecting them 10–15 % slower. One scalar path after another
//!   is not what limits the speed; lanes of SIMD across paths (shading included) would be.
//!   That is what [`PathIntegrator::radiance_batch`] now does for the BSDF sample (stop 60):
//!   a pixel's camera samples advance together, a vertex at a time, and every live path's
//!   BSDF sample is drawn in one loop over lanes that the compiler vectorises
//!   ([`crate::material::sample_many`]: both lobes in every lane, sine and cosine by
//!   [`crate::sampler::sin_cos`], the same bits as one sample alone). Samples per CPU-second
//!   against one path at a time (`cargo bench -p pathtracer --bench render`, two alternating
//!   pairs, 2-core Zen 5): `cornell` +6 %, `deep` +4 %, `tabletop` +1–4 %; the batch without
//!   the vectorised sample was 2–5 % slower than one path at a time. The BSDF's values
//!   towards the light samples (every punctual light, the emitter sample and the
//!   environment-map sample of every vertex of the bounce) are computed the same way ([`crate::material::evaluate_many`]): a vertex
//!   finds its light samples' directions, densities and shadow rays in scalar code, stopping
//!   at the first zero factor, then the bounce's values are computed in one loop over lanes,
//!   then the shadow rays traced. Against the BSDF sample alone in lanes (two to four
//!   alternating pairs), with the value's two models still chosen by a branch (so the loop
//!   did not vectorise): `cornell` +1–2 %, `deep` +1–4 %, `materials` +0–8 %, `tabletop`
//!   +1–3 %, `thin` −7 to +4 %; then with both models computed in every lane and one
//!   selected (the loop vectorised, the same bits), against that (two pairs): `cornell` +4 %,
//!   `deep` +8 %, `materials` +3–5 %, `tabletop` +5–8 %, `thin` +2–4 %. Eight lanes that are
//!   all Lambertian compute that model alone (the same bits): the scenes made Lambertian
//!   (`xtask bench render --no-mitsuba`, 7 renders) `cornell` +2.5–3 %, `deep` +3.5–7 %; as
//!   authored, `cornell` −0.2 to −1.4 % (three alternating pairs). Measured and not kept:
//!   - the BSDF's set-up from `wo` (`P_s` and the Smith term, [`crate::material::Bsdf::at`])
//!     in lanes as well, for the whole bounce before the light values (the environment-map
//!     sample then also waiting for its value): the same bits, within ±2 % on every scene
//!     (two alternating pairs);
//!   - 16 lanes in AVX-512 (both loops called through a `target_feature` function where the
//!     CPU has AVX-512, the same bits): `cornell` −1 %, `deep` ±0 %, `tabletop` −4 to −7 %
//!     against 8 in AVX2; the loops are no longer where the time goes;
//!   - the emitter value computed in the same loop as the BSDF sample (the BSDF moved into the
//!     lanes once for both): `cornell` +4–7 %, but the scenes without emissive triangles
//!     −1 to −4 % (code that runs for nothing there), and the punctual lights left scalar;
//!   - the emitter sample's whole estimate in lanes (the triangle, emission and vertex
//!     gathered per path; the geometry, light pdf, BSDF value and MIS weight of eight samples
//!     in one loop): `cornell` −4 to −6 %, `deep` −3 to −5 %, `tabletop` −1 %. Each sample
//!     moved about 57 numbers in and out of the lanes, and every lane paid the whole estimate
//!     where the scalar code stops at the first zero factor (a light behind the surface).
//!
//!   A batch's camera rays (a pixel's, nearly the same ray) are traced as packets that load
//!   each node once for all of them ([`crate::accel::Accel::closest_hits`], stop 61: the same
//!   bits, `thin` +6–12 %, `tabletop` +3–15 %, `cornell` +1 %, `deep` ±0 against the CWBVH
//!   one-ray loop of then) where the batch holds at least `PACKET_MIN_RAYS` (32; against stop
//!   62's faster one-ray loop they still pay at 32 spp and more, not at 16); every later ray is
//!   traced alone, which measured faster (the accel module docs).
//!   The camera vertices' shadow rays too (stop 67): where a batch's camera vertices have at
//!   least `PACKET_MIN_RAYS` light samples, their shadow rays are grouped by light (a counting
//!   sort, each light's rays in vertex order) and traced as packets
//!   ([`crate::accel::Accel::occluded_many`]); a pixel's rays to one light leave from nearly one
//!   point towards nearly one point. The same bits on every scene; samples per CPU-second in
//!   the one-path loop (`cargo bench -p pathtracer --bench render -- SCENE --seconds 8 --spp 64
//!   --width 128`, three alternating pairs, 2-core Zen 4): `tabletop` −0.2 to +5 %, `materials`
//!   +1.5 to +4.8 %, `deep` −1.3 to +1.1 %. (With a comparison sort instead of the counting
//!   sort `deep` lost 0.3–3 %.) Measured and not kept: a conservative interval test of the
//!   whole packet against a node's eight boxes before the rays' own tests (each box tested by
//!   the packet's bounds on origin and inverse direction, so that a child no ray enters costs
//!   the rays nothing): the same bits and no gain (`deep` and `tabletop` within ±3 %, `thin`
//!   −4 to −1 %): the box tests of coherent packets are not where their time goes. The lane
//!   loop below still traces its chunks' shadow rays one at a time.
//! - Where every material is the same at every point and has no normal map (`cornell`,
//!   `thin`), the whole vertex is shaded in lanes, eight paths at a time (module `lanes`,
//!   stop 65: the same bits, `cornell` +14 % samples per CPU-second, `thin` +2–3 %); the
//!   other scenes keep the loop above, which the lane loop is tested against. A batch's
//!   camera-ray numbers are drawn eight samples at a time in lanes too (`SamplerLanes`, in
//!   [`crate::render::Renderer::render_view`]: `deep` +3 %, `thin` +1–3 %). Measured in this
//!   loop and not kept (stop 65, alternating pairs): the bounce's BSDF numbers drawn in lanes,
//!   ±2 % (within the noise); every number of a bounce's vertices drawn in lanes beforehand,
//!   `deep` −4 to −8 %, `materials` −2 to −4 %, `tabletop` −2 to −5 % (paths that end early
//!   waste theirs).
//! - Where a sample's time goes (stop 59, 2-core Zen 5). Each part below was run twice in
//!   place, the copy's result discarded through `black_box`, and its cost read as the extra
//!   CPU time per sample (`cargo bench -p pathtracer --bench render -- SCENE --seconds 3`,
//!   alternating with the unchanged build, two or three pairs; a copy runs with warm caches,
//!   so the figures are lower bounds). Per sample of the quick views:
//!
//!   | scene | CPU µs | closest hits | shadow rays | closest-hit time | shadow-ray time | traversal in all |
//!   |---|---|---|---|---|---|---|
//!   | `cornell` | 1.26 | 4.04 | 2.51 | 0.27 (21 %) | 0.09 (7 %) | 29 % |
//!   | `deep` | 0.75 | 2.04 | 3.27 | 0.20 (26 %) | 0.13 (18 %) | 44 % |
//!   | `materials` | 0.66 | 1.96 | 1.52 | 0.19 (29 %) | 0.12 (18 %) | 47 % |
//!   | `tabletop` | 0.58 | 1.78 | 1.02 | 0.19 (32 %) | 0.10 (16 %) | 48 % |
//!   | `thin` | 0.40 | 1.64 | 0.76 | 0.12 (31 %) | 0.05 (12 %) | 43 % |
//!
//!   A closest hit costs 67 ns (`cornell`) to 104 ns (`tabletop`), a shadow ray 36–93 ns; the
//!   triangle tests are 17 % of `cornell`'s time (9 % `deep`, 14 % `tabletop`) and the child-box
//!   tests 6 % (13 %, 14 %). The rest, 0.14–0.22 µs per path vertex (600–900 cycles), is
//!   shading; on `cornell`: the BSDF's sample 20 %, the emitter sample's estimate without its
//!   shadow ray 17 %, the interaction 10 %, the BSDF set-up 8 %, the sampler's five numbers 5 %.
//!   Divisions and square roots are 1.4 % of the instructions (about 160 per sample, callgrind
//!   per instruction), so they are not what bounds it; the scalar code's `Vec3` moves and
//!   branches are. The glTF BRDF's set-up and sample (`Bsdf::at` + `BsdfAt::sample`) alone take
//!   73 ns per call at x86-64-v3 even when every call is independent of the last; a
//!   structure-of-arrays copy of it in 8 AVX2 lanes (both lobes computed in every lane and
//!   one selected, sine and cosine by polynomials; not bit-identical to the scalar code,
//!   which it matched to the rounding of grazing directions) took **13.8 ns per sample (5.3x)**,
//!   and the same copy run one lane at a time 56 ns (a microbenchmark, not kept). In the
//!   path loop, where a vertex's work is not independent of the last, neither piece of that
//!   copy paid: polynomial sine and cosine alone gave `cornell` +1 %, `tabletop` +1 %, `deep`
//!   −4 % samples per CPU-second, and with both lobes computed and one selected instead of a
//!   branch every scene lost 2–10 %. Nor did gathering an emissive triangle's vertices, unit
//!   normal, sidedness and (opaque, untextured) radiance once into the emitter table instead
//!   of at every vertex's light sample: the same bits, `cornell` −0.4 %, `deep` +0.5 %
//!   (three alternating pairs).
//!   What this says about the raw target (samples/s at least Mitsuba's): if shading cost
//!   nothing, samples/s would rise at most by 1 / (traversal share): 3.4x on `cornell`,
//!   2.1–2.3x elsewhere, which on stop 58's lowest rows (0.30x `cornell`, 0.22–0.28x the
//!   others) reaches about 1.0x on `cornell` and 0.5–0.6x on the other four. Lanes of SIMD
//!   across paths for the shading are necessary and not sufficient: the traversal must also
//!   become about twice as fast per ray (or a sample trace fewer rays: ours follow paths
//!   longer, [`ROULETTE_SCALE`], and trace one shadow ray per punctual light).
//! - How many rays a sample traces (stop 66, 2-core Zen 4, `cargo xtask bench render`: ours
//!   counted, [`crate::render::ViewOutput::rays`], at 128 px and 64 spp; Mitsuba's `path`
//!   integrator replayed on the same scenes, `tests/mitsuba/bench.py`'s `ray_counts`), closest
//!   hits + any-hit rays per camera sample, glTF BRDF:
//!
//!   | scene | ours | Mitsuba | ours / Mitsuba | samples/s ratio | per ray |
//!   |---|---|---|---|---|---|
//!   | `cornell` | 3.94 + 2.51 | 2.82 + 2.64 | 1.18x | 0.58x | 0.68x |
//!   | `deep` | 1.99 + 3.27 | 1.75 + 1.01 | 1.91x | 0.33x | 0.64x |
//!   | `materials` | 1.91 + 1.52 | 1.63 + 0.74 | 1.45x | 0.37x | 0.54x |
//!   | `tabletop` | 1.73 + 1.02 | 1.48 + 0.57 | 1.34x | 0.36x | 0.49x |
//!   | `thin` | 1.60 + 0.76 | 1.37 + 0.42 | 1.31x | 0.37x | 0.48x |
//!
//!   (samples/s against Mitsuba's `independent` sampler; per ray = that ratio times the
//!   ratio of rays per sample.) The extra rays are the estimator's: a shadow ray to every
//!   punctual light (`deep` has four), paths kept longer by [`ROULETTE_SCALE`], the
//!   emitter-edge pixels' camera rays and the caustic light tracer's paths, each kept
//!   because it lowered the error at equal time (above, and [`crate::caustics`],
//!   [`crate::render`]). So the raw samples/s ratio is the product of two factors: work per
//!   sample (0.52–0.85x, by design) and speed per ray (0.48–0.68x, what the code can still
//!   gain: on the same rays our traversal is 0.45–0.62x Embree's for closest hits and
//!   0.22–0.39x for any-hit rays, and the shading).
//! - Caustic paths (camera → 1 to 3 surfaces that are not sharp → a caster → a punctual
//!   light, see [`crate::caustics`]) are left to the light tracer when
//!   [`PathIntegrator::caustics`] is set (as [`crate::render::Renderer::render_view`] does
//!   when it traces them): at such a caster vertex the punctual lights' estimate is skipped,
//!   everything else is unchanged.
//! - `max_bounces` counts scattering events: 0 shows emitters and the environment only,
//!   1 is direct lighting, `n` adds paths with up to `n` surface reflections.
//! - Russian roulette from the third vertex on, with survival probability
//!   `min(1, ROULETTE_SCALE · max throughput component)` ([`ROULETTE_SCALE`]).
//! - Camera rays that miss return the environment radiance, or zero with `primary_hit =
//!   false` when the background is transparent (the environment still lights the scene).
//!   An environment map is sampled with its own density ([`Environment::sample`] /
//!   [`Environment::pdf`]) and MIS-combined like the emitters.
//! - Shading: BSDFs are evaluated in [`shading_frame`] around the interpolated normal,
//!   perturbed by the material's normal map ([`normal_mapped`], with the asset's TANGENT or a
//!   per-triangle tangent from the normal map's UV set, [`triangle_tangent`]) and bent
//!   towards the viewer when it faces away. The ground-truth normal ([`Interaction::n`])
//!   is the interpolated normal without the normal map.
//! - Alpha: `Mask` cuts where alpha < cutoff; `Blend` is stochastic coverage: a ray passes
//!   through a blended triangle when `hash(ray, triangle) ≥ alpha` ([`alpha_test`]), so the
//!   decision is deterministic per ray and coverage averages to alpha over rays. Light
//!   sampled on a blended emitter is weighted by its alpha (the expected coverage).
//!
//! Shadow and bounce rays start at [`offset_ray_origin`] so they neither re-hit their own
//! surface nor leak through it; shadow rays to a point stop `1e-4` (relative) short of it.

// Negated comparisons (`!(x > 0.0)`) are deliberate: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use crate::accel::{Accel, Hit, TraversalStack};
use crate::geometry::{Frame, Ray, hit_point_error, offset_ray_origin};
use crate::caustics::CausticPaths;
use crate::light::{EmissiveTriangles, Environment, punctual_incidence};
use crate::material::{BsdfAt, BsdfSample, SurfaceAttributes, evaluate_many, sample_many, SurfaceMaterial, base_color, emission, facing_normals, normal_mapped, resolve, shading_frame, triangle_tangent};
use crate::sampler::{Sampler, power_heuristic, splitmix64};
use crate::scene::{AlphaMode, Material, Scene};
use glam::{Vec2, Vec3, Vec4};

mod lanes;
pub use lanes::LaneMaterials;

/// Where each of a path vertex's numbers lies in its block of sampler dimensions: a spare
/// number for the emitter point (1, used only where the picked triangle's share of the
/// emitted power is too small to reuse the choice's number, see
/// [`EmissiveTriangles::sample`]), emitter choice and point (2), environment (2), BSDF (2),
/// Russian roulette (1).
const DIM_EMITTER_SPARE: u32 = 0;
const DIM_EMITTER_POINT: u32 = 1;
const DIM_ENVIRONMENT: u32 = 3;
const DIM_BSDF: u32 = 5;
const DIM_ROULETTE: u32 = 7;
/// Sampler dimensions every path vertex reserves (the block above).
const VERTEX_DIMENSIONS: u32 = DIM_ROULETTE + 1;

/// Fewest camera rays in a batch (a pixel's samples) traced as one packet
/// ([`PathIntegrator::intersect_many`]); smaller batches trace theirs one at a time (the same
/// bits). Samples per CPU-second, packets against one ray at a time (`cargo bench -p pathtracer
/// --bench render`, 128 px, two alternating pairs, stop 62): 16 spp `tabletop` +1 %, `thin`
/// and `deep` ±1 % (at the quick view's 64 px one ray at a time was 1–4 % faster); 32 spp
/// `tabletop` +3 %, `thin` +2–4 %, `deep` −1 to −2.5 %; 64 spp `tabletop` +4–5 %, `thin`
/// +3–5 %, `cornell` +1–2 %, `deep` +0.5–1 %, `materials` 0–0.7 %. With the packets on the wide
/// nodes (stop 63) 16 instead of 32, at 16 spp and 128 px (two pairs): `deep` −1.5 to +2.5 %,
/// `cornell` −0.2 to −1 %, `tabletop` −0.6 to −1.6 %, `thin` +1 to +8 %; not changed.
const PACKET_MIN_RAYS: usize = 32;

/// Russian roulette's survival probability over the path's largest throughput component
/// (capped at 1). pbrt and Mitsuba use 1; 2 keeps paths whose throughput is between ½ and 1
/// alive. Measured (128 px, 64 spp, 16 seeds; a render's variance times its time, 4 bounces):
/// 9 % better on `cornell`, 7.5 % on `deep`, 2.5–4.5 % on `materials`, `tabletop` and `thin`;
/// at 8 bounces 16 % on `cornell` and 8 % on `tabletop`. (1.5 and 3 were within 1 % of 2 on
/// `cornell`; no roulette at all, 6 %.) Mitsuba's rule instead, survival `min(0.95, max
/// throughput component)` (stop 59, `xtask bench render --scenes cornell,deep --runs 5`,
/// both rules in the same hour): samples/s +11 % on `cornell` and +2–4 % on `deep`, so
/// against Mitsuba's `llvm_ad_rgb` `independent` 0.35x instead of 0.31x (`cornell`, glTF)
/// and 0.22x as before (`deep`), but the MSE +19 % and +9 % (equal error against
/// `multijitter` on `cornell` 1.82x instead of 1.94x): the raw-speed gap is not in our
/// longer paths.
pub const ROULETTE_SCALE: f32 = 2.0;

/// Fraction of a shadow ray's length left unchecked at its far end (pbrt's ShadowEpsilon).
pub const SHADOW_EPSILON: f32 = 1e-4;

/// The integrator's settings.
#[derive(Clone, Debug, PartialEq)]
pub struct IntegratorSettings {
    /// Maximum number of scattering events along a path.
    pub max_bounces: u32,
    /// The environment (lights the scene; seen by camera misses unless transparent).
    pub environment: Environment,
    /// Camera rays that miss return zero radiance (alpha 0) instead of the environment.
    pub transparent_background: bool,
}

/// The radiance along one camera ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RadianceSample {
    /// Linear RGB radiance.
    pub radiance: Vec3,
    /// Whether the camera ray hit geometry.
    pub primary_hit: bool,
}

/// A surface point with everything shading needs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Interaction {
    /// Triangle index.
    pub prim: u32,
    /// Hit point (local frame) from the barycentrics.
    pub p: Vec3,
    /// Per-component absolute error bound of `p`.
    pub p_err: Vec3,
    /// Unit geometric normal, flipped to face the incoming ray.
    pub ng: Vec3,
    /// Unit geometric normal of the front face (counter-clockwise side).
    pub ng_front: Vec3,
    /// Unit interpolated normal on the side of the incoming ray (the ground-truth normal; the
    /// integrator's shading frame is built from it, or from the normal map, per vertex).
    pub n: Vec3,
    /// Unit interpolated normal on the front side (not flipped).
    pub ns_front: Vec3,
    /// Barycentrics of the hit.
    pub b: [f32; 3],
    /// Interpolated texture coordinates and vertex colour.
    pub attr: SurfaceAttributes,
    /// Material index.
    pub material: u32,
}

/// Interpolated texture coordinates and vertex colour of triangle `prim` at barycentrics `b`
/// (attributes missing from the mesh take glTF defaults: UV 0, colour white).
#[inline]
pub fn surface_attributes(scene: &Scene, prim: u32, b: [f32; 3]) -> SurfaceAttributes {
    let m = &scene.mesh;
    let idx = m.indices[prim as usize];
    // A missing attribute skips the lookups: UVs are then exactly 0 (the bits of
    // interpolating the default) and the colour exactly white (the value of interpolating
    // the default, without the rounding of `b₀ + b₁ + b₂`), so that an untextured material
    // is the same at every point ([`crate::material::uniform_surface`]).
    let lerp2 = |v: &Vec<Vec2>| {
        if v.is_empty() {
            return Vec2::ZERO;
        }
        (0..3).fold(Vec2::ZERO, |acc, k| acc + b[k] * v.get(idx[k] as usize).copied().unwrap_or(Vec2::ZERO))
    };
    let color = if m.colors.is_empty() {
        Vec4::ONE
    } else {
        (0..3).fold(Vec4::ZERO, |acc, k| acc + b[k] * m.colors.get(idx[k] as usize).copied().unwrap_or(Vec4::ONE))
    };
    SurfaceAttributes { uv: [lerp2(&m.uv0), lerp2(&m.uv1)], color }
}

/// A uniform number in `[0, 1)` that is a pure function of a ray and a triangle (SplitMix64
/// over the bits of origin, direction and triangle index): the coin of stochastic `Blend`
/// coverage.
pub fn blend_hash(ray: &Ray, prim: u32) -> f32 {
    let mut h = splitmix64(prim as u64);
    for x in [ray.origin.x, ray.origin.y, ray.origin.z, ray.direction.x, ray.direction.y, ray.direction.z] {
        h = splitmix64(h ^ x.to_bits() as u64);
    }
    (h >> 40) as f32 * (1.0 / 16_777_216.0)
}

/// Whether the triangle `prim` is present at barycentrics `b` for `ray`: `Mask`: base-colour
/// alpha (factor × texture × vertex colour) ≥ cutoff; `Blend`: `blend_hash(ray, prim) <
/// alpha` (present with probability alpha); `Opaque`: always.
#[inline]
pub fn alpha_test(scene: &Scene, ray: &Ray, prim: u32, b: [f32; 3]) -> bool {
    let Some(mat) = scene.mesh.material.get(prim as usize).and_then(|&m| scene.materials.get(m as usize)) else { return true };
    match mat.alpha_mode {
        AlphaMode::Mask { cutoff } => {
            let attr = surface_attributes(scene, prim, b);
            base_color(mat, &scene.textures, &attr).w >= cutoff
        }
        AlphaMode::Blend => {
            let attr = surface_attributes(scene, prim, b);
            blend_hash(ray, prim) < base_color(mat, &scene.textures, &attr).w
        }
        AlphaMode::Opaque => true,
    }
}

/// The tangent (xyz, handedness w) at a hit for normal mapping: the interpolated asset
/// TANGENT when all three vertices have one, else [`triangle_tangent`] from the UV set
/// `tex_coord`; zero when neither exists.
pub fn tangent_at(scene: &Scene, prim: u32, b: [f32; 3], tex_coord: u32, n: Vec3) -> Vec4 {
    let m = &scene.mesh;
    let idx = m.indices[prim as usize];
    let t = idx.map(|i| m.tangents.get(i as usize).copied().unwrap_or(Vec4::ZERO));
    if t.iter().all(|v| v.truncate().length_squared() > 0.0) {
        let xyz = (0..3).fold(Vec3::ZERO, |acc, k| acc + b[k] * t[k].truncate());
        return xyz.extend(if t[0].w < 0.0 { -1.0 } else { 1.0 });
    }
    let uvs = if tex_coord == 1 { &m.uv1 } else { &m.uv0 };
    let uv = idx.map(|i| uvs.get(i as usize).copied().unwrap_or(Vec2::ZERO));
    let p = idx.map(|i| m.positions[i as usize]);
    triangle_tangent(p, uv, n).unwrap_or(Vec4::ZERO)
}

/// Builds the [`Interaction`] for `hit` of `ray` (hit point from barycentrics, normals
/// facing the ray). (A table of every triangle's unit face normal, made at build, instead of
/// the cross product and normalisation here and in the emitter sample: the same bits,
/// samples per CPU-second at 128 px and 64 spp `cornell` +0.2–1.7 %, `deep` +2.5–4 %, `tabletop`
/// ±0.3 % (two alternating pairs, stop 63), for 12 more bytes per triangle; not kept.)
#[inline(always)]
pub fn interaction(scene: &Scene, ray: &Ray, hit: &Hit) -> Interaction {
    let m = &scene.mesh;
    let idx = m.indices[hit.prim as usize];
    let g = hit_geometry(idx.map(|i| m.positions[i as usize]), idx.map(|i| m.normals.get(i as usize).copied().unwrap_or(Vec3::ZERO)), hit.b, ray.direction);
    Interaction {
        prim: hit.prim,
        p: g.p,
        p_err: g.p_err,
        ng: g.ng,
        ng_front: g.ng_front,
        n: g.n,
        ns_front: g.ns_front,
        b: hit.b,
        attr: surface_attributes(scene, hit.prim, hit.b),
        material: m.material.get(hit.prim as usize).copied().unwrap_or(0),
    }
}

/// The geometric part of an [`Interaction`] (its fields of the same names).
#[derive(Clone, Copy, Debug)]
pub(crate) struct HitGeometry {
    pub(crate) p: Vec3,
    pub(crate) p_err: Vec3,
    pub(crate) ng: Vec3,
    pub(crate) ng_front: Vec3,
    pub(crate) n: Vec3,
    pub(crate) ns_front: Vec3,
}

/// The hit at barycentrics `b` of the triangle with vertices `p` and vertex normals `normals`
/// (zero where the mesh has none) by a ray along `dir`: the point and its error bound, and the
/// geometric and interpolated normals, facing the ray and of the front side. Shared by
/// [`interaction`] and the path loop in lanes (one lane each).
#[inline(always)]
pub(crate) fn hit_geometry(p: [Vec3; 3], normals: [Vec3; 3], b: [f32; 3], dir: Vec3) -> HitGeometry {
    let (point, p_err) = hit_point_error(p, b);
    let ng_front = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero();
    let ns = (0..3).fold(Vec3::ZERO, |acc, k| acc + b[k] * normals[k]);
    let ns = if ns.length_squared() > 1e-12 { ns } else { ng_front };
    let ns_front = ns.normalize_or_zero();
    let (ng, n) = facing_normals(ng_front, ns, dir);
    HitGeometry { p: point, p_err, ng, ng_front, n, ns_front }
}

/// The shading frame and the BSDF seen from `wo` (unit, world) at a path vertex: the
/// interpolated normal, normal-mapped when the material has a normal texture, flipped and
/// bent by [`shading_frame`]. Shared by the path tracer and the caustic light tracer so that
/// both evaluate a vertex alike.
#[inline(always)]
pub fn vertex_bsdf(scene: &Scene, si: &Interaction, mat: &Material, surf: &SurfaceMaterial, wo: Vec3) -> (Frame, BsdfAt) {
    let ns = match &mat.normal_texture {
        Some((r, _)) => {
            let tangent = tangent_at(scene, si.prim, si.b, r.tex_coord, si.ng_front);
            normal_mapped(mat, &scene.textures, &si.attr, si.ns_front, tangent)
        }
        None => si.ns_front,
    };
    let frame = shading_frame(ns, si.n.dot(si.ns_front) < 0.0, wo);
    let bsdf = surf.bsdf.at(frame.to_local(wo));
    (frame, bsdf)
}

/// A path of [`PathIntegrator::radiance_batch`] in flight: at the vertex `hit` of `ray`.
#[derive(Clone, Copy, Debug)]
struct PathState {
    /// Radiance gathered so far.
    l: Vec3,
    /// Throughput up to the vertex.
    beta: Vec3,
    ray: Ray,
    hit: Hit,
    /// The density of the BSDF sample that led here (for MIS at an emitter).
    prev_bsdf_pdf: f32,
    /// Scattering events before this vertex.
    depth: u32,
    /// Whether no vertex so far is sharp (see [`crate::caustics`]).
    all_rough: bool,
}

/// A shaded vertex of path `path` waiting for its BSDF sample.
#[derive(Clone, Copy, Debug)]
struct Pending {
    path: u32,
    /// The vertex's first sampler dimension.
    dim: u32,
    frame: Frame,
    bsdf: BsdfAt,
    /// Origin of every ray leaving the vertex.
    origin: Vec3,
    /// Geometric normal facing the incoming ray.
    ng: Vec3,
}

/// A light sample at a path vertex (a punctual light, a point on an emissive triangle, or a
/// direction of the environment map),
/// all but the BSDF's value there, which is computed for a whole bounce's samples at once
/// ([`evaluate_many`]).
#[derive(Clone, Copy, Debug)]
struct PendingLight {
    /// The vertex's index among the bounce's [`Pending`] vertices.
    vertex: u32,
    /// Direction to the light, in the shading frame.
    wi_l: Vec3,
    /// Punctual: the irradiance (normal to `wi`); emitter: the emitted radiance times alpha
    /// coverage; environment: its radiance.
    radiance: Vec3,
    /// Emitter or environment: the sample's solid-angle density (MIS with BSDF sampling);
    /// punctual: `None`.
    light_pdf: Option<f32>,
    /// The shadow ray and its `t_max`.
    shadow: Ray,
    t_max: f32,
    /// Which light: a punctual light's index in the scene, [`LIGHT_EMITTERS`] or
    /// [`LIGHT_ENVIRONMENT`] (the camera vertex's shadow rays are traced grouped by it).
    light: u32,
}

/// Buffers of [`PathIntegrator::occluded_by_light`].
#[derive(Default)]
struct ShadowScratch {
    /// Each group's first slot, and the next free one while filling.
    start: Vec<usize>,
    next: Vec<usize>,
    order: Vec<u32>,
    rays: Vec<Ray>,
    t_max: Vec<f32>,
    out: Vec<bool>,
    blocked: Vec<bool>,
}

/// Whether a light sample whose BSDF value is `f` has its shadow ray traced: where `f` is
/// not zero (nor NaN), the same rule for one ray at a time and for packets.
#[inline(always)]
fn traces_shadow_ray(f: Vec3) -> bool {
    !(f.max_element() <= 0.0)
}

/// [`PendingLight::light`] of an emissive-triangle sample.
const LIGHT_EMITTERS: u32 = u32::MAX - 1;
/// [`PendingLight::light`] of an environment-map sample.
const LIGHT_ENVIRONMENT: u32 = u32::MAX;

/// Rays traced, by query: closest hits (camera, bounce, ground-truth and light-tracer rays)
/// and any-hit (shadow) rays.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RayCounts {
    /// Closest-hit queries.
    pub closest: u64,
    /// Any-hit (shadow) queries.
    pub any_hit: u64,
}

impl std::ops::Add for RayCounts {
    type Output = RayCounts;
    fn add(self, o: RayCounts) -> RayCounts {
        RayCounts { closest: self.closest + o.closest, any_hit: self.any_hit + o.any_hit }
    }
}

thread_local! {
    /// The rays this thread has traced through any [`PathIntegrator`] (running totals, read
    /// before and after a task by [`PathIntegrator::tallied`]): a thread-local counter costs
    /// a ray an addition, where a shared atomic one would cost a locked instruction.
    static THREAD_RAYS: std::cell::Cell<RayCounts> = const { std::cell::Cell::new(RayCounts { closest: 0, any_hit: 0 }) };
}

/// Adds to this thread's ray counts.
#[inline(always)]
fn count_rays(closest: u64, any_hit: u64) {
    THREAD_RAYS.with(|c| {
        let v = c.get();
        c.set(RayCounts { closest: v.closest.wrapping_add(closest), any_hit: v.any_hit.wrapping_add(any_hit) });
    });
}

/// A [`PathIntegrator`]'s rays, added once per task ([`PathIntegrator::tallied`]).
#[derive(Debug, Default)]
struct RayTally {
    closest: std::sync::atomic::AtomicU64,
    any_hit: std::sync::atomic::AtomicU64,
}

/// A path tracer over one scene (see the module docs).
pub struct PathIntegrator<'a> {
    /// The scene.
    pub scene: &'a Scene,
    /// Its BVH.
    pub accel: &'a Accel,
    /// Its emissive triangles.
    pub emitters: &'a EmissiveTriangles,
    /// When set, the light tracer of [`crate::caustics`] estimates the caustic paths
    /// (camera → surfaces that are not sharp → caster → punctual light) and this integrator
    /// leaves them out; `None`: every path is estimated here.
    pub caustics: Option<&'a CausticPaths>,
    /// Per material, the material resolved once where it is the same at every point
    /// ([`crate::material::uniform_surface`]), else `None` (resolved per vertex). Empty: every
    /// material is resolved per vertex (the same bits, slower).
    pub uniform_surfaces: &'a [Option<SurfaceMaterial>],
    /// Where the scene's materials allow it ([`LaneMaterials::new`]), what the path loop in
    /// lanes reads (module `lanes`); `None`: every vertex is shaded one path at a time (the
    /// same bits, slower).
    pub lane_materials: Option<&'a LaneMaterials>,
    /// Settings.
    pub settings: IntegratorSettings,
    /// The rays of the tasks run through [`PathIntegrator::tallied`].
    tally: RayTally,
}

impl std::fmt::Debug for PathIntegrator<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PathIntegrator").field("settings", &self.settings).finish()
    }
}

impl<'a> PathIntegrator<'a> {
    /// The integrator over `scene` with its acceleration structure, emitters, resolved
    /// materials and settings; no caustic light tracing ([`PathIntegrator::caustics`]).
    pub fn new(
        scene: &'a Scene,
        accel: &'a Accel,
        emitters: &'a EmissiveTriangles,
        uniform_surfaces: &'a [Option<SurfaceMaterial>],
        lane_materials: Option<&'a LaneMaterials>,
        settings: IntegratorSettings,
    ) -> Self {
        PathIntegrator { scene, accel, emitters, caustics: None, uniform_surfaces, lane_materials, settings, tally: RayTally::default() }
    }

    /// Runs `f` (one sequential task, on this thread) and adds the rays it traced to
    /// [`PathIntegrator::rays_traced`]. The count is exact and the same for any thread count
    /// as long as `f` runs no parallel work of its own (a thread waiting on a parallel join
    /// may run other tasks, whose rays would then count here too).
    pub fn tallied<R>(&self, f: impl FnOnce() -> R) -> R {
        use std::sync::atomic::Ordering::Relaxed;
        let before = THREAD_RAYS.with(|c| c.get());
        let r = f();
        let after = THREAD_RAYS.with(|c| c.get());
        self.tally.closest.fetch_add(after.closest.wrapping_sub(before.closest), Relaxed);
        self.tally.any_hit.fetch_add(after.any_hit.wrapping_sub(before.any_hit), Relaxed);
        r
    }

    /// The rays traced so far by the tasks run through [`PathIntegrator::tallied`].
    pub fn rays_traced(&self) -> RayCounts {
        use std::sync::atomic::Ordering::Relaxed;
        RayCounts { closest: self.tally.closest.load(Relaxed), any_hit: self.tally.any_hit.load(Relaxed) }
    }
}

impl PathIntegrator<'_> {
    /// Closest hit honouring alpha masks and back-face culling.
    #[inline(always)]
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        count_rays(1, 0);
        self.accel.closest_hit(ray, f32::INFINITY, |prim, h| alpha_test(self.scene, ray, prim, h.b))
    }

    /// [`PathIntegrator::intersect`] for each of `rays`, into `out` (the same bits), by packets
    /// of rays ([`Accel::closest_hits`]).
    #[inline(always)]
    pub fn intersect_many(&self, rays: &[Ray], out: &mut [Option<Hit>]) {
        count_rays(rays.len() as u64, 0);
        self.accel.closest_hits(rays, f32::INFINITY, |r, prim, h| alpha_test(self.scene, &rays[r], prim, h.b), out)
    }

    /// [`PathIntegrator::intersect`] with the traversal stack `stack` ([`Accel::closest_hit_in`]).
    #[inline(always)]
    pub(crate) fn intersect_in(&self, stack: &mut TraversalStack, ray: &Ray) -> Option<Hit> {
        let hit = self.accel.closest_hit_in(stack, ray, f32::INFINITY, |prim, h| alpha_test(self.scene, ray, prim, h.b));
        count_rays(1, 0);
        hit
    }

    /// [`PathIntegrator::occluded`] with the traversal stack `stack` ([`Accel::occluded_in`]).
    #[inline(always)]
    fn occluded_in(&self, stack: &mut TraversalStack, ray: &Ray, t_max: f32) -> bool {
        let blocked = self.accel.occluded_in(stack, ray, t_max, |prim, h| alpha_test(self.scene, ray, prim, h.b));
        count_rays(0, 1);
        blocked
    }

    /// Whether anything blocks `ray` before `t_max`.
    #[inline(always)]
    pub fn occluded(&self, ray: &Ray, t_max: f32) -> bool {
        count_rays(0, 1);
        self.accel.occluded(ray, t_max, |prim, h| alpha_test(self.scene, ray, prim, h.b))
    }

    /// Whether each light sample's shadow ray is blocked (`scratch.blocked[e]` for
    /// `lights[e]`; false where its BSDF value `values[e]` is zero, whose ray is not traced):
    /// the rays grouped by light (a counting sort, each light's samples in vertex order) and
    /// traced as packets ([`Accel::occluded_many`]), the same answers as one
    /// [`PathIntegrator::occluded`] each. For the camera vertex's samples of a pixel, whose
    /// rays to one light nearly coincide.
    #[inline(always)]
    fn occluded_by_light(&self, lights: &[PendingLight], values: &[(Vec3, f32)], scratch: &mut ShadowScratch) {
        let ShadowScratch { start, next, order, rays, t_max, out, blocked } = scratch;
        let n = self.scene.lights.len();
        // Punctual light `i` is group `i`, the emitters `n`, the environment `n + 1`.
        let group = |e: &PendingLight| match e.light {
            LIGHT_EMITTERS => n,
            LIGHT_ENVIRONMENT => n + 1,
            i => i as usize,
        };
        start.clear();
        start.resize(n + 3, 0);
        for (e, v) in lights.iter().zip(values) {
            if traces_shadow_ray(v.0) {
                start[group(e) + 1] += 1;
            }
        }
        for g in 1..start.len() {
            start[g] += start[g - 1];
        }
        let traced = start[n + 2];
        order.clear();
        order.resize(traced, 0);
        rays.clear();
        rays.resize(traced, Ray::new(Vec3::ZERO, Vec3::Z));
        t_max.clear();
        t_max.resize(traced, 0.0);
        next.clear();
        next.extend_from_slice(start);
        for (i, (e, v)) in lights.iter().zip(values).enumerate() {
            if traces_shadow_ray(v.0) {
                let slot = &mut next[group(e)];
                (order[*slot], rays[*slot], t_max[*slot]) = (i as u32, e.shadow, e.t_max);
                *slot += 1;
            }
        }
        out.clear();
        out.resize(traced, false);
        for g in 0..n + 2 {
            let r = start[g]..start[g + 1];
            if !r.is_empty() {
                self.occluded_many(&rays[r.clone()], &t_max[r.clone()], &mut out[r]);
            }
        }
        blocked.clear();
        blocked.resize(lights.len(), false);
        for (&e, &o) in order.iter().zip(out.iter()) {
            blocked[e as usize] = o;
        }
    }

    /// [`PathIntegrator::occluded`] for each of `rays` (with limits `t_max`), into `out`, by
    /// packets ([`Accel::occluded_many`]).
    #[inline(always)]
    pub fn occluded_many(&self, rays: &[Ray], t_max: &[f32], out: &mut [bool]) {
        count_rays(0, rays.len() as u64);
        self.accel.occluded_many(rays, t_max, |r, prim, h| alpha_test(self.scene, &rays[r], prim, h.b), out)
    }

    /// Whether every vertex samples the environment (an environment map that is not black;
    /// a constant environment is left to BSDF sampling, see the module docs).
    #[inline(always)]
    fn samples_environment(&self) -> bool {
        let env = &self.settings.environment;
        !env.is_black() && env.map.is_some()
    }

    /// The material `mat` of `si` resolved at its point: from [`PathIntegrator::uniform_surfaces`]
    /// where it is the same everywhere, else by [`resolve`] (the same bits either way).
    #[inline(always)]
    pub fn surface(&self, mat: &Material, si: &Interaction) -> SurfaceMaterial {
        match self.uniform_surfaces.get(si.material as usize) {
            Some(Some(surf)) => *surf,
            _ => resolve(mat, &self.scene.textures, &si.attr),
        }
    }

    /// The radiance arriving at `ray.origin` from direction `−ray.direction` (unit).
    pub fn radiance(&self, ray: &Ray, sampler: &mut Sampler) -> RadianceSample {
        self.radiance_split(ray, sampler, true)
    }

    /// The emission of the surface a camera ray sees first (zero for a miss or a surface that
    /// does not emit): exactly the term [`PathIntegrator::radiance`] adds at the camera
    /// vertex, so that `radiance = primary_emission + radiance_split(…, false)` for every ray
    /// and sampler.
    pub fn primary_emission(&self, ray: &Ray) -> Vec3 {
        let scene = self.scene;
        let Some(hit) = self.intersect(ray) else { return Vec3::ZERO };
        let Some(mat) = scene.mesh.material.get(hit.prim as usize).and_then(|&m| scene.materials.get(m as usize)) else { return Vec3::ZERO };
        if !mat.is_emissive() {
            return Vec3::ZERO;
        }
        emission(mat, &scene.textures, &surface_attributes(scene, hit.prim, hit.b))
    }

    /// [`PathIntegrator::radiance`], with the emission of the surface the camera ray hits first
    /// left out when `primary_emission` is false (the caller then estimates that term
    /// separately, [`PathIntegrator::primary_emission`]); the random numbers drawn are the
    /// same either way.
    ///
    /// The path loop runs inside pulp's `vectorize` at the x86-64-v3 level (AVX2, FMA, VEX
    /// encoding) where the CPU has it ([`Accel::at_level`]), with the functions a vertex calls
    /// (`interaction`, `vertex_bsdf`, the BSDF's `sample` and `evaluate_pdf`, the emitter
    /// sample, the ray queries) inlined into it so that they are compiled at that level too;
    /// elsewhere it runs compiled for baseline x86-64. The bits are the same either way (no
    /// operation is contracted into an FMA); measured +6–14 % samples per CPU-second on the
    /// quick views (2-core Zen 5, stop 56: cornell +10 %, deep +14 %, materials +8 %,
    /// tabletop +7 %, thin +6 %). It is [`PathIntegrator::radiance_batch`] with a batch of one
    /// (whose vectorised BSDF sample, [`crate::material::sample_many`], then runs one lane).
    pub fn radiance_split(&self, ray: &Ray, sampler: &mut Sampler, primary_emission: bool) -> RadianceSample {
        // `inline(always)` on the closure: without it the closure, called from both of
        // `at_level`'s branches, stays out of line and compiled for the baseline (measured at
        // stop 56: the path loop then ran with SSE only, 4-7 % slower).
        self.accel.at_level(#[inline(always)] || self.radiance_split_impl(ray, sampler, primary_emission))
    }

    /// [`PathIntegrator::radiance_split`] for many camera rays at once (`rays[k]` with
    /// `samplers[k]`, into `out[k]`): the same bits as one call per ray. The paths advance
    /// together, a vertex at a time: every live path's vertex is shaded, then every BSDF
    /// sample is drawn, then every path is continued and its next ray traced.
    ///
    /// # Panics
    /// If the three slices differ in length.
    pub fn radiance_batch(&self, rays: &[Ray], samplers: &mut [Sampler], primary_emission: bool, out: &mut [RadianceSample]) {
        assert!(rays.len() == samplers.len() && rays.len() == out.len(), "radiance_batch: {} rays, {} samplers, {} results", rays.len(), samplers.len(), out.len());
        self.accel.at_level(#[inline(always)] || self.radiance_batch_impl(rays, samplers, primary_emission, out))
    }

    #[inline(always)]
    fn radiance_split_impl(&self, ray: &Ray, sampler: &mut Sampler, primary_emission: bool) -> RadianceSample {
        let mut out = [RadianceSample { radiance: Vec3::ZERO, primary_hit: false }];
        self.radiance_batch_impl(std::slice::from_ref(ray), std::slice::from_mut(sampler), primary_emission, &mut out);
        out[0]
    }

    #[inline(always)]
    fn radiance_batch_impl(&self, rays: &[Ray], samplers: &mut [Sampler], primary_emission: bool, out: &mut [RadianceSample]) {
        if let Some(mats) = self.lane_materials {
            return self.radiance_lanes(mats, rays, samplers, primary_emission, out);
        }
        let mut stack = TraversalStack::default();
        let (mut paths, mut active) = self.camera_vertices(&mut stack, rays, out);
        let mut pending: Vec<Pending> = Vec::with_capacity(active.len());
        let mut sampled: Vec<Option<BsdfSample>> = Vec::with_capacity(active.len());
        let mut numbers: Vec<Vec2> = Vec::with_capacity(active.len());
        let mut light_wi: Vec<Vec3> = Vec::with_capacity(active.len());
        let mut values: Vec<(Vec3, f32)> = Vec::with_capacity(active.len());
        let mut lights: Vec<PendingLight> = Vec::with_capacity(active.len());
        let mut shadow = ShadowScratch::default();
        let mut camera_vertex = true;
        while !active.is_empty() {
            pending.clear();
            lights.clear();
            for &k in &active {
                let k = k as usize;
                match self.shade_vertex(&mut paths[k], &mut samplers[k], primary_emission, pending.len() as u32, &mut lights) {
                    Some(v) => pending.push(Pending { path: k as u32, ..v }),
                    None => out[k].radiance = paths[k].l,
                }
            }
            // The light samples' BSDF values, then their shadow rays and estimates: a punctual
            // light's `f · E`, an emitter's or the environment's `f · Le · w_light / pdf_light`.
            if !lights.is_empty() {
                light_wi.clear();
                light_wi.extend(lights.iter().map(|e| e.wi_l));
                values.clear();
                values.resize(lights.len(), (Vec3::ZERO, 0.0));
                evaluate_many(|e| &pending[lights[e].vertex as usize].bsdf, &light_wi, &mut values);
                if camera_vertex && lights.len() >= PACKET_MIN_RAYS {
                    self.occluded_by_light(&lights, &values, &mut shadow);
                    for ((e, &value), &b) in lights.iter().zip(&values).zip(&shadow.blocked) {
                        Self::add_light_estimate_traced(&mut paths[pending[e.vertex as usize].path as usize], e, value, b);
                    }
                } else {
                    for (e, &value) in lights.iter().zip(&values) {
                        self.add_light_estimate(&mut stack, &mut paths[pending[e.vertex as usize].path as usize], e, value);
                    }
                }
            }
            camera_vertex = false;
            numbers.clear();
            numbers.extend(pending.iter().map(|v| samplers[v.path as usize].get_2d(v.dim + DIM_BSDF)));
            sampled.clear();
            sampled.resize(pending.len(), None);
            sample_many(|k| &pending[k].bsdf, &numbers, &mut sampled);
            active.clear();
            for (v, bs) in pending.iter().zip(&sampled) {
                let k = v.path as usize;
                if self.continue_path(&mut stack, &mut paths[k], &samplers[k], v, bs) {
                    active.push(k as u32);
                } else {
                    out[k].radiance = paths[k].l;
                }
            }
        }
    }

    /// The batch's camera rays traced (as packets where the batch is large enough): every
    /// path at its first vertex, the paths that hit something (their indices), and `out`
    /// set for every ray (the environment for a miss).
    #[inline(always)]
    fn camera_vertices(&self, stack: &mut TraversalStack, rays: &[Ray], out: &mut [RadianceSample]) -> (Vec<PathState>, Vec<u32>) {
        let env = &self.settings.environment;
        let mut paths: Vec<PathState> = Vec::with_capacity(rays.len());
        let mut active: Vec<u32> = Vec::with_capacity(rays.len());
        // The camera rays (a pixel's, close to each other) as packets where the batch is large
        // enough to pay, else one at a time (the same bits either way).
        let mut hits = vec![None; rays.len()];
        if rays.len() >= PACKET_MIN_RAYS {
            self.intersect_many(rays, &mut hits);
        } else {
            for (h, r) in hits.iter_mut().zip(rays) {
                *h = self.intersect_in(stack, r);
            }
        }
        for (k, (ray, &hit)) in rays.iter().zip(&hits).enumerate() {
            paths.push(PathState {
                l: Vec3::ZERO,
                beta: Vec3::ONE,
                ray: *ray,
                hit: hit.unwrap_or(Hit { prim: 0, t: 0.0, b: [0.0; 3], front: true }),
                prev_bsdf_pdf: 0.0,
                depth: 0,
                all_rough: true,
            });
            out[k] = match hit {
                Some(_) => {
                    active.push(k as u32);
                    RadianceSample { radiance: Vec3::ZERO, primary_hit: true }
                }
                None => {
                    let radiance = if self.settings.transparent_background { Vec3::ZERO } else { env.eval(ray.direction) };
                    RadianceSample { radiance, primary_hit: false }
                }
            };
        }
        (paths, active)
    }

    /// A path's vertex at `path.hit`: the emission it shows added to `path.l`, its
    /// punctual-light, emitter and environment samples pushed on `lights` (as the bounce's
    /// vertex `vertex`); `None` when the path ends here (having pushed nothing),
    /// else what its BSDF sample needs.
    #[inline(always)]
    fn shade_vertex(&self, path: &mut PathState, sampler: &mut Sampler, primary_emission: bool, vertex: u32, lights: &mut Vec<PendingLight>) -> Option<Pending> {
        let scene = self.scene;
        let (ray, hit, depth) = (path.ray, path.hit, path.depth);
        // Past the last scattering event only the emission this vertex shows counts: where
        // its material emits nothing, the interaction is not even built (the same bits).
        if depth >= self.settings.max_bounces {
            let material = scene.mesh.material.get(hit.prim as usize).copied().unwrap_or(0);
            if !scene.materials.get(material as usize).is_some_and(Material::is_emissive) {
                return None;
            }
        }
        let si = interaction(scene, &ray, &hit);
        let mat = scene.materials.get(si.material as usize)?;
        let surf = self.surface(mat, &si);
        self.add_emission_seen(path, surf.emission, si.ng_front, primary_emission);
        if depth >= self.settings.max_bounces {
            return None;
        }
        // The vertex's fixed block of dimensions (`DIM_*`), reserved at once; each number is
        // computed only where it is used (the same numbers as drawing all eight in order).
        let dim = sampler.skip(VERTEX_DIMENSIONS);

        let (frame, bsdf) = vertex_bsdf(scene, &si, mat, &surf, -ray.direction);
        // Every ray leaving this vertex is checked to leave on the `ng` side first, and
        // `offset_ray_origin` depends on the direction only through that side: one origin
        // serves them all (bit-identical to offsetting per ray).
        let origin = offset_ray_origin(si.p, si.p_err, si.ng, si.ng);

        // Punctual lights: deterministic, all of them, unless this is a caustic vertex
        // whose punctual light the light tracer estimates instead ([`crate::caustics`]).
        if !self.caustic_vertex(path, si.material) {
            self.punctual_samples(si.p, si.ng, origin, &frame, |e| lights.push(PendingLight { vertex, ..e }));
        }

        // Emissive triangles: one sample, MIS with BSDF sampling.
        if !self.emitters.is_empty()
            && let Some(es) = self.emitters.sample(sampler.get_2d(dim + DIM_EMITTER_POINT), || sampler.get_1d(dim + DIM_EMITTER_SPARE))
            && let Some(e) = self.emitter_pending(&si, &frame, origin, es)
        {
            lights.push(PendingLight { vertex, ..e });
        }

        // Environment map: one sample, MIS with BSDF sampling. A constant environment is
        // left to BSDF sampling alone (see the module docs).
        if self.samples_environment()
            && let Some(e) = self.environment_sample(sampler.get_2d(dim + DIM_ENVIRONMENT), si.ng, origin, &frame)
        {
            lights.push(PendingLight { vertex, ..e });
        }
        Some(Pending { path: 0, dim, frame, bsdf, origin, ng: si.ng })
    }

    /// Adds a light sample's estimate to `path` where its BSDF value `f` (with density
    /// `bsdf_pdf`) is not zero and its shadow ray is not blocked: a punctual light's `f · E`,
    /// an emitter's or the environment's `f · Le · w_light / pdf_light`.
    #[inline(always)]
    fn add_light_estimate(&self, stack: &mut TraversalStack, path: &mut PathState, e: &PendingLight, (f, bsdf_pdf): (Vec3, f32)) {
        if traces_shadow_ray(f) && !self.occluded_in(stack, &e.shadow, e.t_max) {
            Self::add_unblocked(path, e, f, bsdf_pdf);
        }
    }

    /// [`PathIntegrator::add_light_estimate`] with the shadow ray's answer known: `blocked`.
    #[inline(always)]
    fn add_light_estimate_traced(path: &mut PathState, e: &PendingLight, (f, bsdf_pdf): (Vec3, f32), blocked: bool) {
        if traces_shadow_ray(f) && !blocked {
            Self::add_unblocked(path, e, f, bsdf_pdf);
        }
    }

    /// The estimate of an unblocked light sample with BSDF value `f` (density `bsdf_pdf`).
    #[inline(always)]
    fn add_unblocked(path: &mut PathState, e: &PendingLight, f: Vec3, bsdf_pdf: f32) {
        path.l += match e.light_pdf {
            None => path.beta * f * e.radiance,
            Some(light_pdf) => path.beta * (f * e.radiance * (power_heuristic(light_pdf, bsdf_pdf) / light_pdf)),
        };
    }

    /// Adds the emission `emission` that a path's vertex shows (its surface's, geometric
    /// front normal `ng_front`) to `path.l`: whole at the camera vertex (when
    /// `primary_emission`), else MIS-weighted against the emitter sample that could have
    /// found it.
    #[inline(always)]
    fn add_emission_seen(&self, path: &mut PathState, emission: Vec3, ng_front: Vec3, primary_emission: bool) {
        if emission.max_element() > 0.0 {
            if path.depth == 0 {
                if primary_emission {
                    path.l += path.beta * emission;
                }
            } else {
                let cos_l = ng_front.dot(-path.ray.direction);
                let light_pdf = self.emitters.pdf_solid_angle(path.hit.prim, path.hit.t, cos_l);
                path.l += path.beta * emission * power_heuristic(path.prev_bsdf_pdf, light_pdf);
            }
        }
    }

    /// Whether a path's vertex on `material` is a caustic vertex whose punctual lights the
    /// light tracer estimates ([`crate::caustics`]); updates the path's `all_rough`.
    #[inline(always)]
    fn caustic_vertex(&self, path: &mut PathState, material: u32) -> bool {
        let caustic = path.all_rough && self.caustics.is_some_and(|c| c.is_caustic_vertex(path.depth + 1, material));
        path.all_rough &= self.caustics.is_some_and(|c| !c.is_sharp(material));
        caustic
    }

    /// Every punctual light's sample at the point `p` (geometric normal `ng` facing the
    /// incoming ray, rays leaving from `origin`, shading frame `frame`) that lights its side,
    /// up to the BSDF's value, passed to `push` in the scene's order (its `vertex` is the
    /// caller's to set).
    #[inline(always)]
    fn punctual_samples(&self, p: Vec3, ng: Vec3, origin: Vec3, frame: &Frame, mut push: impl FnMut(PendingLight)) {
        for (index, light) in self.scene.lights.iter().enumerate() {
            let Some(inc) = punctual_incidence(light, p) else { continue };
            if inc.wi.dot(ng) <= 0.0 {
                continue;
            }
            let t_max = if inc.distance.is_finite() {
                match *light {
                    crate::scene::Light::Point { position, .. } | crate::scene::Light::Spot { position, .. } => (position - origin).length() * (1.0 - SHADOW_EPSILON),
                    crate::scene::Light::Directional { .. } => f32::INFINITY,
                }
            } else {
                f32::INFINITY
            };
            push(PendingLight { vertex: 0, wi_l: frame.to_local(inc.wi), radiance: inc.irradiance, light_pdf: None, shadow: Ray::new(origin, inc.wi), t_max, light: index as u32 });
        }
    }

    /// The environment map's sample with the numbers `u` at a point (geometric normal `ng`
    /// facing the incoming ray, rays leaving from `origin`, shading frame `frame`), up to the
    /// BSDF's value; `None` where it lies below the surface or has no radiance (its `vertex`
    /// is the caller's to set).
    #[inline(always)]
    fn environment_sample(&self, u: Vec2, ng: Vec3, origin: Vec3, frame: &Frame) -> Option<PendingLight> {
        let env = &self.settings.environment;
        let (wi, pdf) = env.sample(u)?;
        if !(wi.dot(ng) > 0.0) {
            return None;
        }
        let le = env.eval(wi);
        (le.max_element() > 0.0).then(|| PendingLight { vertex: 0, wi_l: frame.to_local(wi), radiance: le, light_pdf: Some(pdf), shadow: Ray::new(origin, wi), t_max: f32::INFINITY, light: LIGHT_ENVIRONMENT })
    }

    /// Continues a path from its vertex `v` along the BSDF sample `bs` (Russian roulette, the
    /// next ray traced); false when the path ends (its escape to the environment added).
    #[inline(always)]
    fn continue_path(&self, stack: &mut TraversalStack, path: &mut PathState, sampler: &Sampler, v: &Pending, bs: &Option<BsdfSample>) -> bool {
        let Some(bs) = bs else { return false };
        let wi = v.frame.to_world(bs.wi).normalize();
        self.continue_along(stack, path, v.origin, v.ng, wi, bs.weight, bs.pdf, || sampler.get_1d(v.dim + DIM_ROULETTE))
    }

    /// Continues a path from its vertex (rays leave from `origin`, geometric normal `ng`
    /// facing the incoming ray) along the BSDF sample's world direction `wi`, with its weight
    /// and density: Russian roulette (with the number `roulette()`), the next ray traced;
    /// false when the path ends (its escape to the environment added).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn continue_along(&self, stack: &mut TraversalStack, path: &mut PathState, origin: Vec3, ng: Vec3, wi: Vec3, weight: Vec3, pdf: f32, roulette: impl FnOnce() -> f32) -> bool {
        let env = &self.settings.environment;
        if wi.dot(ng) <= 0.0 {
            return false;
        }
        path.beta *= weight;
        path.prev_bsdf_pdf = pdf;
        if path.depth >= 2 {
            let survive = (ROULETTE_SCALE * path.beta.max_element()).min(1.0);
            if !(survive > 0.0) || roulette() >= survive {
                return false;
            }
            path.beta /= survive;
        }
        path.ray = Ray::new(origin, wi);
        match self.intersect_in(stack, &path.ray) {
            Some(h) => {
                path.hit = h;
                path.depth += 1;
                true
            }
            None => {
                if self.samples_environment() {
                    path.l += path.beta * env.eval(wi) * power_heuristic(path.prev_bsdf_pdf, env.pdf(wi));
                } else if !env.is_black() {
                    path.l += path.beta * env.eval(wi);
                }
                false
            }
        }
    }

    /// One light-sampling sample of the emissive triangles at `si`, up to the BSDF's value
    /// ([`PendingLight`]; the bounce's values are computed together, in lanes, and the
    /// estimate is `f · Le · w_light / pdf_light`); `None` where the estimate is zero whatever
    /// that value (its `vertex` is the caller's to set). `origin` is the shadow ray's start, `offset_ray_origin(si.p, si.p_err, si.ng, si.ng)`.
    #[inline(always)]
    fn emitter_pending(&self, si: &Interaction, frame: &Frame, origin: Vec3, es: crate::light::EmitterSample) -> Option<PendingLight> {
        let scene = self.scene;
        let m = &scene.mesh;
        let idx = m.indices[es.prim as usize];
        let p = idx.map(|i| m.positions[i as usize]);
        let (q, q_err) = hit_point_error(p, es.b);
        let n_l = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero();
        let d = q - si.p;
        let dist = d.length();
        if !(dist > 0.0) {
            return None;
        }
        let wi = d / dist;
        if wi.dot(si.ng) <= 0.0 {
            return None;
        }
        let lmat = m.material.get(es.prim as usize).and_then(|&k| scene.materials.get(k as usize))?;
        let cos_l = n_l.dot(-wi);
        if !lmat.double_sided && cos_l <= 0.0 {
            return None;
        }
        // The light's attributes matter only to its textures and alpha; an opaque, untextured
        // emitter (the common case) skips interpolating them.
        let lattr = if lmat.emissive_texture.is_some() || !matches!(lmat.alpha_mode, AlphaMode::Opaque) {
            surface_attributes(scene, es.prim, es.b)
        } else {
            SurfaceAttributes { uv: [Vec2::ZERO; 2], color: Vec4::ONE }
        };
        let coverage = match lmat.alpha_mode {
            AlphaMode::Opaque => 1.0,
            AlphaMode::Mask { cutoff } => {
                if base_color(lmat, &scene.textures, &lattr).w >= cutoff { 1.0 } else { 0.0 }
            }
            AlphaMode::Blend => base_color(lmat, &scene.textures, &lattr).w.clamp(0.0, 1.0),
        };
        let le = emission(lmat, &scene.textures, &lattr) * coverage;
        if le.max_element() <= 0.0 {
            return None;
        }
        let light_pdf = self.emitters.pdf_solid_angle(es.prim, dist, cos_l);
        if !(light_pdf > 0.0) || !light_pdf.is_finite() {
            return None;
        }
        let target = offset_ray_origin(q, q_err, n_l, -wi);
        let seg = target - origin;
        let len = seg.length();
        if !(len > 0.0) {
            return None;
        }
        Some(PendingLight { vertex: 0, wi_l: frame.to_local(wi), radiance: le, light_pdf: Some(light_pdf), shadow: Ray::new(origin, seg / len), t_max: len * (1.0 - SHADOW_EPSILON), light: LIGHT_EMITTERS })
    }
}
