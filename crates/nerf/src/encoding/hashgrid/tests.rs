use super::*;

fn cfg(levels: usize, f: usize, log2_t: u32, nmin: u32, nmax: u32) -> HashGridConfig {
    HashGridConfig { levels, features_per_level: f, log2_table_size: log2_t, base_resolution: nmin, finest_resolution: nmax }
}

fn rnd(i: u64) -> f32 {
    rng::uniform_f32(rng::key(&[4242, i]))
}

fn random_points(n: usize, seed: u64) -> Vec<[f32; 3]> {
    (0..n as u64).map(|i| [0, 1, 2].map(|a| rnd(seed * 1_000_003 + 3 * i + a))).collect()
}

/// Naive f64 reference: per point, per level, independent of the fast path's code.
fn reference(c: &HashGridConfig, params: &[f64], p: [f32; 3]) -> Vec<f64> {
    let (t, f) = (c.table_size(), c.features_per_level);
    let b = if c.levels > 1 { (c.finest_resolution as f64 / c.base_resolution as f64).powf(1.0 / (c.levels - 1) as f64) } else { 1.0 };
    let mut out = vec![0.0; c.output_dim()];
    for l in 0..c.levels {
        let n = (c.base_resolution as f64 * b.powi(l as i32) + 1e-6).floor() as u64;
        let dense = (n + 1).pow(3) <= t as u64;
        let x: Vec<f64> = p.iter().map(|&v| (v as f64).clamp(0.0, 1.0) * n as f64).collect();
        let cell: Vec<u64> = x.iter().map(|&v| (v.floor() as u64).min(n - 1)).collect();
        for dz in 0..2u64 {
            for dy in 0..2u64 {
                for dx in 0..2u64 {
                    let v = [cell[0] + dx, cell[1] + dy, cell[2] + dz];
                    let mut w = 1.0;
                    for a in 0..3 {
                        let fr = x[a] - cell[a] as f64;
                        w *= if [dx, dy, dz][a] == 1 { fr } else { 1.0 - fr };
                    }
                    let i = if dense {
                        (v[0] + v[1] * (n + 1) + v[2] * (n + 1) * (n + 1)) as usize
                    } else {
                        let h = v[0] ^ ((v[1] * 2_654_435_761) & 0xFFFF_FFFF) ^ ((v[2] * 805_459_861) & 0xFFFF_FFFF);
                        (h as usize) % t
                    };
                    for j in 0..f {
                        out[l * f + j] += w * params[(l * t + i) * f + j];
                    }
                }
            }
        }
    }
    out
}

/// Random points in the cube plus combinations of special coordinates (±0, the cube's
/// faces, outside it, NaN, ±inf, denormal-small, just below 1).
fn points_with_specials() -> Vec<[f32; 3]> {
    let mut pts = random_points(1000, 9);
    let special = [0.0, -0.0, 1.0, 0.5, 0.25, 1.0 / 3.0, -0.25, 1.5, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1e-30, 1.0 - 1e-7];
    for (i, &a) in special.iter().enumerate() {
        for &b in &special {
            pts.push([a, b, special[(i * 7 + 3) % special.len()]]);
        }
    }
    pts
}

fn grid(c: HashGridConfig, seed: u64, scale: f32) -> HashGrid {
    let mut g = HashGrid::new(c, seed).unwrap();
    // larger params than the ±1e-4 init so that differences are visible
    for (i, p) in g.params.iter_mut().enumerate() {
        *p = (rnd(1_000_000_007 + i as u64) - 0.5) * scale;
    }
    g
}

#[test]
fn resolutions_follow_the_paper() {
    let c = cfg(16, 2, 19, 16, 2048);
    assert_eq!(c.resolution(0), 16);
    assert_eq!(c.resolution(15), 2048);
    assert!((c.growth_factor() - 1.3819).abs() < 1e-4);
    assert_eq!(c.resolution(1), 22); // floor(16 · 1.3819)
    assert_eq!((0..16).map(|l| c.resolution(l)).collect::<Vec<_>>(), [16, 22, 30, 42, 58, 80, 111, 153, 212, 294, 406, 561, 776, 1072, 1482, 2048]);
    assert!(c.is_dense(4) && !c.is_dense(5)); // 59³ ≤ 2^19 < 81³
    assert_eq!(cfg(1, 2, 19, 16, 16).resolution(0), 16);
    assert!(cfg(1, 3, 19, 16, 16).validate().is_err());
    assert!(cfg(2, 2, 19, 32, 16).validate().is_err());
    assert!(HashGrid::new(cfg(0, 2, 19, 16, 16), 0).is_err());
}

