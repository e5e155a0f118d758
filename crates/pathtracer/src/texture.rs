//! Texture lookup: glTF wrap modes (repeat, mirrored repeat, clamp to edge) and nearest or
//! bilinear filtering, without mipmaps.
//!
//! Conventions: UV (0, 0) is the top-left corner of the image (texel row 0 is the top row),
//! UV (1, 1) the bottom-right. Texel `(x, y)` covers `[x, x+1) × [y, y+1)` in continuous
//! texel coordinates `(u·w, v·h)`, so its centre is at `(x + ½, y + ½)`. Bilinear filtering
//! interpolates between the four texel centres around `(u·w − ½, v·h − ½)`, wrapping each
//! texel index with the sampler's mode.

use crate::scene::{Filter, Texture, TextureRef, Wrap};
use glam::{Vec2, Vec4};

/// Maps an integer texel index into `[0, n)` according to the wrap mode.
#[inline]
pub fn wrap_index(i: i64, n: u32, wrap: Wrap) -> u32 {
    let n = n as i64;
    // Every mode maps an index already in range to itself; skip the 64-bit division then
    // (the common case: interior texels).
    if 0 <= i && i < n {
        return i as u32;
    }
    let r = match wrap {
        Wrap::Repeat => i.rem_euclid(n),
        Wrap::ClampToEdge => i.clamp(0, n - 1),
        Wrap::MirroredRepeat => {
            let period = 2 * n;
            let m = i.rem_euclid(period);
            if m < n { m } else { period - 1 - m }
        }
    };
    r as u32
}

/// `x.floor()` as an integer for finite `|x| ≤ 2⁵³` (exactly; texture coordinates are
/// clamped to ±10¹⁵), without the `floor` library call that baseline x86-64 makes.
#[inline(always)]
fn floor_i64(x: f64) -> i64 {
    let i = x as i64;
    i - ((i as f64) > x) as i64
}

impl Texture {
    /// The texel at integer coordinates (already wrapped into range).
    #[inline]
    pub fn texel(&self, x: u32, y: u32) -> Vec4 {
        self.texels[y as usize * self.width as usize + x as usize]
    }

    /// Samples the texture at `uv` with the given wrap modes and filter. A texture with no
    /// texels (or a non-finite `uv`) returns opaque white, the neutral factor. (Not inlined:
    /// inlined at the path loop's SIMD level it was slower, `docs/experiments.md`.)
    pub fn sample(&self, uv: Vec2, wrap_s: Wrap, wrap_t: Wrap, filter: Filter) -> Vec4 {
        if self.width == 0 || self.height == 0 || !uv.is_finite() || self.texels.len() < (self.width as usize * self.height as usize) {
            return Vec4::ONE;
        }
        // Keep coordinates in a range where f32 → i64 is exact and safe.
        let x = (uv.x as f64 * self.width as f64).clamp(-1e15, 1e15);
        let y = (uv.y as f64 * self.height as f64).clamp(-1e15, 1e15);
        match filter {
            Filter::Nearest => {
                let xi = wrap_index(floor_i64(x), self.width, wrap_s);
                let yi = wrap_index(floor_i64(y), self.height, wrap_t);
                self.texel(xi, yi)
            }
            Filter::Linear => {
                let (x, y) = (x - 0.5, y - 0.5);
                let (x0, y0) = (floor_i64(x), floor_i64(y));
                let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
                let xa = wrap_index(x0, self.width, wrap_s);
                let xb = wrap_index(x0 + 1, self.width, wrap_s);
                let ya = wrap_index(y0, self.height, wrap_t);
                let yb = wrap_index(y0 + 1, self.height, wrap_t);
                let top = self.texel(xa, ya) * (1.0 - fx) + self.texel(xb, ya) * fx;
                let bottom = self.texel(xa, yb) * (1.0 - fx) + self.texel(xb, yb) * fx;
                top * (1.0 - fy) + bottom * fy
            }
        }
    }
}

/// The UV a texture reference looks up: its UV set (`uv` holds `[TEXCOORD_0, TEXCOORD_1]`),
/// then its `KHR_texture_transform` if any ([`crate::scene::UvTransform`]).
#[inline]
pub fn ref_uv(r: &TextureRef, uv: [Vec2; 2]) -> Vec2 {
    let uv = if r.tex_coord == 1 { uv[1] } else { uv[0] };
    match &r.transform {
        Some(t) => t.apply(uv),
        None => uv,
    }
}

