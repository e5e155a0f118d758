//! The roofline of a `fast` training step (`cargo xtask bench nerf`): the work each phase does
//! (floating-point operations for the networks, bytes for the hash tables, the optimisers and
//! the occupancy flags) and the two limits it is measured against on this machine, both timed
//! in the same run: the fp32 matmul peak ([`crate::mlp::gemm_peak_gflops`]) and the memory
//! bandwidth of a streaming kernel ([`stream_bandwidth_gbs`]), and for the hash lookups the
//! rate of random accesses ([`random_access_rate`]).
//!
//! Work model (what a perfect cache would move; the hash tables' corners are random 4- to
//! 32-byte reads, so their real traffic is whole 64-byte lines and latency, not bandwidth):
//! - networks: 2 FLOPs per multiply-add; a trained sample runs both networks forward and
//!   backward (3× the forward: the backward takes two matmuls per layer); the compaction pass
//!   runs the density network's hidden layer and its density column forward on every encoded
//!   sample (those its rounds reached along each ray: between the trained and the marched);
//! - hash forward: per encoded sample and level, 8 corners × `F` floats read and `F` written;
//! - hash backward: per trained sample and level, `F` gradient floats read, 8 corners × `F`
//!   floats read and written in the table gradient, and 8 one-byte touched flags written;
//! - sparse Adam: every one-byte flag read, and per touched entry `F` floats of parameter,
//!   gradient and both moments read and written (8 × 4 bytes per float);
//! - network Adam: per parameter, parameter, gradient and both moments read and parameter and
//!   moments written (7 × 4 bytes).
//!
//! The hash phases are also counted in corners (8 per sample and level) against a third limit
//! measured in the same run, [`random_access_rate`]: independent random reads (forward) or
//! read-modify-writes (backward) of one entry in a table the size of one level.

use crate::models::fast::FastConfig;
use rayon::prelude::*;

/// Threads of the rayon pool the trainer and both limits run on.
pub fn threads() -> usize {
    rayon::current_num_threads()
}

/// Memory bandwidth in GB/s (10⁹ bytes) of a STREAM-style triad `a[i] = b[i] + s · c[i]` over
/// three arrays of `n` floats on every rayon thread, counting 12 bytes per element (two reads
/// and one write, as STREAM does); the best of `reps` timed runs after one warm-up.
pub fn stream_bandwidth_gbs(n: usize, reps: usize) -> f64 {
    let b: Vec<f32> = (0..n).into_par_iter().map(|i| (i % 1024) as f32).collect();
    let c: Vec<f32> = (0..n).into_par_iter().map(|i| (i % 512) as f32).collect();
    let mut a = vec![0.0f32; n];
    const CHUNK: usize = 1 << 16;
    let mut best = f64::INFINITY;
    for rep in 0..=reps.max(1) {
        let s = 1.0 + rep as f32 * 1e-3;
        let t = std::time::Instant::now();
        a.par_chunks_mut(CHUNK).zip(b.par_chunks(CHUNK)).zip(c.par_chunks(CHUNK)).for_each(|((a, b), c)| {
            for ((a, b), c) in a.iter_mut().zip(b).zip(c) {
                *a = b + s * c;
            }
        });
        if rep > 0 {
            best = best.min(t.elapsed().as_secs_f64());
        }
        std::hint::black_box(&a);
    }
    12.0 * n as f64 / best / 1e9
}

/// Random accesses per second, summed over the rayon threads, to entries of `entry_floats`
/// floats at independent, uniformly random positions in a table of `entries` entries: the
/// memory system's limit for the hash grid's corner lookups, which streaming bandwidth
/// overstates (a random corner costs a whole 64-byte line and a latency). Each thread owns
/// one table, the working set of one hash level (the forward runs level after level; the
/// backward gives each thread a level), and makes `accesses_per_thread` accesses whose
/// addresses do not depend on loaded data, so that the core overlaps their misses as it does
/// the corners'. Reads (`write = false`: every float of the entry is read) or
/// read-modify-writes (`write = true`: every float incremented, as the backward accumulates
/// into the table gradient). The best of `reps` timed runs after one warm-up.
pub fn random_access_rate(entries: usize, entry_floats: usize, accesses_per_thread: usize, reps: usize, write: bool) -> f64 {
    let (entries, f) = (entries.max(1), entry_floats.max(1));
    let threads = threads().max(1);
    let mut tables: Vec<Vec<f32>> = (0..threads).into_par_iter().map(|k| vec![k as f32 + 1.0; entries * f]).collect();
    let mut best = f64::INFINITY;
    for rep in 0..=reps.max(1) {
        let t = std::time::Instant::now();
        let check = tables
            .par_iter_mut()
            .enumerate()
            .map(|(k, table)| random_access_pass(table, f, accesses_per_thread, (k as u64) << 32 | rep as u64, write))
            .reduce(|| 0, |a, b| a ^ b);
        std::hint::black_box(check);
        std::hint::black_box(&tables);
        if rep > 0 {
            best = best.min(t.elapsed().as_secs_f64());
        }
    }
    (threads * accesses_per_thread.div_ceil(STREAMS) * STREAMS) as f64 / best
}

