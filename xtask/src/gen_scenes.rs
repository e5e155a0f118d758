//! `cargo xtask gen-scenes`: regenerate the project's scenes from code.

use std::path::PathBuf;

/// Arguments of `gen-scenes`.
#[derive(clap::Args)]
pub struct GenScenesArgs {
    /// Output folder.
    #[arg(long, default_value = "scenes")]
    pub out: PathBuf,
}

/// Writes every scene of `scenegen` into `--out`.
pub fn run(args: GenScenesArgs) -> anyhow::Result<()> {
    let written = scenegen::write_all(&args.out)?;
    for p in &written {
        println!("{}", p.display());
    }
    println!("wrote {} files to {}", written.len(), args.out.display());
    Ok(())
}
