//! The dataset contract shared by every part of the project: cameras (intrinsics and
//! camera-to-world pose), pixel → ray, z-depth ↔ distance, splits and frames, reading and
//! writing `transforms_*.json` (Blender-synthetic layout plus the instant-ngp / nerfstudio
//! intrinsics keys and our `scene_facts` block), and the image files of a view (sRGB PNG,
//! linear EXR, ground-truth EXR, nerfstudio depth `.npy`), all written atomically.
//!
//! Conventions (see `docs/design.md`): metres, glTF world (+Y up); the camera frame is
//! OpenGL's (+X right, +Y up, looking down −Z); pixel (i, j) = (column, row) has its centre at
//! (i + 0.5, j + 0.5) with row 0 at the top; `depth` is z-depth along the camera's −Z axis and
//! `distance` the Euclidean length along the ray.
//!
//! ```
//! use dataset::{Camera, Intrinsics};
//! use glam::{DMat4, DVec3};
//! let intr = Intrinsics::from_fov_x(64, 48, 0.6911);
//! let cam = Camera::new(intr, Camera::look_at(DVec3::new(0.0, 0.0, 4.0), DVec3::ZERO, DVec3::Y)).unwrap();
//! let ray = cam.pixel_center_ray(32, 24);
//! // A plane at z = 0 seen head-on: the central ray travels 4 m, and z-depth equals distance.
//! let t = 4.0 / -ray.direction.z;
//! assert!((cam.z_depth_from_distance(32.5, 24.5, t) - 4.0).abs() < 1e-12);
//! ```

mod camera;
mod camera_path;
mod downscale;
mod error;
pub mod folder;
mod images;
mod path_shapes;
mod path_spline;
mod transforms;
pub mod io;
pub mod labels;
pub mod lock;
pub mod paths;
pub mod pose;

pub use camera_path::{CameraPathFile, MAX_PATH_SIZE, PathFrame, fov_degrees, matrix_to_row_major};
pub use path_shapes::{Orbit, OrbitDefaults, orbit_cameras, through_views};
pub use path_spline::interpolate_poses;
pub use camera::{Camera, Intrinsics, MAX_TRANSLATION, MIN_FIELD_OF_VIEW, Ray};
pub use downscale::check_downscale;
pub use error::{DatasetError, WriteError};
pub use images::{
    GroundTruth, RgbaImage, check_npy_f32, linear_to_srgb, read_exr_rgba, read_ground_truth, read_png_rgba,
    srgb_to_linear, write_exr_rgba, write_ground_truth, write_npy_f32, write_png_mask, write_png_rgba,
};
pub use transforms::{
    Dataset, Frame, FrameRecord, LoadOptions, MaterialFacts, ObjectFacts, SceneFacts, SplitKind, TransformsFile, check_transforms, instant_ngp_fit, nerfstudio_files,
    write_nerfstudio_transforms,
    write_split_transforms,
};
