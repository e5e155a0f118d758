//! `cargo xtask eval`, `compare` and `demo` (being written).

/// Arguments of `eval`.
#[derive(clap::Args)]
pub struct EvalArgs {}
/// Arguments of `compare`.
#[derive(clap::Args)]
pub struct CompareArgs {}
/// Arguments of `demo`.
#[derive(clap::Args)]
pub struct DemoArgs {}

/// Evaluates a run.
pub fn run(_args: EvalArgs) -> anyhow::Result<()> {
    anyhow::bail!("eval is not implemented yet")
}
/// Compares runs.
pub fn run_compare(_args: CompareArgs) -> anyhow::Result<()> {
    anyhow::bail!("compare is not implemented yet")
}
/// Runs the demo.
pub fn run_demo(_args: DemoArgs) -> anyhow::Result<()> {
    anyhow::bail!("demo is not implemented yet")
}
