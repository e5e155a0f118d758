//! Neural radiance fields on the CPU with burn: encodings, fields, ray samplers, volume
//! rendering, the NeRF paper's model and a fast hash-grid model, the training loop,
//! checkpoints, and rendering colour, opacity and depth from a trained run.
//!
//! Layers (nerfstudio's order): data ([`data`]) → encodings ([`encoding`]) → fields
//! ([`field`]) → samplers ([`sampling`], [`occupancy`]) and renderers ([`volrend`]) → models
//! ([`models`]) → trainer ([`train`]); [`backend`] chooses the burn device in one place;
//! [`auto`] sizes the fast model from the scene and its cameras (`--model auto`); [`kernels`]
//! holds the small helpers every layer shares (random streams, tensor and parameter plumbing);
//! [`poses`] perturbs training poses on purpose and [`camera_opt`] refines them.

pub mod auto;
pub mod backend;
pub mod camera_opt;
pub mod checkpoint;
pub mod data;
pub mod encoding;
pub mod field;
pub mod kernels;
pub mod mlp;
pub mod models;
pub mod occupancy;
pub mod poses;
pub mod render;
pub mod roofline;
pub mod sampling;
pub mod supervision;
pub mod train;
pub mod volrend;