#[test]
fn init_is_small_and_seeded() {
    let g = HashGrid::new(cfg(2, 2, 10, 4, 64), 7).unwrap();
    assert!(g.params.iter().all(|v| v.abs() <= 1e-4));
    assert!(g.params.iter().any(|v| v.abs() > 5e-5));
    assert_eq!(g, HashGrid::new(cfg(2, 2, 10, 4, 64), 7).unwrap());
    assert_ne!(g, HashGrid::new(cfg(2, 2, 10, 4, 64), 8).unwrap());
}

#[test]
fn worked_example() {
    let mut g = HashGrid::new(cfg(1, 1, 10, 2, 2), 0).unwrap();
    g.params[0] = 1.0;
    g.params[1] = 3.0;
    let mut out = [0.0];
    g.encode(&[[0.25, 0.0, 0.0]], &mut out);
    assert_eq!(out[0], 2.0);
}

#[test]
fn forward_matches_f64_reference() {
    // dense and hashed levels, collisions (tiny tables), every feature count
    for (c, n) in [
        (cfg(8, 2, 12, 4, 300), 3000),
        (cfg(3, 1, 4, 8, 64), 500), // T = 16: heavy collisions
        (cfg(4, 4, 9, 2, 40), 500),
        (cfg(2, 8, 14, 16, 512), 500),
        (cfg(1, 2, 19, 16, 16), 100),
    ] {
        let g = grid(c.clone(), 1, 2.0);
        let p64: Vec<f64> = g.params.iter().map(|&v| v as f64).collect();
        let mut pts = random_points(n, 2);
        // edges, corners, vertices, outside and NaN
        pts.extend([[0.0; 3], [1.0; 3], [0.0, 1.0, 0.5], [0.5, 0.25, 0.125], [-0.5, 1.5, 0.3], [f32::NAN, 0.2, f32::INFINITY]]);
        let mut out = vec![0.0; pts.len() * c.output_dim()];
        g.encode(&pts, &mut out);
        for (k, &p) in pts.iter().enumerate() {
            let p_clean = p.map(|v| if v.is_nan() { 0.0 } else { v });
            let r = reference(&c, &p64, p_clean);
            for (j, &rv) in r.iter().enumerate() {
                let v = out[k * c.output_dim() + j] as f64;
                assert!((v - rv).abs() < 2e-6, "config {c:?} point {p:?} feature {j}: {v} vs {rv}");
            }
        }
    }
}

/// The AVX2 kernel gives the scalar path's bits (two features, dense and hashed levels,
/// a table of 2^19 entries and a tiny one with collisions), including points on vertices,
/// on the box's faces, outside it, NaN, infinite and -0.0, at every offset of the 8-point
/// blocks (so lane position cannot matter).
#[test]
fn simd_forward_is_bit_identical_to_scalar() {
    for c in [cfg(16, 2, 19, 16, 2048), cfg(6, 2, 4, 2, 300), cfg(4, 2, 14, 3, 17)] {
        let g = grid(c.clone(), 4, 1.0);
        let pts = points_with_specials();
        let lvs = levels(&c);
        let tf = c.table_size() * 2;
        for skip in 0..8 {
            let p = &pts[skip..];
            for (l, lv) in lvs.iter().enumerate() {
                let table = &g.params[l * tf..(l + 1) * tf];
                let (mut fast, mut slow) = (vec![0.0f32; p.len() * 3], vec![0.0f32; p.len() * 3]);
                if lv.dense {
                    encode_level::<2, true>(p, lv, table, &mut fast, 3);
                    encode_level_scalar::<2, true>(p, lv, table, &mut slow, 3);
                } else {
                    encode_level::<2, false>(p, lv, table, &mut fast, 3);
                    encode_level_scalar::<2, false>(p, lv, table, &mut slow, 3);
                }
                for (k, (a, b)) in fast.iter().zip(&slow).enumerate() {
                    assert_eq!(a.to_bits(), b.to_bits(), "config {c:?} level {l} point {:?} value {k}: {a} vs {b}", p[k / 3]);
                }
            }
        }
    }
}

