//! Other tools' world frames, mapped back to the dataset's metric frame.
//!
//! - **nerfstudio** re-orients, re-centres and rescales the poses it loads and writes what it did
//!   to `dataparser_transforms.json` beside its run: `{"transform": T (3x4, rows), "scale": s}`
//!   (`DataparserOutputs.save_dataparser_transform`), with `x_ns = s · (R x + t)` for a point
//!   `x` of the dataset, `T = [R | t]`. [`NerfstudioTransform::to_dataset`] is the inverse,
//!   `x = R⁻¹ (x_ns / s − t)`; a length in nerfstudio's frame is `s` times the dataset's.
//!   `ns-render dataset` divides `raw-*depth*` outputs by `s` itself (`scripts/render.py`,
//!   `DatasetRender`, nerfstudio 1.1.5), so only depth taken from the model directly is in
//!   nerfstudio's units.
//! - **instant-ngp** maps a position `p` of the transforms file's frame to
//!   `cycle(p · scale + offset)` with the axes cycled `xyz ← yzx` (`nerf_matrix_to_ngp` in
//!   `scripts/common.py` and `nerf_loader.cu`), `scale` and `offset` read from the transforms
//!   file (defaults 0.33 and (0.5, 0.5, 0.5)); the offset is in the file's axis order.
//!   [`InstantNgpTransform::to_dataset`] is the inverse; a length in instant-ngp's frame is
//!   `scale` times the dataset's. Its saved meshes are in `(x − offset) / scale` of its frame,
//!   axes still cycled ([`InstantNgpTransform::mesh_to_dataset`]).
//!
//! Both give a 4x4 `f64` matrix acting on column vectors `(x, y, z, 1)` (glam's convention).

use crate::EvalError;
use glam::{DMat4, DVec3, DVec4};
use std::path::Path;

/// instant-ngp's default `scale` when the transforms file has none.
pub const INSTANT_NGP_DEFAULT_SCALE: f64 = 0.33;
/// instant-ngp's default `offset` when the transforms file has none.
pub const INSTANT_NGP_DEFAULT_OFFSET: [f64; 3] = [0.5, 0.5, 0.5];

fn invalid(path: &Path, message: impl std::fmt::Display) -> EvalError {
    EvalError::Input(format!("{}: {message}", path.display()))
}

/// nerfstudio's dataparser transform (`dataparser_transforms.json`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NerfstudioTransform {
    /// `[R | t]`, row by row.
    pub transform: [[f64; 4]; 3],
    /// The scale `s` applied after the transform.
    pub scale: f64,
}

impl NerfstudioTransform {
    /// Parses the text of a `dataparser_transforms.json`; `path` names it in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Self, EvalError> {
        #[derive(serde::Deserialize)]
        struct File {
            transform: Vec<Vec<f64>>,
            scale: f64,
        }
        let f: File = serde_json::from_str(text).map_err(|e| invalid(path, format!("not nerfstudio's dataparser_transforms.json ({e})")))?;
        if f.transform.len() != 3 || f.transform.iter().any(|r| r.len() != 4) {
            return Err(invalid(path, "\"transform\" must be 3 rows of 4 numbers"));
        }
        if !(f.scale.is_finite() && f.scale > 0.0) {
            return Err(invalid(path, format!("\"scale\" is {}, not a positive number", f.scale)));
        }
        let mut transform = [[0.0; 4]; 3];
        for (row, r) in transform.iter_mut().zip(&f.transform) {
            row.copy_from_slice(r);
        }
        let t = Self { transform, scale: f.scale };
        let m = t.to_nerfstudio();
        if !m.to_cols_array().iter().all(|v| v.is_finite()) || m.determinant().abs() < 1e-12 {
            return Err(invalid(path, "\"transform\" is not an invertible finite matrix"));
        }
        Ok(t)
    }

    /// Reads `dataparser_transforms.json` (a regular file of at most 1 MiB).
    pub fn read(path: &Path) -> Result<Self, EvalError> {
        let bytes = crate::prediction_io::read_regular(path, 1 << 20)?;
        Self::parse(&String::from_utf8_lossy(&bytes), path)
    }

    /// The map from the dataset's frame to nerfstudio's: `x ↦ s · (R x + t)`.
    pub fn to_nerfstudio(&self) -> DMat4 {
        let r = |i: usize| DVec4::from_array(self.transform[i]);
        // The rows of [R | t; 0 0 0 1] (glam stores columns, hence the transpose).
        let a = DMat4::from_cols(r(0), r(1), r(2), DVec4::W).transpose();
        DMat4::from_scale(DVec3::splat(self.scale)) * a
    }

    /// The map from nerfstudio's frame back to the dataset's metric frame (the inverse of
    /// [`Self::to_nerfstudio`]).
    pub fn to_dataset(&self) -> DMat4 {
        self.to_nerfstudio().inverse()
    }

    /// A length (a depth, a distance) in nerfstudio's frame, in the dataset's metres.
    pub fn length_to_dataset(&self, length: f64) -> f64 {
        length / self.scale
    }
}

