//! A render request's parameters (`GET /api/render`), checked before anything renders:
//! `w`, `h` (1 to [`MAX_SIZE`] pixels), `c2w` (16 finite numbers, the camera-to-world matrix row
//! by row in the OpenGL camera frame, a rigid transform), `fov` (the vertical field of view in
//! degrees, strictly between 0 and 180), `mode` (`rgb`, `depth` or `opacity`, default `rgb`),
//! and the page's `client` and `seq` (a per-page counter: a request older than the newest one
//! of its page is dropped before it renders). Each bad value is a 400 naming the parameter.

use crate::error::{ViewerError, bad};
use crate::query::Target;
use dataset::{Camera, Intrinsics};
use glam::DMat4;

/// The largest width or height rendered, pixels.
pub const MAX_SIZE: u32 = 4096;

/// What a render shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Display colour on the run's evaluation background.
    Rgb,
    /// Expected z-depth, colour-mapped (viridis, near = dark) over the scene box's depth range.
    Depth,
    /// Accumulated opacity Σw, grey.
    Opacity,
}

impl Mode {
    /// Parses `rgb`, `depth` or `opacity`.
    pub fn parse(s: &str) -> Result<Self, ViewerError> {
        match s {
            "rgb" => Ok(Self::Rgb),
            "depth" => Ok(Self::Depth),
            "opacity" => Ok(Self::Opacity),
            _ => Err(bad(format!("parameter 'mode' = '{s}': expected rgb, depth or opacity"))),
        }
    }
}

/// A checked render request.
#[derive(Clone, Debug)]
pub struct RenderRequest {
    /// The camera to render.
    pub camera: Camera,
    /// What to show.
    pub mode: Mode,
    /// The page that asked, and its request counter (both optional).
    pub order: Option<(String, u64)>,
}

/// Width and height parameters `w` and `h`, each 1 to [`MAX_SIZE`].
pub fn size(t: &Target) -> Result<(u32, u32), ViewerError> {
    let mut out = [0u32; 2];
    for (o, name) in out.iter_mut().zip(["w", "h"]) {
        let v: u64 = t.number(name, None)?;
        if v == 0 || v > MAX_SIZE as u64 {
            return Err(bad(format!("parameter '{name}' = {v}: must be 1 to {MAX_SIZE} pixels")));
        }
        *o = v as u32;
    }
    Ok((out[0], out[1]))
}

/// The camera-to-world matrix of parameter `c2w`: 16 comma-separated finite numbers, row by row.
pub fn pose(t: &Target) -> Result<DMat4, ViewerError> {
    let raw = t.required("c2w")?;
    let nums: Vec<f64> = raw
        .split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| bad("parameter 'c2w': expected 16 comma-separated numbers (the camera-to-world matrix row by row)"))?;
    let m: [f64; 16] = nums
        .as_slice()
        .try_into()
        .map_err(|_| bad(format!("parameter 'c2w': {} numbers, expected 16 (the camera-to-world matrix row by row)", nums.len())))?;
    if m.iter().any(|v| !v.is_finite()) {
        return Err(bad("parameter 'c2w': holds a number that is not finite"));
    }
    Ok(DMat4::from_cols_array(&m).transpose())
}

impl RenderRequest {
    /// Parses and checks a render request's parameters.
    pub fn parse(t: &Target) -> Result<Self, ViewerError> {
        let (w, h) = size(t)?;
        let fov: f64 = t.number("fov", None)?;
        if !(fov.is_finite() && fov > 0.0 && fov < 180.0) {
            return Err(bad(format!("parameter 'fov' = {fov}: the vertical field of view must lie strictly between 0 and 180 degrees")));
        }
        let c2w = pose(t)?;
        let camera = Camera::new(Intrinsics::from_fov_y(w, h, fov.to_radians()), c2w)
            .map_err(|m| bad(format!("parameter 'c2w': {m} (a rigid, invertible camera-to-world transform is needed)")))?;
        let mode = Mode::parse(t.get("mode").unwrap_or("rgb"))?;
        let order = match t.get("seq") {
            Some(_) => Some((t.get("client").unwrap_or("").to_string(), t.number("seq", None)?)),
            None => None,
        };
        Ok(Self { camera, mode, order })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ID: &str = "1,0,0,0,0,1,0,0,0,0,1,2,0,0,0,1";

    fn parse(q: &str) -> Result<RenderRequest, ViewerError> {
        RenderRequest::parse(&Target::parse(&format!("/api/render?{q}")).unwrap())
    }

    #[test]
    fn a_good_request_and_each_bad_parameter() {
        let r = parse(&format!("w=32&h=16&fov=50&c2w={ID}&mode=depth&client=a&seq=4")).unwrap();
        assert_eq!((r.camera.intrinsics.width, r.camera.intrinsics.height), (32, 16));
        assert_eq!(r.camera.origin(), glam::DVec3::new(0.0, 0.0, 2.0));
        assert_eq!((r.mode, r.order), (Mode::Depth, Some(("a".into(), 4))));
        let cases = [
            (format!("w=4097&h=16&fov=50&c2w={ID}"), "'w' = 4097"),
            (format!("w=0&h=16&fov=50&c2w={ID}"), "'w' = 0"),
            (format!("w=8&fov=50&c2w={ID}"), "missing query parameter 'h'"),
            (format!("w=8&h=8&fov=NaN&c2w={ID}"), "'fov' = NaN"),
            (format!("w=8&h=8&fov=180&c2w={ID}"), "'fov' = 180"),
            ("w=8&h=8&fov=50&c2w=1,0,0".into(), "3 numbers"),
            ("w=8&h=8&fov=50&c2w=1,0,0,0,0,1,0,0,0,0,1,inf,0,0,0,1".into(), "not finite"),
            ("w=8&h=8&fov=50&c2w=0,0,0,0,0,0,0,0,0,0,0,0,0,0,0,1".into(), "rigid"),
            (format!("w=8&h=8&fov=50&c2w={ID}&mode=normals"), "'mode' = 'normals'"),
        ];
        for (q, want) in cases {
            let e = parse(&q).unwrap_err();
            assert_eq!(e.status(), 400, "{q}");
            assert!(e.to_string().contains(want), "{q}: {e}");
        }
    }
}