#[test]
fn simd_backward_is_bit_identical_to_scalar() {
    fn run<const F: usize>(c: &HashGridConfig, pts: &[[f32; 3]]) {
        let lvs = levels(c);
        let t = c.table_size();
        let d: Vec<f32> = (0..pts.len() * F).map(|i| rnd(7000 + i as u64) - 0.5).collect();
        for skip in 0..8 {
            let (p, d) = (&pts[skip..], &d[skip * F..]);
            for (l, lv) in lvs.iter().enumerate() {
                let (mut fast, mut slow) = (vec![0.0f32; t * F], vec![0.0f32; t * F]);
                let (mut tf, mut ts) = (vec![false; t], vec![false; t]);
                if lv.dense {
                    backward_level::<F, true, true>(p, lv, d, &mut fast, &mut tf);
                    backward_level_scalar::<F, true, true>(p, lv, d, &mut slow, &mut ts);
                } else {
                    backward_level::<F, false, true>(p, lv, d, &mut fast, &mut tf);
                    backward_level_scalar::<F, false, true>(p, lv, d, &mut slow, &mut ts);
                }
                assert_eq!(tf, ts, "config {c:?} level {l}: touched entries");
                assert!(ts.iter().any(|x| *x));
                // Without the touched flags, the same gradient.
                let mut unmarked = vec![0.0f32; t * F];
                if lv.dense {
                    backward_level::<F, true, false>(p, lv, d, &mut unmarked, &mut []);
                } else {
                    backward_level::<F, false, false>(p, lv, d, &mut unmarked, &mut []);
                }
                for (k, ((a, b), u)) in fast.iter().zip(&slow).zip(&unmarked).enumerate() {
                    assert_eq!(a.to_bits(), b.to_bits(), "config {c:?} F {F} level {l} gradient {k}: {a} vs {b}");
                    assert_eq!(u.to_bits(), b.to_bits(), "config {c:?} F {F} level {l} gradient {k} (no flags): {u} vs {b}");
                }
            }
        }
    }
    let pts = points_with_specials();
    for (levels, log2_t, nmin, nmax) in [(16usize, 14u32, 16u32, 2048u32), (6, 4, 2, 300), (4, 14, 3, 17)] {
        run::<1>(&cfg(levels, 1, log2_t, nmin, nmax), &pts);
        run::<2>(&cfg(levels, 2, log2_t, nmin, nmax), &pts);
        run::<4>(&cfg(levels, 4, log2_t, nmin, nmax), &pts);
    }
}

/// Prefetching is skipped exactly on the levels whose used entries fit in
/// [`PREFETCH_MIN_BYTES`]: instant-ngp's grid (16 levels, `T = 2^19`, `F = 2`, 16 to 2048)
/// has three dense levels that small (17³, 23³ and 31³ entries of 8 bytes), then a dense
/// level of 43³ entries (632 KiB) and hashed ones of 4 MiB.
#[test]
fn prefetching_is_skipped_on_levels_that_stay_in_cache() {
    let c = cfg(16, 2, 19, 16, 2048);
    let lvs = levels(&c);
    let on: Vec<bool> = lvs.iter().map(|lv| worth_prefetching(lv, 2)).collect();
    assert_eq!(&on[..4], &[false, false, false, true], "resolutions {:?}", lvs.iter().map(|l| l.res).collect::<Vec<_>>());
    assert!(on[4..].iter().all(|x| *x));
    // One feature per entry halves the bytes: 43³ · 4 B = 318 KiB still over, 31³ · 4 B under.
    assert_eq!(lvs.iter().map(|lv| worth_prefetching(lv, 1)).take(4).collect::<Vec<_>>(), [false, false, false, true]);
    // A tiny table is never worth it, however fine the level.
    let small = cfg(4, 2, 10, 16, 2048);
    assert!(levels(&small).iter().all(|lv| !worth_prefetching(lv, 2)));
}

