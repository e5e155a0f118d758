//! The queries against brute force (every triangle tested), at any scale, through spilled
//! stacks, nested queries and packets.

use super::*;
use crate::sampler::{Sampler, sample_uniform_sphere};
use crate::scene::{Aabb, AlphaMode, Material, Mesh, Scene};
use glam::DVec3;

/// A soup of `n` random triangles in the unit cube (half single-sided, half
/// double-sided), plus a grid of quads sharing edges and vertices (watertightness).
fn soup(n: usize) -> Scene {
    let mut rng = Sampler::new(3, 0, 0, 0);
    let mut positions = Vec::new();
    let mut indices = Vec::new();
    let mut material = Vec::new();
    for k in 0..n {
        let c = Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 2.0 - 1.0;
        let size = 0.05 + 0.3 * rng.next_1d();
        let base = positions.len() as u32;
        for _ in 0..3 {
            positions.push(c + size * sample_uniform_sphere(rng.next_2d()));
        }
        indices.push([base, base + 1, base + 2]);
        material.push((k % 2) as u32);
    }
    let g = 6u32;
    let base = positions.len() as u32;
    for j in 0..=g {
        for i in 0..=g {
            positions.push(Vec3::new(i as f32 / g as f32 * 2.0 - 1.0, -0.9, j as f32 / g as f32 * 2.0 - 1.0));
        }
    }
    for j in 0..g {
        for i in 0..g {
            let v = base + j * (g + 1) + i;
            indices.push([v, v + g + 1, v + 1]);
            indices.push([v + 1, v + g + 1, v + g + 2]);
            material.extend([1, 1]);
        }
    }
    let bounds = positions.iter().fold(Aabb::EMPTY, |a, p| a.union_point(*p));
    let single = Material::gltf_default();
    let double = Material { double_sided: true, ..Material::gltf_default() };
    Scene {
        name: "soup".into(),
        origin: DVec3::ZERO,
        mesh: Mesh { positions, indices, material, ..Default::default() },
        materials: vec![single, double],
        textures: vec![],
        lights: vec![],
        cameras: vec![],
        bounds,
        warnings: vec![],
        objects: vec![],
    }
}

/// The closest hit and the any-hit answer by testing every triangle, with the same rules
/// (culling, ties to the lowest index).
fn brute_force(scene: &Scene, ray: &Ray, t_max: f32) -> (Option<(u32, f32)>, bool) {
    let wr = WatertightRay::new(ray).unwrap();
    let mut best: Option<(u32, f32)> = None;
    let mut any = false;
    for (k, idx) in scene.mesh.indices.iter().enumerate() {
        let p = idx.map(|i| scene.mesh.positions[i as usize]);
        let front = (p[1] - p[0]).cross(p[2] - p[0]).dot(ray.direction) < 0.0;
        if !scene.materials[scene.mesh.material[k] as usize].double_sided && !front {
            continue;
        }
        let Some(h) = intersect_triangle(&wr, p, t_max) else { continue };
        any = true;
        if best.is_none_or(|(bk, bt)| h.t < bt || (h.t == bt && (k as u32) < bk)) {
            best = Some((k as u32, h.t));
        }
    }
    (best, any)
}

