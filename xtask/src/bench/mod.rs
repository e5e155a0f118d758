//! `cargo xtask bench`: the benchmarks, one file each.

mod auto;
mod auto_diff;
mod nerf;
mod render;

pub use render::{BenchArgs, run};