/// Samples a material's texture reference at [`ref_uv`]; a reference to a missing texture
/// yields opaque white.
pub fn sample_ref(textures: &[Texture], r: &TextureRef, uv: [Vec2; 2]) -> Vec4 {
    let Some(tex) = textures.get(r.texture as usize) else { return Vec4::ONE };
    tex.sample(ref_uv(r, uv), r.wrap_s, r.wrap_t, r.filter)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 2×2 texture: top row red, green; bottom row blue, white.
    fn checker() -> Texture {
        Texture {
            width: 2,
            height: 2,
            texels: vec![
                Vec4::new(1.0, 0.0, 0.0, 1.0),
                Vec4::new(0.0, 1.0, 0.0, 1.0),
                Vec4::new(0.0, 0.0, 1.0, 1.0),
                Vec4::new(1.0, 1.0, 1.0, 1.0),
            ],
        }
    }

    #[test]
    fn floor_i64_is_floor() {
        for x in [0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 2.999_999, -2.000_001, 1e15, -1e15, 123_456.75, -7.0] {
            assert_eq!(floor_i64(x), x.floor() as i64, "{x}");
        }
    }

    #[test]
    fn wrap_modes_match_definitions() {
        assert_eq!((-1..5).map(|i| wrap_index(i, 3, Wrap::Repeat)).collect::<Vec<_>>(), vec![2, 0, 1, 2, 0, 1]);
        assert_eq!((-1..5).map(|i| wrap_index(i, 3, Wrap::ClampToEdge)).collect::<Vec<_>>(), vec![0, 0, 1, 2, 2, 2]);
        assert_eq!((-3..7).map(|i| wrap_index(i, 3, Wrap::MirroredRepeat)).collect::<Vec<_>>(), vec![2, 1, 0, 0, 1, 2, 2, 1, 0, 0]);
    }

    #[test]
    fn nearest_uses_top_left_origin() {
        let t = checker();
        let s = |u, v| t.sample(Vec2::new(u, v), Wrap::Repeat, Wrap::Repeat, Filter::Nearest);
        assert_eq!(s(0.25, 0.25), Vec4::new(1.0, 0.0, 0.0, 1.0)); // top-left: red
        assert_eq!(s(0.75, 0.25), Vec4::new(0.0, 1.0, 0.0, 1.0)); // top-right: green
        assert_eq!(s(0.25, 0.75), Vec4::new(0.0, 0.0, 1.0, 1.0)); // bottom-left: blue
        assert_eq!(s(1.25, -0.25), Vec4::new(0.0, 0.0, 1.0, 1.0)); // repeat
    }

    #[test]
    fn bilinear_is_exact_at_centres_and_midpoints() {
        let t = checker();
        let s = |u, v, w| t.sample(Vec2::new(u, v), w, w, Filter::Linear);
        assert!((s(0.25, 0.25, Wrap::ClampToEdge) - Vec4::new(1.0, 0.0, 0.0, 1.0)).length() < 1e-6);
        // Centre of the image: average of all four texels.
        assert!((s(0.5, 0.5, Wrap::ClampToEdge) - Vec4::new(0.5, 0.5, 0.5, 1.0)).length() < 1e-6);
        // At u = 0 with repeat, half left column + half right column (top row).
        assert!((s(0.0, 0.25, Wrap::Repeat) - Vec4::new(0.5, 0.5, 0.0, 1.0)).length() < 1e-6);
        // With clamp, u = 0 is the left texel.
        assert!((s(0.0, 0.25, Wrap::ClampToEdge) - Vec4::new(1.0, 0.0, 0.0, 1.0)).length() < 1e-6);
        // Empty texture is neutral white, NaN uv too.
        let empty = Texture { width: 0, height: 0, texels: vec![] };
        assert_eq!(empty.sample(Vec2::ZERO, Wrap::Repeat, Wrap::Repeat, Filter::Linear), Vec4::ONE);
        assert_eq!(t.sample(Vec2::NAN, Wrap::Repeat, Wrap::Repeat, Filter::Linear), Vec4::ONE);
    }

    #[test]
    fn texture_transform_samples_the_hand_computed_texel() {
        use crate::scene::UvTransform;
        // 4×4 texture whose texel (x, y) stores (x, y) in R, G.
        let t = Texture {
            width: 4,
            height: 4,
            texels: (0..16).map(|i| Vec4::new((i % 4) as f32, (i / 4) as f32, 0.0, 1.0)).collect(),
        };
        let xf = UvTransform::new(Vec2::new(0.5, 0.25), std::f32::consts::FRAC_PI_2, Vec2::new(2.0, 0.5));
        // The spec's T·R·S by hand at uv = (0.3, 0.1): u' = 0·2·0.3 + 1·0.5·0.1 + 0.5 = 0.55,
        // v' = −1·2·0.3 + 0·0.5·0.1 + 0.25 = −0.35 (repeat: 0.65) → texel (2, 2).
        let uv = xf.apply(Vec2::new(0.3, 0.1));
        assert!((uv - Vec2::new(0.55, -0.35)).length() < 1e-6, "{uv}");
        // Pure rotation by +90°: (1, 0) → (0, −1), (0, 1) → (1, 0).
        let r = UvTransform::new(Vec2::ZERO, std::f32::consts::FRAC_PI_2, Vec2::ONE);
        assert!((r.apply(Vec2::X) - Vec2::new(0.0, -1.0)).length() < 1e-6);
        assert!((r.apply(Vec2::Y) - Vec2::X).length() < 1e-6);
        // The reference reads TEXCOORD_1 (the extension's texCoord override resolved at import).
        let r1 = TextureRef { texture: 0, tex_coord: 1, wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat, filter: Filter::Nearest, transform: Some(xf) };
        let uvs = [Vec2::new(0.9, 0.9), Vec2::new(0.3, 0.1)];
        assert_eq!(sample_ref(std::slice::from_ref(&t), &r1, uvs), Vec4::new(2.0, 2.0, 0.0, 1.0));
        // Without the transform: TEXCOORD_1 as is, texel (1, 0); with set 0: texel (3, 3).
        assert_eq!(sample_ref(std::slice::from_ref(&t), &TextureRef { transform: None, ..r1 }, uvs), Vec4::new(1.0, 0.0, 0.0, 1.0));
        assert_eq!(sample_ref(std::slice::from_ref(&t), &TextureRef { transform: None, tex_coord: 0, ..r1 }, uvs), Vec4::new(3.0, 3.0, 0.0, 1.0));
    }
}