/// The traversal with one stack entry (every further pending child spilled to the heap)
/// answers exactly as with the full stack, and as the brute force, in trees from a few
/// to thousands of triangles; so do the queries with a caller's stack, reused by every
/// query of both kinds without being cleared.
#[test]
fn a_traversal_that_spills_its_stack_answers_the_same() {
    for (n, params) in [(40, AccelParams::medium_build()), (3000, AccelParams::fastest_build()), (3000, AccelParams::slow_build())] {
        let scene = soup(n);
        let accel = Accel::build(&scene, &params).unwrap();
        let mut rng = Sampler::new(17, 0, 3, 0);
        let mut stack = TraversalStack::default();
        let mut hits = 0;
        for k in 0..1500 {
            let o = Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 3.0 - 1.5;
            let ray = Ray::new(o, sample_uniform_sphere(rng.next_2d()));
            let t_max = if k % 4 == 0 { 0.3 + rng.next_1d() } else { f32::INFINITY };
            let key = |h: Option<Hit>| h.map(|h| (h.prim, h.t.to_bits(), h.b.map(f32::to_bits), h.front));
            let full = key(accel.closest_hit(&ray, t_max, |_, _| true));
            let spilled = key(accel.closest_hit_with(FourWide, &ray, t_max, |_, _| true, &mut [0; 1]));
            assert_eq!(spilled, full, "{n} triangles, ray {k}");
            assert_eq!(key(accel.closest_hit_in(&mut stack, &ray, t_max, |_, _| true)), full, "{n} triangles, ray {k}");
            let occluded = accel.occluded(&ray, t_max, |_, _| true);
            assert_eq!(accel.occluded_with(FourWide, &ray, t_max, |_, _| true, &mut [0; 1]), occluded, "{n} triangles, ray {k}");
            assert_eq!(accel.occluded_in(&mut stack, &ray, t_max, |_, _| true), occluded, "{n} triangles, ray {k}");
            let (want, any) = brute_force(&scene, &ray, t_max);
            assert_eq!(full.map(|f| (f.0, f32::from_bits(f.1))), want, "{n} triangles, ray {k}");
            assert_eq!(occluded, any);
            hits += want.is_some() as u32;
        }
        assert!(hits > 100, "{n} triangles: too few hits ({hits})");
    }
}

#[test]
fn a_query_made_inside_another_answers_as_alone() {
    // The one-ray queries share their thread's traversal stack; an alpha test that makes
    // a query of its own (while the outer query's stack is in use) gets a fresh one, and
    // both answer as when made alone. Every triangle alpha-masked, so that the alpha test
    // runs (it keeps every surface).
    let mut scene = soup(500);
    for m in &mut scene.materials {
        m.alpha_mode = crate::scene::AlphaMode::Mask { cutoff: 0.5 };
    }
    let accel = Accel::build(&scene, &AccelParams::medium_build()).unwrap();
    let mut rng = Sampler::new(29, 0, 7, 0);
    let mut inner_queries = 0;
    for k in 0..2000 {
        let o = Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 3.0 - 1.5;
        let ray = Ray::new(o, sample_uniform_sphere(rng.next_2d()));
        let other = Ray::new(-o, sample_uniform_sphere(rng.next_2d()));
        let key = |h: Option<Hit>| h.map(|h| (h.prim, h.t.to_bits()));
        let (alone, other_alone) = (key(accel.closest_hit(&ray, f32::INFINITY, |_, _| true)), key(accel.closest_hit(&other, f32::INFINITY, |_, _| true)));
        let other_blocked = accel.occluded(&other, f32::INFINITY, |_, _| true);
        let nested = std::cell::Cell::new(0);
        let got = key(accel.closest_hit(&ray, f32::INFINITY, |_, _| {
            assert_eq!(key(accel.closest_hit(&other, f32::INFINITY, |_, _| true)), other_alone, "ray {k}");
            assert_eq!(accel.occluded(&other, f32::INFINITY, |_, _| true), other_blocked, "ray {k}");
            nested.set(nested.get() + 1);
            true
        }));
        let blocked = accel.occluded(&ray, f32::INFINITY, |_, _| {
            assert_eq!(key(accel.closest_hit(&other, f32::INFINITY, |_, _| true)), other_alone, "ray {k}");
            true
        });
        assert_eq!(got, alone, "ray {k}");
        assert_eq!(blocked, alone.is_some(), "ray {k}");
        inner_queries += nested.get();
    }
    assert!(inner_queries > 100, "{inner_queries} nested queries");
}

