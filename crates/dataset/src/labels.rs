//! Per-pixel object and material labels of a view, and their files.
//!
//! A rendered view may carry, beside its colour and ground truth:
//! - `<split>/r_<k>_ids.png`: 16-bit grey PNG, the object hit by the pixel-centre ray (the ray
//!   of the depth, normal and mask files, so the same hit): object ID = index in the scene
//!   facts' `objects` list + 1, 0 where the ray hits nothing;
//! - `<split>/r_<k>_material.png`: 16-bit grey PNG, the hit triangle's material index + 1
//!   (index into the facts' `materials` list), 0 on a miss;
//! - `<split>/r_<k>_coverage.npy`: float32 array of shape (height, width, 4) holding, per
//!   pixel, the two labels most of the pixel's image samples hit and their shares:
//!   `[id_a, share_a, id_b, share_b]` with `share_a ≥ share_b`, IDs as in `_ids.png` (0 = no
//!   hit, the background counts as a label), shares in [0, 1] summing to at most 1 (less when
//!   a third label was hit). An interior pixel has `share_a = 1`; an edge pixel, the soft edge
//!   where an exact mask and an anti-aliased image disagree, less.
//!
//! IDs are 16-bit: a scene with more than [`MAX_LABEL`] objects or materials is refused by the
//! renderer with that limit named.

use crate::DatasetError;
use crate::SplitKind;
use crate::io::{atomic_write, read};
use std::path::{Path, PathBuf};

/// The largest object or material ID a label file holds (16-bit PNG; 0 is "no hit").
pub const MAX_LABEL: usize = u16::MAX as usize;

/// One view's labels (row-major from the top row).
///
/// # Shapes
/// `object.len() == material.len() == coverage.len() == width * height`.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewLabels {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Object ID of the pixel-centre hit (0: none).
    pub object: Vec<u16>,
    /// Material index + 1 of the pixel-centre hit (0: none).
    pub material: Vec<u16>,
    /// `[id_a, share_a, id_b, share_b]` per pixel (see the module documentation).
    pub coverage: Vec<[f32; 4]>,
}

impl ViewLabels {
    /// Whether pixel `p` is an interior pixel: every sample of it hit one label.
    pub fn interior(&self, p: usize) -> bool {
        self.coverage.get(p).is_some_and(|c| c[1] >= 1.0)
    }
}

/// What a view's file stem (`r_<k>`) is followed by in its label files: object IDs, material
/// IDs, coverage.
pub const LABEL_SUFFIXES: [&str; 3] = ["_ids.png", "_material.png", "_coverage.npy"];

/// The label files of view `index` of `split`, relative to the dataset folder: object IDs,
/// material IDs, coverage.
pub fn label_files(split: SplitKind, index: u32) -> [String; 3] {
    LABEL_SUFFIXES.map(|suffix| format!("{}/r_{index}{suffix}", split.name()))
}

/// Whether all label files of view `index` of `split` exist in `dir`.
pub fn labels_complete(dir: &Path, split: SplitKind, index: u32) -> bool {
    label_files(split, index).iter().all(|f| dir.join(f).is_file())
}

/// The label counts of `values`: for each label its number of samples, the two most frequent
/// first (ties to the smaller label), as a coverage entry `[id_a, share_a, id_b, share_b]`.
/// `values` empty gives `[0, 0, 0, 0]`.
pub fn coverage_of(values: &[u16]) -> [f32; 4] {
    if values.is_empty() {
        return [0.0; 4];
    }
    let mut sorted = values.to_vec();
    sorted.sort_unstable();
    let mut runs: Vec<(usize, u16)> = Vec::new();
    for v in sorted {
        match runs.last_mut() {
            Some((n, id)) if *id == v => *n += 1,
            _ => runs.push((1, v)),
        }
    }
    // Most samples first; among equal counts, the smaller label (`runs` is sorted by label).
    runs.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
    let n = values.len() as f32;
    let (a, b) = (runs[0], runs.get(1).copied().unwrap_or((0, 0)));
    [a.1 as f32, a.0 as f32 / n, b.1 as f32, b.0 as f32 / n]
}