#[test]
fn vertices_are_exact() {
    // a dense level (N = 4) and a hashed one (N = 64, T = 2^10): at a vertex the encoding
    // is that vertex's entry exactly, including p = 0 and p = 1
    let c = cfg(2, 2, 10, 4, 64);
    let g = grid(c.clone(), 4, 1.0);
    let t = c.table_size();
    let entry = |l: usize, v: [u32; 3]| -> [f32; 2] {
        let n = c.resolution(l);
        let i = if c.is_dense(l) {
            (v[0] + v[1] * (n + 1) + v[2] * (n + 1) * (n + 1)) as usize
        } else {
            ((v[0] ^ v[1].wrapping_mul(PRIMES[1]) ^ v[2].wrapping_mul(PRIMES[2])) as usize) % t
        };
        [g.params[(l * t + i) * 2], g.params[(l * t + i) * 2 + 1]]
    };
    for (p, v4, v64) in [
        ([0.0, 0.0, 0.0], [0, 0, 0], [0, 0, 0]),
        ([1.0, 1.0, 1.0], [4, 4, 4], [64, 64, 64]),
        ([0.25, 0.5, 1.0], [1, 2, 4], [16, 32, 64]),
    ] {
        let mut out = [0.0; 4];
        g.encode(&[p], &mut out);
        assert_eq!(out[..2], entry(0, v4));
        assert_eq!(out[2..], entry(1, v64));
    }
}

#[test]
fn continuous_across_cell_boundaries() {
    let c = cfg(4, 2, 12, 4, 32);
    let g = grid(c.clone(), 3, 1.0);
    // p = 0.25 is a vertex on every level (N = 4, 8, 16, 32)
    let pts = [[0.25, 0.5, 0.75], [0.25 - 1e-6, 0.5, 0.75], [0.25 + 1e-6, 0.5, 0.75]];
    let mut out = vec![0.0; 3 * c.output_dim()];
    g.encode(&pts, &mut out);
    let d = c.output_dim();
    for j in 0..d {
        assert!((out[j] - out[d + j]).abs() < 1e-4 && (out[j] - out[2 * d + j]).abs() < 1e-4);
    }
    // no points: nothing written, nothing accumulated
    let mut grad = vec![0.0; c.n_params()];
    g.encode(&[], &mut []);
    g.backward(&[], &[], &mut grad);
    assert!(grad.iter().all(|v| *v == 0.0));
    // clamping: outside equals the clamped point exactly
    let mut o2 = vec![0.0; 2 * d];
    g.encode(&[[-3.0, 2.0, 0.5], [0.0, 1.0, 0.5]], &mut o2);
    assert_eq!(o2[..d], o2[d..]);
}

#[test]
fn backward_is_the_exact_adjoint_and_matches_finite_differences() {
    for c in [cfg(6, 2, 10, 4, 200), cfg(3, 1, 4, 8, 64), cfg(2, 4, 8, 2, 30)] {
        let g = grid(c.clone(), 5, 1.0);
        let pts = random_points(400, 6);
        let d = c.output_dim();
        let d_out: Vec<f32> = (0..pts.len() * d).map(|i| rnd(77_000_000 + i as u64) - 0.5).collect();
        let mut grad = vec![0.0; c.n_params()];
        g.backward(&pts, &d_out, &mut grad);
        // finite differences of L(θ) = Σ d_out · enc(θ) with the f64 reference
        let p64: Vec<f64> = g.params.iter().map(|&v| v as f64).collect();
        let loss = |params: &[f64]| -> f64 {
            pts.iter().enumerate().map(|(k, &p)| reference(&c, params, p).iter().enumerate().map(|(j, v)| v * d_out[k * d + j] as f64).sum::<f64>()).sum()
        };
        let touched: Vec<usize> = (0..grad.len()).filter(|&i| grad[i] != 0.0).collect();
        assert!(touched.len() > 10);
        let h = 1e-3;
        for &i in touched.iter().step_by(touched.len() / 12 + 1).chain([0usize, grad.len() - 1].iter()) {
            let (mut a, mut b) = (p64.clone(), p64.clone());
            a[i] += h;
            b[i] -= h;
            let fd = (loss(&a) - loss(&b)) / (2.0 * h);
            assert!((grad[i] as f64 - fd).abs() < 1e-4 * (1.0 + fd.abs()), "param {i}: {} vs {fd}", grad[i]);
        }
        // adjoint identity over all params: <d_out, enc(θ)> = <grad, θ>
        let mut out = vec![0.0; pts.len() * d];
        g.encode(&pts, &mut out);
        let lhs: f64 = out.iter().zip(&d_out).map(|(a, b)| *a as f64 * *b as f64).sum();
        let rhs: f64 = grad.iter().zip(&g.params).map(|(a, b)| *a as f64 * *b as f64).sum();
        assert!((lhs - rhs).abs() < 1e-4 * (1.0 + lhs.abs()), "{lhs} vs {rhs}");
        // accumulation: a second call doubles
        let mut grad2 = grad.clone();
        g.backward(&pts, &d_out, &mut grad2);
        assert!(grad2.iter().zip(&grad).all(|(a, b)| (*a - 2.0 * *b).abs() <= 1e-5 * (1.0 + b.abs())));
    }
}

