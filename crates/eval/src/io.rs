//! Atomic file output: every file is written to a temporary name in its destination folder
//! and then renamed over the destination, so a reader never sees a half-written file.

use std::path::Path;

use crate::error::EvalError;

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> EvalError + '_ {
    move |source| EvalError::Io { path: path.to_path_buf(), source }
}

/// Write `bytes` to `path` atomically through the project's one implementation,
/// [`dataset::io::atomic_write`] (temporary name in the same folder, then rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), EvalError> {
    dataset::io::atomic_write(path, bytes).map_err(EvalError::from)
}

/// Serialise `value` as pretty JSON and write it atomically.
pub fn write_json_atomic<T: serde::Serialize>(path: &Path, value: &T) -> Result<(), EvalError> {
    let mut text = serde_json::to_string_pretty(value)
        .map_err(|source| EvalError::Json { path: path.to_path_buf(), source })?;
    text.push('\n');
    write_atomic(path, text.as_bytes())
}

/// Read and parse a JSON file written by this crate (`eval.json`, `report.json`).
pub fn read_json<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, EvalError> {
    let text = std::fs::read_to_string(path).map_err(io_err(path))?;
    serde_json::from_str(&text).map_err(|source| EvalError::Json { path: path.to_path_buf(), source })
}

/// Encode an 8-bit RGB buffer as PNG and write it atomically.
///
/// # Shapes
/// `rgb`: `[height * width * 3]`, row-major, row 0 on top.
pub fn write_png_atomic(path: &Path, width: u32, height: u32, rgb: Vec<u8>) -> Result<(), EvalError> {
    let img = image::RgbImage::from_raw(width, height, rgb).ok_or_else(|| {
        EvalError::Input(format!("{}: pixel buffer does not match {width}x{height}", path.display()))
    })?;
    let mut bytes = std::io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, image::ImageFormat::Png)
        .map_err(|source| EvalError::Png { path: path.to_path_buf(), source })?;
    write_atomic(path, &bytes.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_write_replaces_and_leaves_no_temp() {
        let dir = std::env::temp_dir().join(format!("eval-io-{}", std::process::id()));
        let path = dir.join("sub").join("a.json");
        write_atomic(&path, b"one").unwrap();
        write_atomic(&path, b"two").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"two");
        let names: Vec<_> = std::fs::read_dir(dir.join("sub")).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names, vec![std::ffi::OsString::from("a.json")]);
        write_png_atomic(&dir.join("p.png"), 2, 1, vec![255, 0, 0, 0, 0, 255]).unwrap();
        let img = image::open(dir.join("p.png")).unwrap().to_rgb8();
        assert_eq!(img.get_pixel(1, 0).0, [0, 0, 255]);
        assert!(write_png_atomic(&dir.join("q.png"), 2, 2, vec![0; 3]).is_err());
        write_json_atomic(&dir.join("v.json"), &vec![1.5, 2.0]).unwrap();
        assert_eq!(read_json::<Vec<f64>>(&dir.join("v.json")).unwrap(), vec![1.5, 2.0]);
        let e = read_json::<Vec<String>>(&dir.join("v.json")).unwrap_err();
        assert!(e.to_string().contains("v.json"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