/// Writes a view's label files (`files` from [`label_files`], joined to the folder), each
/// atomically.
pub fn write_labels(files: &[PathBuf; 3], labels: &ViewLabels) -> Result<(), DatasetError> {
    let n = labels.width as usize * labels.height as usize;
    for (path, len) in [(&files[0], labels.object.len()), (&files[1], labels.material.len()), (&files[2], labels.coverage.len())] {
        if len != n {
            return Err(DatasetError::invalid(path, format!("{len} label values for a {}x{} view", labels.width, labels.height)));
        }
    }
    write_png_u16(&files[0], labels.width, labels.height, &labels.object)?;
    write_png_u16(&files[1], labels.width, labels.height, &labels.material)?;
    let mut out = npy_prefix(labels.height, labels.width);
    out.reserve(n * 16);
    for c in &labels.coverage {
        for v in c {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    atomic_write(&files[2], &out)
}

/// Reads a view's label files written by [`write_labels`]; each must decode at `width` ×
/// `height` (the first damaged or mis-sized file is named).
pub fn read_labels(files: &[PathBuf; 3], width: u32, height: u32) -> Result<ViewLabels, DatasetError> {
    let object = read_png_u16(&files[0], width, height)?;
    let material = read_png_u16(&files[1], width, height)?;
    let bytes = read(&files[2])?;
    let prefix = npy_prefix(height, width);
    let n = width as usize * height as usize;
    if !bytes.starts_with(&prefix) || bytes.len() != prefix.len() + 16 * n {
        return Err(DatasetError::invalid(
            &files[2],
            format!("not a whole {height}x{width}x4 float32 .npy array ({} bytes, {} expected)", bytes.len(), prefix.len() + 16 * n),
        ));
    }
    let coverage = bytes[prefix.len()..]
        .chunks_exact(16)
        .map(|c| std::array::from_fn(|k| f32::from_le_bytes([c[4 * k], c[4 * k + 1], c[4 * k + 2], c[4 * k + 3]])))
        .collect();
    Ok(ViewLabels { width, height, object, material, coverage })
}

/// The header of the (`height`, `width`, 4) float32 `.npy` file.
fn npy_prefix(height: u32, width: u32) -> Vec<u8> {
    crate::images::npy_f32_header(&[height as usize, width as usize, 4])
}

/// Writes a 16-bit single-channel PNG (the encoder takes native-endian samples and stores
/// them big-endian, as PNG does).
fn write_png_u16(path: &Path, width: u32, height: u32, values: &[u16]) -> Result<(), DatasetError> {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_ne_bytes()).collect();
    let mut out = Vec::new();
    {
        use image::ImageEncoder;
        let enc = image::codecs::png::PngEncoder::new(&mut out);
        enc.write_image(&bytes, width, height, image::ExtendedColorType::L16).map_err(|e| DatasetError::image(path, e))?;
    }
    atomic_write(path, &out)
}

/// Reads a 16-bit single-channel PNG of `width` × `height`.
fn read_png_u16(path: &Path, width: u32, height: u32) -> Result<Vec<u16>, DatasetError> {
    let bytes = read(path)?;
    let img = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png).map_err(|e| DatasetError::image(path, e))?;
    let image::DynamicImage::ImageLuma16(grey) = img else {
        return Err(DatasetError::invalid(path, "is not a 16-bit grey PNG (object and material IDs are)"));
    };
    if (grey.width(), grey.height()) != (width, height) {
        return Err(DatasetError::invalid(path, format!("is {}x{}, the view is {width}x{height}", grey.width(), grey.height())));
    }
    Ok(grey.into_raw())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coverage_counts_the_two_most_frequent_labels() {
        assert_eq!(coverage_of(&[3, 3, 3, 3]), [3.0, 1.0, 0.0, 0.0]);
        assert_eq!(coverage_of(&[0, 5, 5, 0, 5, 7, 5, 5]), [5.0, 0.625, 0.0, 0.25]);
        // Ties go to the smaller label.
        assert_eq!(coverage_of(&[9, 2, 9, 2]), [2.0, 0.5, 9.0, 0.5]);
        assert_eq!(coverage_of(&[]), [0.0; 4]);
    }

    #[test]
    fn labels_round_trip_and_damage_is_named() {
        let dir = std::env::temp_dir().join(format!("dataset-labels-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("test")).unwrap();
        let files = label_files(SplitKind::Test, 2).map(|f| dir.join(f));
        let (w, h) = (5u32, 3u32);
        let n = (w * h) as usize;
        let labels = ViewLabels {
            width: w,
            height: h,
            object: (0..n as u16).map(|k| k * 4099).collect(),
            material: (0..n as u16).map(|k| u16::MAX - k).collect(),
            coverage: (0..n).map(|k| [k as f32, 0.75, 0.0, 0.25]).collect(),
        };
        write_labels(&files, &labels).unwrap();
        assert!(labels_complete(&dir, SplitKind::Test, 2));
        assert_eq!(read_labels(&files, w, h).unwrap(), labels);
        let err = read_labels(&files, w + 1, h).unwrap_err().to_string();
        assert!(err.contains("r_2_ids.png") && err.contains("5x3"), "{err}");
        let bytes = std::fs::read(&files[2]).unwrap();
        std::fs::write(&files[2], &bytes[..bytes.len() - 4]).unwrap();
        let err = read_labels(&files, w, h).unwrap_err().to_string();
        assert!(err.contains("r_2_coverage.npy"), "{err}");
        let short = ViewLabels { object: vec![1; n - 1], ..labels };
        assert!(write_labels(&files, &short).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
