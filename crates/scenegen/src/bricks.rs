//! The `bricks` scene: a construction-toy town on a studded base plate, the hard case for a
//! radiance field (hundreds of small parts, studs a few pixels wide, seams between parts,
//! sub-pixel metal rods, fine printed detail, saturated glossy plastic).
//!
//! Dimensions follow the toy's proportions at a stud pitch `P` = 6 cm: a brick is `1.2 P` high,
//! a plate `0.4 P`; studs have radius `0.3 P` and height `0.21 P`; neighbouring parts leave a
//! seam of `2 × 0.8 mm`. Parts are placed on a stud grid of 24 × 24 cells (the base plate,
//! 1.44 m square, top face at `y = 0`) with an occupancy map, so no two parts overlap; each
//! part stands on the base plate or on a part below it.
//!
//! Everything is a pure function of a fixed seed (SplitMix64), so the output is byte-identical
//! from run to run. Each distinct part shape is one glTF mesh, instanced by nodes.

use std::collections::BTreeMap;
use std::f32::consts::FRAC_PI_2;

use glam::{Mat4, Quat, Vec3};

use crate::SceneGenError;
use crate::builder::{GeometryId, Light, Material, MaterialId, SceneBuilder, Transform};
use crate::mesh::Mesh;
use crate::texture::{checker, stripes};

/// Stud pitch, m.
const PITCH: f32 = 0.06;
/// Plate height, m; a brick is three plates.
const PLATE: f32 = 0.4 * PITCH;
/// Stud radius and height, m.
const STUD_R: f32 = 0.3 * PITCH;
const STUD_H: f32 = 0.21 * PITCH;
/// Clearance on each side of a part, m (a seam of twice this between neighbours).
const GAP: f32 = 0.0008;
/// Segments around a stud.
const STUD_SEGMENTS: u32 = 12;
/// Base plate size, studs.
const GRID: i32 = 24;
/// Base plate thickness, m.
const BASE_THICKNESS: f32 = 0.004;
/// Metal rod radius, m: thinner than a pixel at 200x200.
const ROD_R: f32 = 0.004;

/// SplitMix64: a small deterministic generator.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// A whole number in `0..n`.
    fn below(&mut self, n: u32) -> u32 {
        (self.next() % u64::from(n)) as u32
    }
}

/// The shape of a rectangular part: footprint in studs along its own x and z, height in
/// plates, studded top or a smooth tile.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
struct Shape {
    w: u32,
    l: u32,
    plates: u32,
    studs: bool,
}

/// A part's mesh: origin at the centre of its footprint, bottom at `y = 0`, sides inset by
/// [`GAP`].
fn part_mesh(s: Shape) -> Mesh {
    let h = s.plates as f32 * PLATE;
    let (hx, hz) = (s.w as f32 * PITCH / 2.0 - GAP, s.l as f32 * PITCH / 2.0 - GAP);
    let mut m = Mesh::cuboid(Vec3::new(hx, h / 2.0, hz)).transformed(&Mat4::from_translation(Vec3::Y * (h / 2.0)));
    if s.studs {
        for i in 0..s.w {
            for j in 0..s.l {
                let at = Vec3::new((i as f32 + 0.5) * PITCH - s.w as f32 * PITCH / 2.0, h, (j as f32 + 0.5) * PITCH - s.l as f32 * PITCH / 2.0);
                m.append(&Mesh::cylinder(STUD_R, STUD_H, STUD_SEGMENTS).transformed(&Mat4::from_translation(at)));
            }
        }
    }
    m
}

/// The scene under construction: the builder, the part shapes made so far and the occupied
/// cells (`x`, `z`, plate level).
struct Town {
    s: SceneBuilder,
    shapes: BTreeMap<Shape, GeometryId>,
    occupied: BTreeMap<(i32, i32), Vec<(u32, u32)>>,
    parts: usize,
}

impl Town {
    /// The base of a part's footprint cells: the lowest level at which all are free from
    /// `plates` upwards, i.e. the top of what lies below.
    fn top(&self, x: i32, z: i32, w: u32, l: u32) -> u32 {
        let mut top = 0;
        for i in x..x + w as i32 {
            for j in z..z + l as i32 {
                for &(_, hi) in self.occupied.get(&(i, j)).into_iter().flatten() {
                    top = top.max(hi);
                }
            }
        }
        top
    }