#[test]
fn point_gradient_matches_finite_differences_of_the_f64_reference() {
    for c in [cfg(6, 2, 10, 4, 200), cfg(3, 1, 4, 8, 64), cfg(2, 4, 8, 2, 30), cfg(2, 8, 12, 3, 9)] {
        let g = grid(c.clone(), 11, 1.0);
        let mut pts = random_points(300, 12);
        // Clamped axes have derivative 0.
        pts.extend([[-0.2, 0.3, 0.4], [0.3, 1.7, 0.6], [0.5, 0.5, f32::NAN]]);
        let (n, d) = (pts.len(), c.output_dim());
        let d_out: Vec<f32> = (0..n * d).map(|i| rnd(91_000_000 + i as u64) - 0.5).collect();
        let grad = g.point_gradient(&pts, &g.level_major(&d_out));
        let p64: Vec<f64> = g.params.iter().map(|&v| v as f64).collect();
        let loss = |k: usize, p: [f64; 3]| -> f64 { reference(&c, &p64, p.map(|v| v as f32)).iter().enumerate().map(|(j, v)| v * d_out[k * d + j] as f64).sum() };
        let finest = c.finest_resolution as f64;
        let mut checked = 0;
        for (k, p) in pts.iter().enumerate() {
            for a in 0..3 {
                if !p[a].is_finite() || !(0.0..=1.0).contains(&p[a]) {
                    assert_eq!(grad[k][a], 0.0, "point {k} axis {a} is clamped");
                    continue;
                }
                let (mut lo, mut hi) = (p.map(|v| v as f64), p.map(|v| v as f64));
                let h = 1e-2 / finest;
                lo[a] -= h;
                hi[a] += h;
                // Within one cell of every level the encoding is linear along an axis, so the
                // central difference is exact: skip points within h of a face of any level
                // (and points with a NaN, which the reference does not treat as 0).
                let crosses = (0..c.levels).any(|l| {
                    let r = c.resolution(l) as f64;
                    (lo[a] * r).floor() != (hi[a] * r).floor()
                });
                if crosses || lo[a] < 0.0 || hi[a] > 1.0 || p.iter().any(|v| !v.is_finite()) {
                    continue;
                }
                // The step the f32 points really take.
                let (lo32, hi32) = (lo.map(|v| v as f32 as f64), hi.map(|v| v as f32 as f64));
                let fd = (loss(k, hi32) - loss(k, lo32)) / (hi32[a] - lo32[a]);
                assert!((grad[k][a] as f64 - fd).abs() < 1e-3 * (1.0 + fd.abs()), "{c:?} point {k} axis {a}: {} vs {fd}", grad[k][a]);
                checked += 1;
            }
        }
        assert!(checked > 600, "{checked} derivatives checked");
    }
}

#[test]
fn point_gradient_is_deterministic_across_thread_counts() {
    let c = cfg(5, 2, 12, 4, 128);
    let g = grid(c.clone(), 8, 1.0);
    let pts = random_points(9000, 3);
    let d_lvl: Vec<f32> = (0..pts.len() * c.output_dim()).map(|i| rnd(7 + i as u64) - 0.5).collect();
    let run = |threads: usize| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| g.point_gradient(&pts, &d_lvl));
    assert_eq!(run(1), run(3));
}