/// Independent address streams of [`random_access_pass`]: enough that generating addresses
/// (a multiply-add each) is never the limit, only the memory system.
const STREAMS: usize = 8;

/// One thread's part of [`random_access_rate`]: `accesses` (rounded up to a multiple of
/// [`STREAMS`]) accesses to entries of `f` floats of `table`, at positions from [`STREAMS`]
/// interleaved 64-bit LCGs (Knuth's MMIX constants) started from `seed`, whose high 32 bits
/// pick the entry; returns the XOR of the bits read (reads) or 0. `f` of 1, 2, 4 or 8 (the
/// hash grid's) runs with the entry size known at compile time, as the hash grid's kernels do.
fn random_access_pass(table: &mut [f32], f: usize, accesses: usize, seed: u64, write: bool) -> u32 {
    match (f, write) {
        (1, false) => pass::<1, false>(table, accesses, seed),
        (1, true) => pass::<1, true>(table, accesses, seed),
        (2, false) => pass::<2, false>(table, accesses, seed),
        (2, true) => pass::<2, true>(table, accesses, seed),
        (4, false) => pass::<4, false>(table, accesses, seed),
        (4, true) => pass::<4, true>(table, accesses, seed),
        (8, false) => pass::<8, false>(table, accesses, seed),
        (8, true) => pass::<8, true>(table, accesses, seed),
        // Other sizes: whole entries of `f` floats, one at a time.
        _ => {
            let mut acc = 0u32;
            let entries = (table.len() / f) as u64;
            let mut h: [u64; STREAMS] = streams(seed);
            for _ in 0..accesses.div_ceil(STREAMS) {
                for h in &mut h {
                    let i = next_entry(h, entries);
                    for x in &mut table[i * f..i * f + f] {
                        if write {
                            *x += 1.0;
                        } else {
                            acc ^= x.to_bits();
                        }
                    }
                }
            }
            acc
        }
    }
}

/// The start of each of the [`STREAMS`] address streams.
fn streams(seed: u64) -> [u64; STREAMS] {
    std::array::from_fn(|k| seed ^ (k as u64 + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15))
}

/// Advances one LCG stream and maps its high 32 bits to an entry in `[0, entries)`.
#[inline(always)]
fn next_entry(h: &mut u64, entries: u64) -> usize {
    *h = h.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
    (((*h >> 32) * entries) >> 32) as usize
}

/// [`random_access_pass`] for entries of `F` floats.
fn pass<const F: usize, const WRITE: bool>(table: &mut [f32], accesses: usize, seed: u64) -> u32 {
    let (entries, _) = table.as_chunks_mut::<F>();
    let n = entries.len() as u64;
    let mut h = streams(seed);
    let mut acc = 0u32;
    for _ in 0..accesses.div_ceil(STREAMS) {
        for h in &mut h {
            let e = &mut entries[next_entry(h, n)];
            if WRITE {
                for x in e {
                    *x += 1.0;
                }
            } else {
                for x in e.iter() {
                    acc ^= x.to_bits();
                }
            }
        }
    }
    acc
}

/// What one training step of a `fast` model did, for [`StepWork::of`].
#[derive(Clone, Copy, Debug, Default)]
pub struct StepCounts {
    /// Samples marched.
    pub marched: f64,
    /// Samples hash-encoded and put through the compaction pass (up to `marched`).
    pub encoded: f64,
    /// Samples trained on (after compaction).
    pub trained: f64,
    /// Hash-table entries the sparse Adam updated.
    pub touched: f64,
}

/// The work of the phases of one step, from the model's sizes and [`StepCounts`].
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct StepWork {
    /// FLOPs of the fused network sweep (both networks forward and backward).
    pub mlp_flops: f64,
    /// FLOPs of the compaction pass (density network's hidden layer and density column).
    pub density_pass_flops: f64,
    /// Bytes of the hash-grid forward.
    pub hash_forward_bytes: f64,
    /// Bytes of the hash-grid backward.
    pub hash_backward_bytes: f64,
    /// Bytes of the sparse Adam over the hash tables.
    pub adam_hash_bytes: f64,
    /// Bytes of the networks' Adam.
    pub adam_mlp_bytes: f64,
    /// Corner reads of the hash-grid forward (8 per encoded sample and level).
    pub hash_forward_corners: f64,
    /// Corner read-modify-writes of the hash-grid backward (8 per trained sample and level).
    pub hash_backward_corners: f64,
}