    fn free(&self, x: i32, z: i32, w: u32, l: u32, level: u32, plates: u32) -> bool {
        if x < 0 || z < 0 || x + w as i32 > GRID || z + l as i32 > GRID {
            return false;
        }
        (x..x + w as i32).all(|i| {
            (z..z + l as i32).all(|j| self.occupied.get(&(i, j)).into_iter().flatten().all(|&(lo, hi)| hi <= level || lo >= level + plates))
        })
    }

    /// Places a part covering cells `x..x+w`, `z..z+l` from plate level `level`; a footprint
    /// with `w > l` uses the `l × w` shape turned a quarter. Refuses an overlap (a bug in the
    /// layout, not an input).
    fn place(&mut self, name: &str, (x, z, level): (i32, i32, u32), (w, l, plates): (u32, u32, u32), studs: bool, material: MaterialId) -> Result<(), SceneGenError> {
        if !self.free(x, z, w, l, level, plates) {
            return Err(SceneGenError::InvalidMesh { name: name.into(), reason: format!("overlaps another part at ({x}, {z}) level {level}") });
        }
        for i in x..x + w as i32 {
            for j in z..z + l as i32 {
                self.occupied.entry((i, j)).or_default().push((level, level + plates));
            }
        }
        let turned = w > l;
        let shape = Shape { w: w.min(l), l: w.max(l), plates, studs };
        let geometry = match self.shapes.get(&shape) {
            Some(g) => *g,
            None => {
                let g = self.s.add_geometry(&format!("part_{}x{}x{}{}", shape.w, shape.l, shape.plates, if studs { "" } else { "_tile" }), part_mesh(shape))?;
                self.shapes.insert(shape, g);
                g
            }
        };
        let centre = Vec3::new((x as f32 + w as f32 / 2.0) * PITCH - GRID as f32 * PITCH / 2.0, level as f32 * PLATE, (z as f32 + l as f32 / 2.0) * PITCH - GRID as f32 * PITCH / 2.0);
        let rotation = if turned { Quat::from_rotation_y(FRAC_PI_2) } else { Quat::IDENTITY };
        self.s.add_instance(&format!("{name}_{}", self.parts), geometry, material, Transform::from_translation_rotation(centre, rotation))?;
        self.parts += 1;
        Ok(())
    }

    /// A world point at cell corner `(x, z)` and plate level `level`.
    fn at(x: f32, z: f32, level: f32) -> Vec3 {
        Vec3::new(x * PITCH - GRID as f32 * PITCH / 2.0, level * PLATE, z * PITCH - GRID as f32 * PITCH / 2.0)
    }
}

/// Bricks along a wall line of `n` cells starting at `(x, z)` in direction `(dx, dz)`, one
/// course at `level`: lengths of 4 from `offset`, shorter where the line or an opening ends
/// them; `open(k)` says whether cell `k` of the line is an opening.
#[allow(clippy::too_many_arguments)]
fn course(t: &mut Town, (x, z): (i32, i32), (dx, dz): (i32, i32), n: i32, offset: i32, level: u32, open: &dyn Fn(i32) -> bool, material: MaterialId) -> Result<(), SceneGenError> {
    let mut k = 0;
    while k < n {
        if open(k) {
            k += 1;
            continue;
        }
        let stop = if k == 0 && offset > 0 { offset } else { 4 };
        let mut len = 0;
        while len < stop && k + len < n && !open(k + len) {
            len += 1;
        }
        let (cx, cz) = (x + dx * k, z + dz * k);
        let (w, l) = if dx != 0 { (len as u32, 1) } else { (1, len as u32) };
        t.place("wall", (cx, cz, level), (w, l, 3), true, material)?;
        k += len;
    }
    Ok(())
}

/// Builds the scene (see the module docs and `scenes/README.md`).
pub(crate) fn bricks() -> Result<SceneBuilder, SceneGenError> {
    build().map(|(s, _)| s)
}