#[test]
fn traversal_finds_exactly_what_testing_every_triangle_finds() {
    let scene = soup(300);
    for params in [AccelParams::fastest_build(), AccelParams::medium_build()] {
        let accel = Accel::build(&scene, &params).unwrap();
        let mut rng = Sampler::new(11, 0, 1, 0);
        let mut hits = 0;
        for k in 0..4000 {
            let o = Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 3.0 - 1.5;
            // Some axis-aligned directions (zero components) as well as general ones.
            let d = if k % 10 == 0 { [Vec3::X, -Vec3::Y, Vec3::Z, -Vec3::X][k / 10 % 4] } else { sample_uniform_sphere(rng.next_2d()) };
            let ray = Ray::new(o, d);
            let t_max = if k % 3 == 0 { 0.5 + rng.next_1d() } else { f32::INFINITY };
            let (want, any) = brute_force(&scene, &ray, t_max);
            let got = accel.closest_hit(&ray, t_max, |_, _| true).map(|h| (h.prim, h.t));
            assert_eq!(got, want, "ray {k}: {ray:?} t_max {t_max}");
            assert_eq!(accel.occluded(&ray, t_max, |_, _| true), any, "ray {k}: {ray:?} t_max {t_max}");
            hits += want.is_some() as u32;
        }
        assert!(hits > 500, "too few hits ({hits}) to mean anything");
    }
}

/// The eight-wide (AVX2, where the CPU has it) and the four-wide child-box tests give the
/// same hits bit for bit, and exactly the watertight test's on every triangle (the brute
/// force), hits near the ray's origin included: rays aimed at
/// the shared vertices and edges of the quad grid and at random points, in scenes scaled
/// from 1e-4 to 1e5.
#[test]
fn eight_and_four_wide_box_tests_answer_as_the_brute_force_at_any_scale() {
    for scale in [1e-4f32, 1.0, 1e5] {
        let mut scene = soup(200);
        for p in &mut scene.mesh.positions {
            *p *= scale;
        }
        let accel = Accel::build(&scene, &AccelParams::medium_build()).unwrap();
        let mut four = Accel::build(&scene, &AccelParams::medium_build()).unwrap();
        four.set_avx2(false);
        assert_eq!(four.simd_level(), "4-wide");
        let mut rng = Sampler::new(5, 0, 2, 0);
        let mut hits = 0;
        for k in 0..3000 {
            let o = (Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 3.0 - 1.5) * scale;
            let g = 6.0;
            let (i, j) = ((rng.next_1d() * 7.0).floor(), (rng.next_1d() * 7.0).floor());
            let vertex = |i: f32, j: f32| Vec3::new(i / g * 2.0 - 1.0, -0.9, j / g * 2.0 - 1.0) * scale;
            let target = match k % 3 {
                0 => vertex(i, j),
                1 => vertex(i, j).lerp(vertex(i + 1.0, j + 1.0), 0.5),
                _ => (Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 2.0 - 1.0) * scale,
            };
            let ray = Ray::new(o, (target - o).normalize());
            if !ray.direction.is_finite() {
                continue;
            }
            let full = |a: &Accel| a.closest_hit(&ray, f32::INFINITY, |_, _| true).map(|h| (h.prim, h.t.to_bits(), h.b.map(f32::to_bits), h.front));
            assert_eq!(full(&accel), full(&four), "scale {scale} ray {k}: 8-wide and 4-wide differ");
            let occluded = accel.occluded(&ray, f32::INFINITY, |_, _| true);
            assert_eq!(four.occluded(&ray, f32::INFINITY, |_, _| true), occluded, "scale {scale} ray {k}");
            hits += full(&accel).is_some() as u32;
            {
                let (want, any) = brute_force(&scene, &ray, f32::INFINITY);
                let got = accel.closest_hit(&ray, f32::INFINITY, |_, _| true).map(|h| (h.prim, h.t));
                assert_eq!(got, want, "scale {scale} ray {k}: {ray:?}");
                assert_eq!(occluded, any, "scale {scale} ray {k}");
            }
        }
        assert!(hits > 1000, "scale {scale}: too few hits ({hits})");
    }
}

