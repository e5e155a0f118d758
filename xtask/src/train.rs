//! `cargo xtask train` and `render-nerf` (being written).

/// Arguments of `train`.
#[derive(clap::Args)]
pub struct TrainArgs {}
/// Arguments of `render-nerf`.
#[derive(clap::Args)]
pub struct RenderNerfArgs {}

/// Trains a model.
pub fn run(_args: TrainArgs) -> anyhow::Result<()> {
    anyhow::bail!("train is not implemented yet")
}
/// Renders views from a run.
pub fn run_render(_args: RenderNerfArgs) -> anyhow::Result<()> {
    anyhow::bail!("render-nerf is not implemented yet")
}