impl StepWork {
    /// The work model of the module docs for a model of `config` with `mlp_params` network
    /// parameters.
    pub fn of(config: &FastConfig, mlp_params: usize, c: StepCounts) -> Self {
        let (l, f) = (config.levels as f64, config.features_per_level as f64);
        let enc = l * f;
        let dw = config.density_width as f64;
        let density = enc * dw + dw * config.geo_features as f64;
        let cin = (config.geo_features + config.dir_dims()) as f64;
        let cw = config.color_width as f64;
        let color = cin * cw + config.color_depth.saturating_sub(1) as f64 * cw * cw + cw * 3.0;
        let table_entries = l * (1u64 << config.log2_table_size) as f64;
        StepWork {
            mlp_flops: c.trained * (density + color) * 2.0 * 3.0,
            density_pass_flops: c.encoded * (enc * dw + dw) * 2.0,
            hash_forward_bytes: c.encoded * l * (8.0 * f + f) * 4.0,
            hash_backward_bytes: c.trained * l * (f * 4.0 + 8.0 * f * 4.0 * 2.0 + 8.0),
            adam_hash_bytes: table_entries + c.touched * f * 4.0 * 8.0,
            adam_mlp_bytes: mlp_params as f64 * 4.0 * 7.0,
            hash_forward_corners: c.encoded * l * 8.0,
            hash_backward_corners: c.trained * l * 8.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The work model against a hand count for a tiny model: 2 levels of 2 features (enc 4),
    /// density 4 → 8 → 3, colour (3 + 0) → 8 → 3 (depth 1, no view dependence), 2⁴ entries.
    #[test]
    fn work_model_counts_by_hand() {
        let cfg = FastConfig {
            levels: 2,
            features_per_level: 2,
            log2_table_size: 4,
            density_width: 8,
            geo_features: 3,
            color_width: 8,
            color_depth: 1,
            view_dependent: Some(false),
            ..FastConfig::new()
        };
        assert_eq!(cfg.dir_dims(), 0);
        let w = StepWork::of(&cfg, 100, StepCounts { marched: 12.0, encoded: 10.0, trained: 5.0, touched: 6.0 });
        // density 4·8 + 8·3 = 56, colour 3·8 + 8·3 = 48 MACs; ×2 FLOPs ×3 (fwd + bwd) × 5 samples
        assert_eq!(w.mlp_flops, 5.0 * 104.0 * 6.0);
        // compaction: (4·8 + 8) MACs × 2 × 10 samples
        assert_eq!(w.density_pass_flops, 10.0 * 40.0 * 2.0);
        // forward: 10 samples × 2 levels × (8 corners × 2 + 2) floats × 4 bytes
        assert_eq!(w.hash_forward_bytes, 10.0 * 2.0 * 18.0 * 4.0);
        // backward: 5 × 2 levels × (2·4 + 8·2·4·2 + 8) bytes
        assert_eq!(w.hash_backward_bytes, 5.0 * 2.0 * (8.0 + 128.0 + 8.0));
        // 32 flags + 6 entries × 2 floats × 32 bytes; 100 parameters × 28 bytes
        assert_eq!(w.adam_hash_bytes, 32.0 + 6.0 * 2.0 * 32.0);
        assert_eq!(w.adam_mlp_bytes, 2800.0);
        // 8 corners × 2 levels × 10 encoded (forward) and × 5 trained (backward)
        assert_eq!((w.hash_forward_corners, w.hash_backward_corners), (160.0, 80.0));
    }

    /// The limits are finite and positive on any machine (their values are the benchmark's).
    #[test]
    fn limits_are_measured() {
        let bw = stream_bandwidth_gbs(1 << 16, 1);
        let peak = crate::mlp::gemm_peak_gflops(64, 1);
        assert!(bw.is_finite() && bw > 0.0 && peak.is_finite() && peak > 0.0, "bandwidth {bw} GB/s, peak {peak} GFLOP/s");
        for write in [false, true] {
            let r = random_access_rate(1 << 12, 2, 1 << 12, 1, write);
            assert!(r.is_finite() && r > 0.0, "random access rate {r}/s (write {write})");
        }
    }

    /// The random-access kernel spreads its accesses uniformly over the table (so it stands for
    /// random corners) and touches every float of an entry: its read-modify-write pass adds
    /// exactly one per float per access, every entry is reached, none more than twice its share.
    #[test]
    fn random_access_kernel_spreads_its_accesses_over_the_table() {
        let (entries, f, n) = (64usize, 2usize, 1usize << 14);
        let mut table = vec![0.0f32; entries * f];
        assert_eq!(random_access_pass(&mut table, f, n, 7, true), 0);
        assert_eq!(table.iter().sum::<f32>(), (n * f) as f32);
        let share = (n / entries) as f32;
        for e in table.chunks_exact(f) {
            assert_eq!(e[0], e[1], "both floats of an entry");
            assert!(e[0] > share / 2.0 && e[0] < 2.0 * share, "{} accesses to one entry, share {share}", e[0]);
        }
        // Reads leave the table alone.
        let before = table.clone();
        random_access_pass(&mut table, f, n, 7, false);
        assert_eq!(table, before);
    }
}
