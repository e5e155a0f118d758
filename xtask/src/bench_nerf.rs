//! `cargo xtask bench nerf` (being written).

/// Prints training throughput figures for both models.
pub fn run() -> anyhow::Result<()> {
    anyhow::bail!("bench nerf is not implemented yet")
}