#[test]
fn deterministic_across_thread_counts() {
    let c = cfg(5, 2, 12, 4, 128);
    let g = grid(c.clone(), 8, 1.0);
    let pts = random_points(5000, 9);
    let d_out: Vec<f32> = (0..pts.len() * c.output_dim()).map(|i| rnd(i as u64) - 0.5).collect();
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| {
            let mut out = vec![0.0; pts.len() * c.output_dim()];
            g.encode(&pts, &mut out);
            let mut grad = vec![0.0; c.n_params()];
            g.backward(&pts, &d_out, &mut grad);
            (out, grad)
        })
    };
    assert_eq!(run(1), run(4));
}

#[test]
fn adam_first_step_and_finite() {
    let mut adam = Adam::new(AdamConfig::instant_ngp(0.1), 4);
    let mut p = vec![1.0, 1.0, 1.0, 1.0];
    adam.step(&mut p, &[0.5, -2.0, 0.0, f32::NAN]);
    assert!((p[0] - 0.9).abs() < 1e-6 && (p[1] - 1.1).abs() < 1e-6);
    assert_eq!(&p[2..], &[1.0, 1.0]);
    // converges on a quadratic
    let mut adam = Adam::new(AdamConfig { lr: 0.05, beta1: 0.9, beta2: 0.999, eps: 1e-8 }, 1);
    let mut x = vec![3.0f32];
    for _ in 0..500 {
        let g = [2.0 * (x[0] - 1.0)];
        adam.step(&mut x, &g);
    }
    assert!((x[0] - 1.0).abs() < 1e-2, "{}", x[0]);
}

#[test]
fn sparse_adam_updates_only_touched_entries_and_clears() {
    let c = cfg(3, 2, 8, 2, 40);
    let g = grid(c.clone(), 2, 1.0);
    let pts = random_points(50, 3);
    let d_out: Vec<f32> = (0..pts.len() * c.output_dim()).map(|i| rnd(5_000 + i as u64) - 0.5).collect();
    let mut grad = vec![0.0; c.n_params()];
    let mut touched = vec![false; c.levels * c.table_size()];
    g.backward_touched(&pts, &d_out, &mut grad, &mut touched);
    let mut plain = vec![0.0; c.n_params()];
    g.backward(&pts, &d_out, &mut plain);
    assert_eq!(grad, plain);
    // every entry with a nonzero gradient is flagged
    assert!(grad.chunks(2).zip(&touched).all(|(gr, t)| *t || gr.iter().all(|v| *v == 0.0)));
    let n_touched = touched.iter().filter(|t| **t).count();
    assert!(n_touched > 10 && n_touched < touched.len());
    // sparse on the touched entries = dense on them; untouched entries unchanged
    let (mut dense, mut sparse) = (Adam::new(AdamConfig::instant_ngp(0.01), c.n_params()), Adam::new(AdamConfig::instant_ngp(0.01), c.n_params()));
    let (mut pd, mut ps) = (g.params.clone(), g.params.clone());
    dense.step(&mut pd, &grad);
    let flags = touched.clone();
    assert_eq!(sparse.step_sparse(&mut ps, &mut grad, &mut touched, 2, 0.01), n_touched, "updated entries");
    for (e, hit) in flags.iter().enumerate() {
        for i in 2 * e..2 * e + 2 {
            assert_eq!(ps[i], if *hit { pd[i] } else { g.params[i] }, "entry {e}");
        }
    }
    assert!(grad.iter().all(|v| *v == 0.0) && touched.iter().all(|t| !*t));
}