/// The scene and its number of parts (the base plate's sections not counted).
fn build() -> Result<(SceneBuilder, usize), SceneGenError> {
    let mut s = SceneBuilder::new("bricks");
    let plastic = |s: &mut SceneBuilder, name: &str, c: [f32; 3]| s.add_material(Material::diffuse(name, c).with_metallic_roughness(0.0, 0.25));
    let red = plastic(&mut s, "red", [0.72, 0.03, 0.03])?;
    let blue = plastic(&mut s, "blue", [0.02, 0.16, 0.62])?;
    let yellow = plastic(&mut s, "yellow", [0.92, 0.68, 0.02])?;
    let green = plastic(&mut s, "green", [0.03, 0.42, 0.08])?;
    let white = plastic(&mut s, "white", [0.85, 0.85, 0.82])?;
    let black = plastic(&mut s, "black", [0.02, 0.02, 0.02])?;
    let orange = plastic(&mut s, "orange", [0.9, 0.3, 0.02])?;
    let brown = plastic(&mut s, "brown", [0.25, 0.1, 0.03])?;
    let dark_red = plastic(&mut s, "dark_red", [0.35, 0.02, 0.02])?;
    let base = s.add_material(Material::diffuse("base_plate", [0.2, 0.45, 0.15]).with_metallic_roughness(0.0, 0.35))?;
    let rubber = s.add_material(Material::diffuse("rubber", [0.03, 0.03, 0.03]).with_metallic_roughness(0.0, 0.7))?;
    let metal = s.add_material(Material::diffuse("metal", [0.8, 0.8, 0.82]).with_metallic_roughness(1.0, 0.3))?;
    let grille_tex = s.add_texture("print_grille", stripes(64, 16, [20, 20, 20], [220, 220, 210]))?;
    let sign_tex = s.add_texture("print_sign", checker(64, 8, [200, 20, 20], [240, 240, 240]))?;
    let grille = s.add_material(Material::diffuse("print_grille", [1.0; 3]).with_texture(grille_tex).with_metallic_roughness(0.0, 0.25))?;
    let sign = s.add_material(Material::diffuse("print_sign", [1.0; 3]).with_texture(sign_tex).with_metallic_roughness(0.0, 0.25))?;

    // The base plate: 3 x 3 sections of 8 x 8 studs, flush, 4 mm thick with its top at y = 0
    // (thin, as the toy's are, so the renderer's rig sees it as a ground).
    let mut section = Mesh::cuboid(Vec3::new(4.0 * PITCH, BASE_THICKNESS / 2.0, 4.0 * PITCH)).transformed(&Mat4::from_translation(Vec3::Y * (-BASE_THICKNESS / 2.0)));
    for i in 0..8 {
        for j in 0..8 {
            let at = Vec3::new((i as f32 - 3.5) * PITCH, 0.0, (j as f32 - 3.5) * PITCH);
            section.append(&Mesh::cylinder(STUD_R, STUD_H, STUD_SEGMENTS).transformed(&Mat4::from_translation(at)));
        }
    }
    let section = s.add_geometry("base_section", section)?;
    for i in 0..3 {
        for j in 0..3 {
            let c = Town::at(8.0 * i as f32 + 4.0, 8.0 * j as f32 + 4.0, 0.0);
            s.add_instance(&format!("base_{i}_{j}"), section, base, Transform::from_translation(c))?;
        }
    }
    let mut t = Town { s, shapes: BTreeMap::new(), occupied: BTreeMap::new(), parts: 0 };

    // A house, 10 x 8 studs, six courses in running bond, with a door and windows; a roof of
    // plates, a printed sign and a chimney.
    let (hx, hz, hw, hl) = (2, 2, 10, 8);
    let colours = [red, white, red, white, red, red];
    for c in 0..6u32 {
        let level = 3 * c;
        let offset = if c % 2 == 0 { 0 } else { 2 };
        let front_open = move |k: i32| (c < 4 && (4..6).contains(&k)) || ((2..4).contains(&c) && ((1..3).contains(&k) || (7..9).contains(&k)));
        let back_open = move |k: i32| (2..4).contains(&c) && (3..7).contains(&k);
        let side_open = move |k: i32| (2..4).contains(&c) && (2..4).contains(&k);
        course(&mut t, (hx, hz), (1, 0), hw, offset, level, &front_open, colours[c as usize])?;
        course(&mut t, (hx, hz + hl - 1), (1, 0), hw, (offset + 1) % 4, level, &back_open, colours[c as usize])?;
        course(&mut t, (hx, hz + 1), (0, 1), hl - 2, offset, level, &side_open, colours[c as usize])?;
        course(&mut t, (hx + hw - 1, hz + 1), (0, 1), hl - 2, 4 - offset, level, &side_open, colours[c as usize])?;
    }
    for (k, (w, l)) in [(2u32, 8u32), (2, 8), (2, 8), (2, 8), (2, 8)].iter().enumerate() {
        t.place("roof", (hx + 2 * k as i32, hz, 18), (*w, *l, 1), true, dark_red)?;
    }
    for (k, w) in [4u32, 4].iter().enumerate() {
        t.place("roof_top", (hx + 1 + 4 * k as i32, hz + 1, 19), (*w, 6, 1), true, dark_red)?;
    }
    for level in [20, 23, 26] {
        t.place("chimney", (hx + 7, hz + 5, level), (2, 2, 3), true, white)?;
    }
    t.place("sign", (hx + 3, hz - 1, 0), (4, 1, 1), false, sign)?;

    // A car: a chassis plate on two metal axles with wheels, a cab, a printed grille.
    let (cx, cz) = (15, 2);
    let wheel_y = 0.045;
    for (k, az) in [(0, cz as f32 + 1.5), (1, cz as f32 + 7.5)] {
        let a = Town::at(cx as f32 - 0.6, az, 0.0) + Vec3::Y * wheel_y;
        let b = Town::at(cx as f32 + 4.6, az, 0.0) + Vec3::Y * wheel_y;
        t.s.add_mesh(&format!("axle_{k}"), Mesh::cylinder_between(a, b, ROD_R, 8), metal, Transform::IDENTITY)?;
        for (side, x) in [(0, cx as f32 - 0.5), (1, cx as f32 + 4.0)] {
            let p = Town::at(x, az, 0.0) + Vec3::Y * wheel_y;
            let wheel = Mesh::cylinder_between(p, p + Vec3::X * 0.03, 0.045, 24);
            t.s.add_mesh(&format!("wheel_{k}_{side}"), wheel, rubber, Transform::IDENTITY)?;
            let hub = Mesh::cylinder_between(p - Vec3::X * 0.002, p + Vec3::X * 0.032, 0.015, 12);
            t.s.add_mesh(&format!("hub_{k}_{side}"), hub, metal, Transform::IDENTITY)?;
        }
    }
    // The chassis rests on the axles: its cells are marked from level 3 (0.072 m > wheel top).
    t.place("chassis", (cx, cz, 3), (4, 10, 1), true, blue)?;
    t.place("bumper", (cx, cz - 1, 3), (4, 1, 1), false, grille)?;
    t.place("hood", (cx, cz, 4), (4, 3, 3), true, yellow)?;
    for (x, z, w, l) in [(0, 3, 1, 4), (3, 3, 1, 4), (1, 6, 2, 1)] {
        t.place("cab", (cx + x, cz + z, 4), (w, l, 3), true, yellow)?;
        t.place("cab", (cx + x, cz + z, 7), (w, l, 3), true, white)?;
    }
    t.place("cab_roof", (cx, cz + 3, 10), (4, 4, 1), true, black)?;
    t.place("bed", (cx, cz + 7, 4), (4, 3, 1), false, orange)?;

    // A tree: a trunk of 1 x 1 bricks and a crown of plates in a rough ball.
    let (tx, tz) = (4, 15);
    for k in 0..5 {
        t.place("trunk", (tx + 2, tz + 2, 3 * k), (1, 1, 3), true, brown)?;
    }
    let mut rng = Rng(0xB41C_5EED);
    for level in (15..30).step_by(1) {
        let r = 2.5 - ((level as f32 - 21.0) / 4.5).powi(2) * 2.0;
        for _ in 0..6 {
            let (w, l) = [(1u32, 1u32), (1, 2), (2, 1), (2, 2)][rng.below(4) as usize];
            let x = tx + 2 + rng.below(5) as i32 - 2;
            let z = tz + 2 + rng.below(5) as i32 - 2;
            let d = ((x - tx - 2) as f32).hypot((z - tz - 2) as f32);
            if d <= r && t.free(x, z, w, l, level, 1) {
                t.place("leaves", (x, z, level), (w, l, 1), true, green)?;
            }
        }
    }

    // A tower of 2 x 2 bricks with a metal antenna.
    let (wx, wz) = (19, 15);
    for k in 0..8 {
        t.place("tower", (wx, wz, 3 * k), (2, 2, 3), true, if k % 2 == 0 { blue } else { white })?;
    }
    let top = Town::at(wx as f32 + 1.0, wz as f32 + 1.0, 24.0) + Vec3::Y * STUD_H;
    t.s.add_mesh("antenna", Mesh::cylinder_between(top, top + Vec3::Y * 0.22, 0.003, 8), metal, Transform::IDENTITY)?;

    // A fence of metal posts on round-less 1 x 1 plates, with two rails.
    let fz = 22;
    for k in 0..11 {
        let x = 1 + 2 * k;
        t.place("post_base", (x, fz, 0), (1, 1, 1), true, black)?;
        let p = Town::at(x as f32 + 0.5, fz as f32 + 0.5, 1.0);
        t.s.add_mesh(&format!("post_{k}"), Mesh::cylinder_between(p, p + Vec3::Y * 0.16, ROD_R, 8), metal, Transform::IDENTITY)?;
    }
    for (k, y) in [(0, 0.07), (1, 0.14)] {
        let a = Town::at(1.5, fz as f32 + 0.5, 1.0) + Vec3::Y * y;
        let b = Town::at(21.5, fz as f32 + 0.5, 1.0) + Vec3::Y * y;
        t.s.add_mesh(&format!("rail_{k}"), Mesh::cylinder_between(a, b, 0.003, 8), metal, Transform::IDENTITY)?;
    }

    // Loose parts: random shapes and colours on the free cells, stacked up to three bricks high.
    let palette = [red, blue, yellow, green, white, black, orange];
    let sizes = [(1u32, 1u32), (1, 2), (1, 3), (1, 4), (2, 2), (2, 3), (2, 4), (1, 6), (2, 6)];
    let mut placed = 0;
    for _ in 0..20_000 {
        if placed == 320 {
            break;
        }
        let (a, b) = sizes[rng.below(sizes.len() as u32) as usize];
        let (w, l) = if rng.below(2) == 0 { (a, b) } else { (b, a) };
        let x = rng.below((GRID - w as i32 + 1) as u32) as i32;
        let z = rng.below((GRID - l as i32 + 1) as u32) as i32;
        let plates = if rng.below(3) == 0 { 1 } else { 3 };
        let level = t.top(x, z, w, l);
        if level > 9 {
            continue;
        }
        // Keep the structures' own cells clear (they are taller than 6 plates near their
        // bases only where parts stand; their footprints are excluded explicitly).
        let near = |(x0, z0, x1, z1): (i32, i32, i32, i32)| x < x1 && x + w as i32 > x0 && z < z1 && z + l as i32 > z0;
        if [(hx - 1, hz - 1, hx + hw + 1, hz + hl + 1), (cx - 2, cz - 2, cx + 6, cz + 11), (tx, tz, tx + 5, tz + 5), (wx - 1, wz - 1, wx + 3, wz + 3), (0, fz - 1, GRID, fz + 2)].into_iter().any(near) {
            continue;
        }
        if !t.free(x, z, w, l, level, plates) {
            continue;
        }
        let material = palette[rng.below(palette.len() as u32) as usize];
        t.place(if plates == 1 { "plate" } else { "brick" }, (x, z, level), (w, l, plates), rng.below(8) != 0, material)?;
        placed += 1;
    }

    let parts = t.parts;
    let mut s = t.s;
    s.add_light("sun", Light::Directional { color: [1.0, 0.97, 0.92], illuminance: 2.5 }, Transform::look_at(Vec3::new(2.0, 4.0, 3.0).normalize() * 10.0, Vec3::ZERO, Vec3::Y))?;
    s.add_light("fill", Light::Point { color: [0.9, 0.95, 1.0], intensity: 5.0 }, Transform::from_translation(Vec3::new(-1.2, 1.8, 1.0)))?;
    Ok((s, parts))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Hundreds of parts, none overlapping (`place` refuses overlaps), with the thin rods and
    /// printed tiles present, within a bounding radius of about a metre.
    #[test]
    fn the_town_has_hundreds_of_parts_and_fits_the_camera_rig() {
        let (s, parts) = build().unwrap();
        assert!((300..3000).contains(&parts), "{parts} parts");
        let (lo, hi) = s.bounds().unwrap();
        let radius = ((hi - lo) / 2.0).length();
        assert!((0.9..1.4).contains(&radius), "bounding radius {radius}");
        assert!(lo.y > -0.03 && hi.y < 1.0, "{lo} {hi}");
    }
}