/// instant-ngp's `scale` and `offset` (from the transforms file it loaded).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InstantNgpTransform {
    /// Positions are multiplied by it (lengths too).
    pub scale: f64,
    /// Added after scaling, in the transforms file's axis order.
    pub offset: [f64; 3],
}

impl InstantNgpTransform {
    /// The transform of a transforms file (a JSON object): its `scale` and `offset`, or
    /// instant-ngp's defaults where absent; `path` names it in errors.
    pub fn from_json(json: &serde_json::Value, path: &Path) -> Result<Self, EvalError> {
        let scale = match json.get("scale") {
            None => INSTANT_NGP_DEFAULT_SCALE,
            Some(v) => v.as_f64().filter(|s| s.is_finite() && *s > 0.0).ok_or_else(|| invalid(path, format!("\"scale\" is {v}, not a positive number")))?,
        };
        let offset = match json.get("offset") {
            None => INSTANT_NGP_DEFAULT_OFFSET,
            Some(v) => {
                let a: Option<Vec<f64>> = v.as_array().map(|a| a.iter().filter_map(|x| x.as_f64().filter(|x| x.is_finite())).collect());
                match a {
                    Some(a) if a.len() == 3 && v.as_array().is_some_and(|v| v.len() == 3) => [a[0], a[1], a[2]],
                    _ => return Err(invalid(path, format!("\"offset\" is {v}, not 3 finite numbers"))),
                }
            }
        };
        Ok(Self { scale, offset })
    }

    /// The map from the transforms file's frame to instant-ngp's: `p ↦ cycle(p · scale +
    /// offset)`, where `cycle(x, y, z) = (y, z, x)`.
    pub fn to_instant_ngp(&self) -> DMat4 {
        let cycle = DMat4::from_cols(DVec4::new(0.0, 0.0, 1.0, 0.0), DVec4::new(1.0, 0.0, 0.0, 0.0), DVec4::new(0.0, 1.0, 0.0, 0.0), DVec4::W);
        cycle * DMat4::from_translation(DVec3::from_array(self.offset)) * DMat4::from_scale(DVec3::splat(self.scale))
    }

    /// The map from instant-ngp's frame back to the dataset's metric frame.
    pub fn to_dataset(&self) -> DMat4 {
        self.to_instant_ngp().inverse()
    }

    /// A length in instant-ngp's frame, in the dataset's metres.
    pub fn length_to_dataset(&self, length: f64) -> f64 {
        length / self.scale
    }

    /// The map from the frame of a mesh instant-ngp saved (`--save_mesh`) to the dataset's.
    /// `save_mesh` writes `v = (x − offset) / scale` for a point `x` of its own frame, undoing
    /// the scale and offset but not the axis cycle, so `x = v · scale + offset` and then
    /// [`Self::to_dataset`].
    pub fn mesh_to_dataset(&self) -> DMat4 {
        self.to_dataset() * DMat4::from_translation(DVec3::from_array(self.offset)) * DMat4::from_scale(DVec3::splat(self.scale))
    }
}
