//! `cargo xtask render` (being written).

/// Arguments of `render`.
#[derive(clap::Args)]
pub struct RenderArgs {}

/// Renders a dataset.
pub fn run(_args: RenderArgs) -> anyhow::Result<std::path::PathBuf> {
    anyhow::bail!("render is not implemented yet")
}