/// The fused backward and sparse Adam give exactly the parameters and moments of
/// `backward_touched` then `step_sparse`, step after step, for every feature count, with
/// dense and hashed levels, whatever the pool (including a scratch made in a smaller pool,
/// which grows to the larger one's threads), and an empty batch still counts as a step.
#[test]
fn fused_backward_and_adam_equal_the_two_calls_bit_for_bit() {
    fn run<const F: usize>() {
        let c = cfg(4, F, 9, 3, 60); // levels 0–1 dense, 2–3 hashed
        assert!(c.is_dense(0) && !c.is_dense(3));
        let mut a = grid(c.clone(), 11, 1.0);
        let mut b = a.clone();
        let (mut adam_a, mut adam_b) = (Adam::new(AdamConfig::instant_ngp(0.01), c.n_params()), Adam::new(AdamConfig::instant_ngp(0.01), c.n_params()));
        let mut grad = vec![0.0; c.n_params()];
        let mut touched = vec![false; c.levels * c.table_size()];
        let small = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let mut scratch = small.install(BackwardScratch::new);
        assert_eq!(scratch.slots.len(), 1);
        let pools = [1, 3].map(|t| rayon::ThreadPoolBuilder::new().num_threads(t).build().unwrap());
        for step in 0..6u64 {
            let n = if step == 2 { 0 } else { 40 + 17 * step as usize };
            let pts = random_points(n, 100 + step);
            let d_out: Vec<f32> = (0..n * c.output_dim()).map(|i| rnd(9_000 * step + i as u64) - 0.5).collect();
            a.backward_touched(&pts, &d_out, &mut grad, &mut touched);
            let want = adam_a.step_sparse(&mut a.params, &mut grad, &mut touched, F, 0.01 / (1 + step) as f32);
            let d_lvl = b.level_major(&d_out);
            let got = pools[step as usize % 2].install(|| b.backward_adam(&pts, &d_lvl, &mut adam_b, 0.01 / (1 + step) as f32, &mut scratch));
            assert_eq!(got.updated, want, "F = {F}, step {step}: entries updated");
            assert!(got.backward_seconds >= 0.0 && got.adam_seconds >= 0.0);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&a.params), bits(&b.params), "F = {F}, step {step}: params");
            assert_eq!((bits(&adam_a.m), bits(&adam_a.v)), (bits(&adam_b.m), bits(&adam_b.v)), "F = {F}, step {step}: moments");
            assert_eq!(adam_a.step, adam_b.step);
        }
        // the scratch grew to the 3-thread pool and is left cleared: every slot all zero
        // and unflagged
        assert_eq!(scratch.slots.len(), 3);
        for slot in &scratch.slots {
            let buf = slot.lock().unwrap();
            assert!(buf.grad.iter().all(|v| *v == 0.0) && buf.touched.iter().all(|t| !*t));
        }
    }
    run::<1>();
    run::<2>();
    run::<4>();
    run::<8>();
}

/// On-CPU time of the calling thread in seconds (Linux `schedstat`), insensitive to other
/// processes competing for the cores; `None` elsewhere.
pub(crate) fn thread_cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    Some(s.split_whitespace().next()?.parse::<f64>().ok()? * 1e-9)
}

/// `cargo test -p nerf hashgrid_timing -- --ignored --nocapture`
///
/// Prints wall time on the default pool and on-CPU time on one thread (the machine is
/// shared, so wall times vary with load; CPU time much less, but the kernel updates it at
/// scheduler ticks, so values below ~10 ms are coarse).
#[test]
#[ignore]
fn hashgrid_timing() {
    let n = 262_144;
    let random = random_points(n, 10);
    // training-like: 1024 random chords of the cube, 256 consecutive samples each
    let ends = random_points(2048, 11);
    let rays: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            let (a, b, t) = (ends[2 * (i / 256)], ends[2 * (i / 256) + 1], (i % 256) as f32 / 255.0);
            [0, 1, 2].map(|k| a[k] + t * (b[k] - a[k]))
        })
        .collect();
    for (levels, nmin, pts, kind) in [
        (1usize, 16u32, &random, "random"),
        (1, 2048, &random, "random"),
        (16, 16, &random, "random"),
        (1, 2048, &rays, "along rays"),
        (16, 16, &rays, "along rays"),
    ] {
        let c = cfg(levels, 2, 19, nmin, 2048);
        let g = HashGrid::new(c.clone(), 0).unwrap();
        let mut out = vec![0.0; n * c.output_dim()];
        let d_out = vec![1e-3f32; n * c.output_dim()];
        let mut grad = vec![0.0; c.n_params()];
        let mut wall = (f64::MAX, f64::MAX);
        for _ in 0..5 {
            let t0 = std::time::Instant::now();
            g.encode(pts, &mut out);
            let t1 = std::time::Instant::now();
            g.backward(pts, &d_out, &mut grad);
            let t2 = std::time::Instant::now();
            wall.0 = wall.0.min((t1 - t0).as_secs_f64());
            wall.1 = wall.1.min((t2 - t1).as_secs_f64());
        }
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let cpu = pool.install(|| {
            let mut cpu = (f64::MAX, f64::MAX);
            for _ in 0..5 {
                let t0 = thread_cpu_seconds().unwrap_or(0.0);
                g.encode(pts, &mut out);
                let t1 = thread_cpu_seconds().unwrap_or(0.0);
                g.backward(pts, &d_out, &mut grad);
                let t2 = thread_cpu_seconds().unwrap_or(0.0);
                cpu.0 = cpu.0.min(t1 - t0);
                cpu.1 = cpu.1.min(t2 - t1);
            }
            cpu
        });
        println!(
            "hashgrid L={levels} N_min={nmin} F=2 T=2^19, {n} points {kind}: wall ({} threads) fwd {:.1} ms + bwd {:.1} ms; 1-thread CPU fwd {:.1} ms + bwd {:.1} ms",
            rayon::current_num_threads(),
            wall.0 * 1e3,
            wall.1 * 1e3,
            cpu.0 * 1e3,
            cpu.1 * 1e3
        );
    }
}

