//! MP4 video of RGB frames: H.264 (Constrained Baseline, yuv420p, the format every browser
//! plays) encoded by OpenH264 (the `openh264` crate, which compiles Cisco's C++ source: no system
//! library or ffmpeg is needed) and muxed by `muxide` (pure Rust, `moov` before `mdat` so a
//! browser starts playing before the whole file has arrived).
//!
//! yuv420p needs an even width and height, and OpenH264 at least 16 pixels a side: a frame
//! is padded to that by repeating its last column or row. Every frame is encoded at a fixed bit rate of about 0.2 bits per pixel per
//! frame (at least 1 Mbit/s) with an IDR frame every second, so a player can seek. The file is
//! written under a temporary name and renamed when finished.

use crate::EvalError;
use openh264::encoder::{BitRate, Encoder, EncoderConfig, FrameRate, FrameType, IntraFramePeriod};
use openh264::formats::{RgbSliceU8, YUVBuffer};
use std::path::{Path, PathBuf};

/// Writes frames into an MP4 file; [`VideoWriter::finish`] completes it.
pub struct VideoWriter {
    path: PathBuf,
    tmp: PathBuf,
    width: u32,
    height: u32,
    fps: f64,
    frames: u64,
    encoder: Encoder,
    muxer: muxide::api::Muxer<std::fs::File>,
}

impl std::fmt::Debug for VideoWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VideoWriter").field("path", &self.path).field("frames", &self.frames).finish()
    }
}

fn video_err(path: &Path, what: impl std::fmt::Display) -> EvalError {
    EvalError::Input(format!("{}: video encoding failed: {what}", path.display()))
}

/// The encoded size of a side of `n` pixels: even (yuv420p), and at least 16 (OpenH264
/// refuses smaller frames).
pub fn even(n: u32) -> u32 {
    (n + (n & 1)).max(16)
}

impl VideoWriter {
    /// Starts a `width` × `height` video (before padding to even) at `fps` frames per second.
    pub fn create(path: &Path, width: u32, height: u32, fps: f64) -> Result<Self, EvalError> {
        if width == 0 || height == 0 || width > 8192 || height > 8192 {
            return Err(video_err(path, format!("frame size {width}x{height} is not 1 to 8192 pixels a side")));
        }
        if !(fps.is_finite() && fps > 0.0 && fps <= 1000.0) {
            return Err(video_err(path, format!("{fps} frames per second is not above 0 and at most 1000")));
        }
        let (w, h) = (even(width), even(height));
        let bits = ((w as f64 * h as f64 * fps * 0.2) as u32).max(1_000_000);
        let config = EncoderConfig::new()
            .bitrate(BitRate::from_bps(bits))
            .max_frame_rate(FrameRate::from_hz(fps as f32))
            .skip_frames(false)
            .intra_frame_period(IntraFramePeriod::from_num_frames(fps.round().max(1.0) as u32));
        let encoder = Encoder::with_api_config(openh264::OpenH264API::from_source(), config).map_err(|e| video_err(path, e))?;
        let tmp = dataset::io::temp_path_for(path);
        if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).map_err(|e| EvalError::Dataset(dataset::DatasetError::write(parent, e)))?;
        }
        let file = std::fs::File::create(&tmp).map_err(|e| EvalError::Dataset(dataset::DatasetError::write(path, e)))?;
        let muxer = muxide::api::MuxerBuilder::new(file)
            .video(muxide::api::VideoCodec::H264, w, h, fps)
            .with_fast_start(true)
            .build()
            .map_err(|e| video_err(path, e))?;
        Ok(Self { path: path.to_path_buf(), tmp, width, height, fps, frames: 0, encoder, muxer })
    }

    /// Appends one frame: `rgb` is `[height * width * 3]` 8-bit display colour, row 0 at the top.
    pub fn push(&mut self, rgb: &[u8]) -> Result<(), EvalError> {
        let (w, h) = (self.width as usize, self.height as usize);
        if rgb.len() != w * h * 3 {
            return Err(video_err(&self.path, format!("a frame of {} bytes, expected {w}x{h}x3", rgb.len())));
        }
        let (ew, eh) = (even(self.width) as usize, even(self.height) as usize);
        let padded: Vec<u8> = if (ew, eh) == (w, h) {
            rgb.to_vec()
        } else {
            (0..eh).flat_map(|y| (0..ew).flat_map(move |x| {
                let p = 3 * (y.min(h - 1) * w + x.min(w - 1));
                [rgb[p], rgb[p + 1], rgb[p + 2]]
            })).collect()
        };
        let yuv = YUVBuffer::from_rgb8_source(RgbSliceU8::new(&padded, (ew, eh)));
        let stream = self.encoder.encode(&yuv).map_err(|e| video_err(&self.path, e))?;
        let key = matches!(stream.frame_type(), FrameType::IDR | FrameType::I);
        let data = stream.to_vec();
        if data.is_empty() {
            return Err(video_err(&self.path, format!("the encoder skipped frame {}", self.frames)));
        }
        let pts = self.frames as f64 / self.fps;
        self.muxer.write_video(pts, &data, key).map_err(|e| video_err(&self.path, e))?;
        self.frames += 1;
        Ok(())
    }

    /// Completes the file and renames it into place; returns the number of frames.
    pub fn finish(self) -> Result<u64, EvalError> {
        let Self { path, tmp, muxer, frames, .. } = self;
        let done = (|| {
            if frames == 0 {
                return Err(video_err(&path, "no frames"));
            }
            muxer.finish().map_err(|e| video_err(&path, e))?;
            std::fs::rename(&tmp, &path).map_err(|e| EvalError::Dataset(dataset::DatasetError::write(&path, e)))
        })();
        if done.is_err() {
            let _ = std::fs::remove_file(&tmp);
        }
        done.map(|_| frames)
    }
}
