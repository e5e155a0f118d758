//! Regenerate the built-in scenes: `cargo run -p scenegen --example gen -- scenes`
//! writes every scene and `README.md` into the given folder (default `scenes`).

use std::path::PathBuf;

fn main() {
    let dir = PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "scenes".to_string()),
    );
    match scenegen::write_all(&dir) {
        Ok(files) => {
            for f in &files {
                println!("{}", f.display());
            }
        }
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}