/// The packet queries answer every ray exactly as the one-ray queries do (triangle, `t`,
/// barycentrics and face, bit for bit; the any-hit answer): coherent bundles (one origin,
/// a narrow cone, as a pixel's camera rays), incoherent rays, rays that cannot hit
/// (non-finite, zero direction, `t_max ≤ 0`), finite limits, alpha-tested triangles with
/// an answer that depends on the ray, batches across packet boundaries, in a shallow and
/// a deep tree, with both child-box tests.
#[test]
fn packet_queries_answer_each_ray_as_the_one_ray_queries() {
    for (n, params) in [(300, AccelParams::medium_build()), (5000, AccelParams::fastest_build())] {
        let mut scene = soup(n);
        // Material 1 (double-sided, and the grid) alpha-tested.
        scene.materials[1].alpha_mode = AlphaMode::Mask { cutoff: 0.5 };
        for avx2 in [true, false] {
            let mut accel = Accel::build(&scene, &params).unwrap();
            accel.set_avx2(avx2);
            let mut rng = Sampler::new(17, 0, n as u64, avx2 as u32);
            for (batch, len) in [0usize, 1, 7, 64, 65, 200].into_iter().enumerate() {
                let coherent = batch % 2 == 0;
                let o0 = Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 3.0 - 1.5;
                // Aimed into the soup, so that a bundle hits as well as misses.
                let d0 = ((Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) - 0.5) - o0).normalize();
                let mut rays = Vec::new();
                let mut limits = Vec::new();
                for k in 0..len {
                    let ray = match k % 23 {
                        5 => Ray::new(Vec3::new(f32::NAN, 0.0, 0.0), Vec3::X),
                        11 => Ray::new(o0, Vec3::ZERO),
                        17 => Ray::new(o0, Vec3::new(0.0, f32::INFINITY, 0.0)),
                        // At the grid's shared vertices and edges (zero edge functions).
                        19 | 20 => {
                            let (i, j) = ((rng.next_1d() * 7.0).floor(), (rng.next_1d() * 7.0).floor());
                            let vertex = |i: f32, j: f32| Vec3::new(i / 6.0 * 2.0 - 1.0, -0.9, j / 6.0 * 2.0 - 1.0);
                            let target = if k % 23 == 19 { vertex(i, j) } else { vertex(i, j).lerp(vertex(i + 1.0, j), 0.5) };
                            // Straight down onto it (the edge functions exactly zero), or from the bundle's origin.
                            if k % 2 == 0 { Ray::new(target + 1.9 * Vec3::Y, -Vec3::Y) } else { Ray::new(o0, (target - o0).normalize()) }
                        }
                        _ if coherent => Ray::new(o0 + 1e-3 * Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()), (d0 + 0.05 * sample_uniform_sphere(rng.next_2d())).normalize()),
                        _ => Ray::new(Vec3::new(rng.next_1d(), rng.next_1d(), rng.next_1d()) * 3.0 - 1.5, sample_uniform_sphere(rng.next_2d())),
                    };
                    rays.push(ray);
                    limits.push(match k % 5 {
                        0 => 0.5 + rng.next_1d(),
                        1 if k % 7 == 0 => 0.0,
                        _ => f32::INFINITY,
                    });
                }
                // The alpha test depends on the ray and the hit.
                let alpha = |r: usize, prim: u32, h: &TriangleHit| !(r as u32 * 7 + prim * 13 + (h.b[0] * 8.0) as u32).is_multiple_of(3);
                let key = |h: Option<Hit>| h.map(|h| (h.prim, h.t.to_bits(), h.b.map(f32::to_bits), h.front));
                for t_max in [f32::INFINITY, 1.0] {
                    let mut got = vec![None; len];
                    accel.closest_hits(&rays, t_max, alpha, &mut got);
                    for (r, ray) in rays.iter().enumerate() {
                        let want = accel.closest_hit(ray, t_max, |prim, h| alpha(r, prim, h));
                        assert_eq!(key(got[r]), key(want), "n {n} avx2 {avx2} batch {batch} ray {r}: {ray:?} t_max {t_max}");
                    }
                }
                let mut blocked = vec![false; len];
                accel.occluded_many(&rays, &limits, alpha, &mut blocked);
                for (r, ray) in rays.iter().enumerate() {
                    let want = accel.occluded(ray, limits[r], |prim, h| alpha(r, prim, h));
                    assert_eq!(blocked[r], want, "n {n} avx2 {avx2} batch {batch} ray {r}: {ray:?} t_max {}", limits[r]);
                }
                if len >= 64 {
                    let hits = rays.iter().filter(|r| accel.closest_hit(r, f32::INFINITY, |_, _| true).is_some()).count();
                    assert!(hits > len / 10 && hits < len, "n {n} batch {batch}: {hits} of {len} rays hit; the test needs hits and misses");
                }
            }
        }
    }
}
