//! Camera paths made from a dataset: an orbit, a spiral, or a smooth path through chosen
//! views ([`crate::path_spline`]).
//!
//! - **Orbit**: `frames` cameras on a horizontal circle around the centre, at `elevation`
//!   degrees above the centre's horizontal plane (+Y up, the glTF world) and `radius` metres
//!   from it, looking at the centre, starting at azimuth 0 (+Z) and turning about +Y.
//! - **Spiral**: the same circle turned `turns` times while the elevation sweeps from
//!   `elevation − swing` to `elevation + swing` and back along a cosine.
//! - **Through views**: the train views named by index are the keyframes; frames in between
//!   come from the spline, and each keyframe's frame is that view's pose exactly.
//!
//! The defaults ([`OrbitDefaults::of`]) come from what the dataset carries: the centre is the
//! scene box's centre from `scene_facts` (else the point nearest to every train camera's
//! viewing axis), the radius and elevation the train cameras' mean distance and elevation
//! about that centre. Every camera has the first train view's intrinsics.

use crate::path_spline::interpolate_poses;
use crate::{Camera, Dataset, SplitKind};
use glam::{DMat3, DVec3};

/// Where an orbit or spiral goes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Orbit {
    /// The point looked at, world space.
    pub centre: DVec3,
    /// Distance from the centre, metres.
    pub radius: f64,
    /// Elevation above the centre's horizontal plane, degrees.
    pub elevation: f64,
    /// Number of frames.
    pub frames: u32,
    /// Number of turns (1 for an orbit).
    pub turns: f64,
    /// Half the elevation sweep of a spiral, degrees (0 for an orbit).
    pub swing: f64,
}

/// The scene centre and the train cameras' mean radius and elevation about it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrbitDefaults {
    /// Scene centre.
    pub centre: DVec3,
    /// Mean distance of the train cameras from the centre.
    pub radius: f64,
    /// Mean elevation of the train cameras about the centre, degrees.
    pub elevation: f64,
}

impl OrbitDefaults {
    /// The defaults of `dataset` (see the module documentation).
    pub fn of(dataset: &Dataset) -> Self {
        let cams: Vec<&Camera> = dataset.split(SplitKind::Train).iter().map(|f| &f.camera).collect();
        let centre = match &dataset.facts {
            Some(f) => (DVec3::from_array(f.aabb_min) + DVec3::from_array(f.aabb_max)) * 0.5,
            None => nearest_to_axes(&cams),
        };
        let n = cams.len().max(1) as f64;
        let radius = cams.iter().map(|c| (c.origin() - centre).length()).sum::<f64>() / n;
        let elevation = cams
            .iter()
            .map(|c| {
                let d = c.origin() - centre;
                (d.y / d.length().max(1e-300)).clamp(-1.0, 1.0).asin().to_degrees()
            })
            .sum::<f64>()
            / n;
        Self { centre, radius, elevation }
    }
}

/// The point with the least summed squared distance to every camera's viewing axis (the
/// origin when the axes are all parallel).
fn nearest_to_axes(cams: &[&Camera]) -> DVec3 {
    let mut a = DMat3::ZERO;
    let mut b = DVec3::ZERO;
    for c in cams {
        let d = -c.c2w.z_axis.truncate().normalize();
        let p = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += p;
        b += p * c.origin();
    }
    if a.determinant().abs() < 1e-9 { DVec3::ZERO } else { a.inverse() * b }
}

/// The cameras of an orbit or spiral, with `template`'s intrinsics.
pub fn orbit_cameras(orbit: &Orbit, template: &Camera) -> Result<Vec<Camera>, String> {
    if !(orbit.radius.is_finite() && orbit.radius > 0.0) {
        return Err(format!("radius {}: must be finite and positive", orbit.radius));
    }
    if orbit.frames == 0 {
        return Err("frames 0: a path needs at least one frame".into());
    }
    (0..orbit.frames)
        .map(|k| {
            let t = k as f64 / orbit.frames as f64;
            let azimuth = std::f64::consts::TAU * orbit.turns * t;
            let elevation = (orbit.elevation - orbit.swing * (std::f64::consts::TAU * t).cos()).clamp(-89.0, 89.0).to_radians();
            let dir = DVec3::new(elevation.cos() * azimuth.sin(), elevation.sin(), elevation.cos() * azimuth.cos());
            Camera::new(template.intrinsics, Camera::look_at(orbit.centre + orbit.radius * dir, orbit.centre, DVec3::Y))
                .map_err(|e| format!("frame {k}: {e}"))
        })
        .collect()
}

/// A smooth path through the train views `views` (indices into the train split), `per_segment`
/// frames from one to the next; returns the frames and the keyframe cameras.
pub fn through_views(dataset: &Dataset, views: &[usize], per_segment: u32, cycle: bool) -> Result<(Vec<Camera>, Vec<Camera>), String> {
    let train = dataset.split(SplitKind::Train);
    if views.is_empty() {
        return Err("no views given".into());
    }
    let keys: Vec<Camera> = views
        .iter()
        .map(|&v| train.get(v).map(|f| f.camera).ok_or_else(|| format!("view {v}: the train split has {} views (0 to {})", train.len(), train.len().saturating_sub(1))))
        .collect::<Result<_, _>>()?;
    let poses = interpolate_poses(&keys.iter().map(|c| c.c2w).collect::<Vec<_>>(), per_segment, cycle);
    let frames = poses
        .into_iter()
        .enumerate()
        .map(|(k, m)| Camera::new(keys[0].intrinsics, m).map_err(|e| format!("frame {k}: {e}")))
        .collect::<Result<_, _>>()?;
    Ok((frames, keys))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Intrinsics;

    #[test]
    fn an_orbit_circles_the_centre_at_its_radius_and_elevation() {
        let template = Camera::new(Intrinsics::from_fov_x(16, 16, 0.7), glam::DMat4::IDENTITY).unwrap();
        let centre = DVec3::new(1.0, 2.0, -1.0);
        let orbit = Orbit { centre, radius: 3.0, elevation: 30.0, frames: 12, turns: 1.0, swing: 0.0 };
        let cams = orbit_cameras(&orbit, &template).unwrap();
        assert_eq!(cams.len(), 12);
        for c in &cams {
            let d = c.origin() - centre;
            assert!((d.length() - 3.0).abs() < 1e-12);
            assert!((d.y - 1.5).abs() < 1e-12, "elevation 30 degrees at radius 3 is 1.5 m up");
            // Looks at the centre.
            assert!(((-c.c2w.z_axis.truncate()) + d.normalize()).length() < 1e-12);
        }
        let spiral = orbit_cameras(&Orbit { swing: 20.0, turns: 2.0, ..orbit }, &template).unwrap();
        let heights: Vec<f64> = spiral.iter().map(|c| c.origin().y - centre.y).collect();
        assert!(heights[0] < heights[6] && (heights[0] - 3.0 * 10f64.to_radians().sin()).abs() < 1e-12);
        assert!(orbit_cameras(&Orbit { radius: 0.0, ..orbit }, &template).is_err());
    }
}