#[allow(clippy::needless_range_loop)]
mod sparse_adam_list {
    use super::*;

    /// The listed sparse Adam equals a plain per-flag loop bit for bit over several steps, on a
    /// table of several chunks plus a partial one, with flags scattered at random (including
    /// each chunk's first and last entry, and some non-finite gradients), for 1, 2 and 3
    /// parameters per flag (2 runs the AVX2 kernel where the CPU has AVX2).
    #[test]
    fn sparse_adam_equals_a_per_flag_loop() {
        for group in [1usize, 2, 3] {
            let entries = (1usize << 14) * 3 + 77;
            let n = entries * group;
            let cfg = AdamConfig::instant_ngp(0.01);
            let mut adam = Adam::new(cfg.clone(), n);
            let (mut p, mut rp) = (vec![0.1f32; n], vec![0.1f32; n]);
            let (mut rm, mut rv) = (vec![0.0f32; n], vec![0.0f32; n]);
            for step in 1..=4u64 {
                let mut g = vec![0.0f32; n];
                let mut touched = vec![false; entries];
                for e in 0..entries {
                    let hit = e % (1 << 14) == 0 || e % (1 << 14) == (1 << 14) - 1 || rng::uniform_f32(rng::key(&[step, e as u64])) < 0.35;
                    if hit {
                        touched[e] = true;
                        for i in e * group..(e + 1) * group {
                            g[i] = rng::uniform_f32(rng::key(&[step, i as u64, 1])) - 0.5;
                        }
                        // Now and then a non-finite gradient (treated as 0).
                        if e % 997 == 5 {
                            g[e * group] = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY][e % 3];
                        }
                    }
                }
                let (reference_g, flags) = (g.clone(), touched.clone());
                let want = touched.iter().filter(|t| **t).count();
                assert_eq!(adam.step_sparse(&mut p, &mut g, &mut touched, group, 0.01), want);
                let t = step as i32;
                let c1 = (1.0 - (cfg.beta1 as f64).powi(t)) as f32;
                let c2 = (1.0 - (cfg.beta2 as f64).powi(t)) as f32;
                for e in (0..entries).filter(|&e| flags[e]) {
                    for i in e * group..(e + 1) * group {
                        let gi = if reference_g[i].is_finite() { reference_g[i] } else { 0.0 };
                        rm[i] = cfg.beta1 * rm[i] + (1.0 - cfg.beta1) * gi;
                        rv[i] = cfg.beta2 * rv[i] + (1.0 - cfg.beta2) * gi * gi;
                        rp[i] -= 0.01 * (rm[i] / c1) / ((rv[i] / c2).sqrt() + cfg.eps);
                    }
                }
                assert!(p.iter().zip(&rp).all(|(a, b)| a.to_bits() == b.to_bits()), "group {group} step {step}: parameters differ");
                assert!(adam.m.iter().zip(&rm).all(|(a, b)| a.to_bits() == b.to_bits()), "group {group} step {step}: first moments differ");
                assert!(adam.v.iter().zip(&rv).all(|(a, b)| a.to_bits() == b.to_bits()), "group {group} step {step}: second moments differ");
                assert!(g.iter().all(|v| *v == 0.0) && touched.iter().all(|t| !*t), "group {group} step {step}: buffers not cleared");
            }
        }
    }
}
