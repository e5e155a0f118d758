//! The built-in scenes, each a function returning a [`SceneBuilder`], and the
//! text of `scenes/README.md`.
//!
//! Light levels are chosen so that a diffuse surface of albedo 0.5 renders
//! with linear radiance of roughly 0.2–0.8 at exposure 1: a point light of
//! `I` cd at `r` m gives irradiance `I / r²` (times the cosine), a sun of `E`
//! lux gives `E · cos θ`, and a Lambertian surface reflects `albedo · E / π`.

use std::f32::consts::PI;

use glam::{Quat, Vec2, Vec3};

use crate::SceneGenError;
use crate::builder::{Glass, Light, Material, PerspectiveCamera, SceneBuilder, Transform};
use crate::mesh::Mesh;
use crate::texture::{Bumps, bump_normal_map, checker, stripes};

/// One built-in scene: its name, what it tests, and how to build it.
struct SceneDef {
    name: &'static str,
    description: &'static str,
    build: fn() -> Result<SceneBuilder, SceneGenError>,
}

const SCENES: &[SceneDef] = &[
    SceneDef {
        name: "cornell",
        description: "Closed Cornell-like room (2 m wide, 2 m high, 3.8 m deep: x ∈ [-1, 1], y ∈ [0, 2], z ∈ [-1, 2.8]): \
            white floor, ceiling, back and front walls, red left wall, green right wall, a short box and a tall \
            box rotated about +Y. Tests global illumination in a closed diffuse room and an area light: the only \
            light is an emissive 0.5 m × 0.4 m quad 2 cm below the ceiling, facing down, radiance 30 × (1, 0.9, 0.75) \
            (direct irradiance ≈ 1.5 at the floor below it). One glTF perspective camera (yfov 45°) inside the \
            room, 10 cm from the front wall at (0, 1, 2.7), looks at the boxes; cameras must stay inside the room.",
        build: cornell,
    },
    SceneDef {
        name: "tabletop",
        description: "The default demo scene, object-centric like the NeRF synthetic scenes (≈ 4.5k triangles, \
            within a 1 m radius): a checker-textured ground disc (radius 1 m, 12.5 cm cells), a checker-textured box with a small sphere on \
            it, a latitude-striped sphere, a torus with per-vertex colours (COLOR_0) and a cylinder vase. Tests \
            textures, vertex colours, curved surfaces and occlusion. Lights: a directional sun of 2.5 lux \
            (elevation ≈ 48°) and a 5 cd point light ≈ 2.4 m from the centre. No camera: the renderer places \
            cameras on a hemisphere around the bounds.",
        build: tabletop,
    },
    SceneDef {
        name: "thin",
        description: "Thin structures on a 0.9 m base disc (bounding radius ≈ 1.3 m, so a pixel at 200×200 \
            covers ≈ 1.6 cm when the bounding sphere fills a 40° view): a wire-frame cube of 1.8 cm wires, a fence \
            lattice of 2.4 cm wires, a helical spring of 1.6 cm wire, and a plant whose stem carries thin \
            double-sided leaf quads. Features are 1–2 pixels wide: tests aliasing, thin-structure recovery and \
            depth at silhouettes. Lights: a 2.5 lux sun and a 4 cd point light. No camera.",
        build: thin,
    },
    SceneDef {
        name: "deep",
        description: "A colonnade receding along −Z: a 26 m checker-textured floor, two rows of ten pillars \
            with lintels, a back wall 20.8 m from the camera and a lamp globe 0.5 m in front of it, so the depth \
            range seen from the glTF camera exceeds 20:1 (tested ≥ 20). Tests unbounded-ish depth \
            parameterisation and near/far sampling. One glTF perspective camera (yfov 50°) at 1.6 m height \
            looks down the colonnade. Lights: a 2 lux sun at 45° elevation and three 3 cd point lights 2.5 m \
            above the floor along the axis. Open sky (no hit → depth 0).",
        build: deep,
    },
    SceneDef {
        name: "materials",
        description: "For physically based materials: two rows of five spheres (radius 0.2 m) with roughness \
            0.05, 0.25, 0.5, 0.75, 1 — the front row dielectric red (metallic 0), the back row gold (metallic \
            1) — a box with a tangent-space bump normal map (with TANGENT attributes), on a checker-textured \
            3.2 m square ground plane. Lights: a 2 lux sun, a 3 cd point light and a 15 cd spot light (inner 12°, \
            outer 20°) aimed at the normal-mapped box. Lambertian renders see only base colours. No camera.",
        build: materials,
    },
    SceneDef {
        name: "bricks",
        description: "The hard scene: a construction-toy town of about 440 parts on a 24 × 24-stud base plate \
            (1.44 m square, stud pitch 6 cm, bounding radius ≈ 1 m): a house of bricks in running bond with a door, \
            windows, a plate roof and a chimney, a car on metal axles with rubber wheels and a printed grille, a \
            tree of plates, a tower of 2 × 2 bricks with a 3 mm metal antenna, a fence of 4 mm metal posts and \
            3 mm rails, and about 280 loose bricks and plates stacked up to three high. Studs (3.6 cm wide) span \
            2–3 pixels at 200 × 200, the seams between parts (1.6 mm) and the rods are below a pixel, the printed \
            tiles carry 16 stripes or an 8 × 8 checker, and the plastic is saturated and glossy (roughness 0.25). \
            Tests what users' own scenes ask of a radiance field: many small parts, thin structures, fine \
            texture and glossy highlights. Lights: a 2.5 lux sun and a 5 cd point light. No camera; no ground \
            beyond the base plate.",
        build: crate::bricks::bricks,
    },
    SceneDef {
        name: "skinned",
        description: "A skinned mesh at its default pose: a tube (radius 0.09 m, 1.2 m tall, 24 rings of 24 \
            segments, closed top) bound to a chain of three joints 0.4 m apart under an armature node turned 30° \
            about +Y; the joints bend it by 35° and 40° about their +Z, and the last one squashes it to 70 % \
            along its Z, so positions, normals and bounds all differ from the bind pose (the straight tube). \
            Each vertex blends the two nearest joints linearly along the tube (JOINTS_0 / WEIGHTS_0, inverse \
            bind matrices the inverse bind-pose joint transforms). A grey box stands beside it on a 1.2 m \
            ground disc. Lights: a 2.5 lux sun and a 4 cd point light. No camera.",
        build: skinned,
    },
    SceneDef {
        name: "morphed",
        description: "Morph targets at their default weights: two spheres (radius 0.3 m) share a mesh with two \
            targets, `stretch` (positions scaled by (1.4, 0.75, 1) about the centre, with normal \
            displacements) and `bump` (the cap above 53° latitude pushed out along the normal by up to 0.2 m; \
            no normal displacements, written as a sparse accessor). The left sphere shows the mesh's weights \
            (0.6, 0.8), the right one its node's (1, 0). On a 1.2 m ground disc; lights: a 2.5 lux sun and a \
            4 cd point light. No camera.",
        build: morphed,
    },
    SceneDef {
        name: "glass",
        description: "Glass among opaque objects, the hard case for radiance fields (refraction, view-dependent \
            transmission): on a checker-textured 2.4 m square ground, a smooth glass sphere (radius 0.25 m, ior \
            1.5, KHR_materials_volume with green-tinted Beer–Lambert absorption: attenuation colour (0.6, 0.9, \
            0.7) at 0.5 m), a rough glass block (roughness 0.3, ior 1.5, clear volume), a red diffuse box and a \
            gold sphere behind them. Lights: a 2.5 lux sun; shadow rays stop at glass, so the sun casts a \
            full shadow behind it, and what lights the scene through the glass is the environment (the \
            render's, found by BSDF sampling). No camera.",
        build: glass,
    },
    SceneDef {
        name: "coated",
        description: "Clear coats and sheens (KHR_materials_clearcoat, KHR_materials_sheen) on coloured bases: on a \
            grey 2.4 m square ground, a back row of three spheres (radius 0.2 m) with a full clear coat — a red \
            rough plastic under a smooth bumpy coat (roughness 0.05, a clearcoatNormalTexture of round bumps \
            over the unmapped base; the sphere carries TANGENT), a blue one under a rough coat (0.4) and a gold \
            metal under a half coat (0.5, roughness 0.1) — and a front row of three sheen spheres — a \
            velvet (base (0.05, 0.01, 0.015), sheen (1, 0.6, 0.6), roughness 0.3), a near-black base with a blue \
            sheen (0.3, 0.5, 1) at roughness 0.6, and a green plastic with both a white sheen (0.5) and a clear coat (0.6, roughness \
            0.2). Lights: a 2.5 lux sun and a 4 cd point light. No camera.",
        build: coated,
    },
];

/// Names of the built-in scenes, in the order [`crate::write_all`] writes them.
pub fn scene_names() -> &'static [&'static str] {
    const NAMES: &[&str] = &["cornell", "tabletop", "thin", "deep", "materials", "bricks", "skinned", "morphed", "glass", "coated"];
    NAMES
}

/// One paragraph saying what the named scene tests, its units and its lights.
pub fn scene_description(name: &str) -> Option<&'static str> {
    SCENES
        .iter()
        .find(|s| s.name == name)
        .map(|s| s.description)
}

/// Build the named built-in scene in memory (to write it, or to inspect it in tests).
pub fn build_scene(name: &str) -> Result<SceneBuilder, SceneGenError> {
    let def =
        SCENES
            .iter()
            .find(|s| s.name == name)
            .ok_or_else(|| SceneGenError::UnknownScene {
                name: name.to_string(),
                known: scene_names().join(", "),
            })?;
    (def.build)()
}

/// Spheres per side of the [`stress`] scene's grid.
const STRESS_GRID: u32 = 4;

/// A stress scene for the renderer's scaling benchmark (not one of the committed scenes: at a
/// million triangles its buffer is tens of megabytes): a 4 m square floor under a 4 × 4 grid of
/// UV spheres (radius 0.2 m, 0.6 m apart; grey, roughness 0.5), each tessellated with
/// `2r` segments and `r` rings, `r` chosen so that the scene has about `triangles` triangles in
/// all (at least 16 × 12). Lights: a 2.5 lux sun and a 5 cd point light. The picture hardly
/// changes with the tessellation, so what a render costs against `triangles` is what the
/// acceleration structure costs.
pub fn stress(triangles: u32) -> Result<SceneBuilder, SceneGenError> {
    let mut s = SceneBuilder::new(&format!("stress_{triangles}"));
    let floor = s.add_material(Material::diffuse("floor", [0.6, 0.6, 0.6]))?;
    let grey = s.add_material(
        Material::diffuse("spheres", [0.7, 0.5, 0.3]).with_metallic_roughness(0.0, 0.5),
    )?;
    s.add_mesh("floor", Mesh::quad(Vec2::splat(4.0), 1.0), floor, Transform::IDENTITY)?;
    // A sphere of `2r` segments and `r` rings has 2r·(2r − 2) = 4r² − 4r triangles.
    let per_sphere = (triangles.saturating_sub(2) / (STRESS_GRID * STRESS_GRID)) as f64;
    let rings = ((1.0 + (1.0 + per_sphere).sqrt()) / 2.0).round().max(2.0) as u32;
    let sphere = s.add_geometry("sphere", Mesh::uv_sphere(0.2, 2 * rings, rings))?;
    for i in 0..STRESS_GRID {
        for j in 0..STRESS_GRID {
            let at = |k: u32| (k as f32 - (STRESS_GRID - 1) as f32 / 2.0) * 0.6;
            let t = Transform::from_translation(Vec3::new(at(i), 0.2, at(j)));
            s.add_instance(&format!("sphere_{i}_{j}"), sphere, grey, t)?;
        }
    }
    s.add_light(
        "sun",
        Light::Directional {
            color: [1.0, 0.97, 0.92],
            illuminance: 2.5,
        },
        sun_from(Vec3::new(2.0, 4.0, 3.0)),
    )?;
    s.add_light(
        "fill",
        Light::Point {
            color: [0.9, 0.95, 1.0],
            intensity: 5.0,
        },
        Transform::from_translation(Vec3::new(-1.2, 1.8, 1.0)),
    )?;
    Ok(s)
}

/// The text of `scenes/README.md`.
pub(crate) fn readme() -> String {
    let mut s = String::from(
        "# Scenes\n\nGenerated by the `scenegen` crate (`cargo xtask gen-scenes`, or \
         `cargo run -p scenegen --example gen -- scenes`); do not edit by hand. Each scene is \
         `NAME.gltf` with `NAME.bin` and `NAME_*.png` beside it. Units are metres, glTF world \
         (right-handed, +Y up). Point and spot intensities are in candela, directional in lux; \
         a diffuse surface of albedo 0.5 renders at linear radiance ≈ 0.2–0.8.\n\n",
    );
    for def in SCENES {
        s.push_str(&format!(
            "- `{}`: {}\n",
            def.name,
            def.description
                .split_whitespace()
                .collect::<Vec<_>>()
                .join(" ")
        ));
    }
    s
}

fn deg(d: f32) -> f32 {
    d * PI / 180.0
}

fn sun_from(direction_to_sun: Vec3) -> Transform {
    Transform::look_at(direction_to_sun.normalize() * 10.0, Vec3::ZERO, Vec3::Y)
}

fn cornell() -> Result<SceneBuilder, SceneGenError> {
    let mut s = SceneBuilder::new("cornell");
    let white = s.add_material(Material::diffuse("white", [0.73, 0.73, 0.73]))?;
    let red = s.add_material(Material::diffuse("red", [0.63, 0.065, 0.05]))?;
    let green = s.add_material(Material::diffuse("green", [0.14, 0.45, 0.091]))?;
    let light = s.add_material(Material::emissive("light", [1.0, 0.9, 0.75], 30.0))?;

    let (x0, x1, y0, y1, z0, z1) = (-1.0f32, 1.0f32, 0.0f32, 2.0f32, -1.0f32, 2.8f32);
    let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    // Inward-facing walls from exact corners (counter-clockwise seen from inside).
    let floor =
        Mesh::quad_from_corners([c(x0, y0, z1), c(x1, y0, z1), c(x1, y0, z0), c(x0, y0, z0)]);
    let ceiling =
        Mesh::quad_from_corners([c(x0, y1, z0), c(x1, y1, z0), c(x1, y1, z1), c(x0, y1, z1)]);
    let back =
        Mesh::quad_from_corners([c(x0, y0, z0), c(x1, y0, z0), c(x1, y1, z0), c(x0, y1, z0)]);
    let front =
        Mesh::quad_from_corners([c(x1, y0, z1), c(x0, y0, z1), c(x0, y1, z1), c(x1, y1, z1)]);
    let left =
        Mesh::quad_from_corners([c(x0, y0, z1), c(x0, y0, z0), c(x0, y1, z0), c(x0, y1, z1)]);
    let right =
        Mesh::quad_from_corners([c(x1, y0, z0), c(x1, y0, z1), c(x1, y1, z1), c(x1, y1, z0)]);
    s.add_mesh(
        "white_walls",
        Mesh::merge([&floor, &ceiling, &back, &front]),
        white,
        Transform::IDENTITY,
    )?;
    s.add_mesh("left_wall", left, red, Transform::IDENTITY)?;
    s.add_mesh("right_wall", right, green, Transform::IDENTITY)?;

    // The area light: 0.5 m × 0.4 m, 2 cm below the ceiling, facing down.
    let ly = y1 - 0.02;
    let lamp = Mesh::quad_from_corners([
        c(-0.25, ly, -0.2),
        c(0.25, ly, -0.2),
        c(0.25, ly, 0.2),
        c(-0.25, ly, 0.2),
    ]);
    s.add_mesh("area_light", lamp, light, Transform::IDENTITY)?;

    let short = Transform::from_translation_rotation(
        Vec3::new(0.4, 0.3, 0.25),
        Quat::from_rotation_y(deg(-17.0)),
    );
    s.add_mesh("short_box", Mesh::cuboid(Vec3::splat(0.3)), white, short)?;
    let tall = Transform::from_translation_rotation(
        Vec3::new(-0.35, 0.6, -0.35),
        Quat::from_rotation_y(deg(20.0)),
    );
    s.add_mesh(
        "tall_box",
        Mesh::cuboid(Vec3::new(0.3, 0.6, 0.3)),
        white,
        tall,
    )?;

    let camera = PerspectiveCamera {
        yfov: deg(45.0),
        znear: 0.01,
        zfar: None,
        aspect_ratio: None,
    };
    s.add_camera(
        "camera",
        camera,
        Transform::look_at(c(0.0, 1.0, 2.7), c(0.0, 0.9, 0.0), Vec3::Y),
    )?;
    Ok(s)
}

/// Hue in [0, 1) to a saturated linear RGB colour.
fn hue(h: f32) -> Vec3 {
    let k = |n: f32| {
        let k = (n + h * 6.0) % 6.0;
        1.0 - (k.min(4.0 - k).clamp(0.0, 1.0))
    };
    Vec3::new(k(5.0), k(3.0), k(1.0)) * 0.8 + Vec3::splat(0.1)
}

fn tabletop() -> Result<SceneBuilder, SceneGenError> {
    let mut s = SceneBuilder::new("tabletop");
    let ground_tex = s.add_texture("ground", checker(256, 8, [200, 200, 200], [90, 90, 90]))?;
    let crate_tex = s.add_texture("crate", checker(128, 4, [230, 140, 40], [245, 230, 200]))?;
    let ball_tex = s.add_texture("ball", stripes(64, 8, [40, 90, 200], [235, 235, 235]))?;

    let ground = s.add_material(Material::diffuse("ground", [1.0; 3]).with_texture(ground_tex))?;
    let crate_mat = s.add_material(Material::diffuse("crate", [1.0; 3]).with_texture(crate_tex))?;
    let ball = s.add_material(
        Material::diffuse("ball", [1.0; 3])
            .with_texture(ball_tex)
            .with_metallic_roughness(0.0, 0.5),
    )?;
    let rainbow = s.add_material(
        Material::diffuse("vertex_colours", [1.0; 3]).with_metallic_roughness(0.0, 0.6),
    )?;
    let ceramic = s.add_material(
        Material::diffuse("ceramic", [0.55, 0.6, 0.5]).with_metallic_roughness(0.0, 0.3),
    )?;
    let gold = s.add_material(
        Material::diffuse("gold", [1.0, 0.77, 0.34]).with_metallic_roughness(1.0, 0.3),
    )?;

    // 12.5 cm checker cells: the 8-cell texture repeats every metre.
    s.add_mesh(
        "ground",
        Mesh::disc(1.0, 64, 1.0).with_planar_uvs(1.0),
        ground,
        Transform::IDENTITY,
    )?;
    let crate_at = Transform::from_translation_rotation(
        Vec3::new(-0.5, 0.2, 0.3),
        Quat::from_rotation_y(deg(30.0)),
    );
    s.add_mesh("crate", Mesh::cuboid(Vec3::splat(0.2)), crate_mat, crate_at)?;
    s.add_mesh(
        "gold_ball",
        Mesh::uv_sphere(0.1, 24, 12),
        gold,
        Transform::from_translation(Vec3::new(-0.5, 0.5, 0.3)),
    )?;
    s.add_mesh(
        "ball",
        Mesh::uv_sphere(0.3, 48, 24),
        ball,
        Transform::from_translation(Vec3::new(0.45, 0.3, 0.2)),
    )?;
    let ring = Mesh::torus(0.25, 0.08, 48, 16)
        .with_colors(|p, _| hue((p.z.atan2(p.x) / (2.0 * PI)).rem_euclid(1.0)));
    let ring_at = Transform::from_translation_rotation(
        Vec3::new(0.15, 0.33, -0.5),
        Quat::from_rotation_y(deg(30.0)) * Quat::from_rotation_x(deg(90.0)),
    );
    s.add_mesh("ring", ring, rainbow, ring_at)?;
    s.add_mesh(
        "vase",
        Mesh::cylinder(0.12, 0.5, 32),
        ceramic,
        Transform::from_translation(Vec3::new(-0.45, 0.0, -0.45)),
    )?;

    s.add_light(
        "sun",
        Light::Directional {
            color: [1.0, 0.97, 0.92],
            illuminance: 2.5,
        },
        sun_from(Vec3::new(2.0, 4.0, 3.0)),
    )?;
    s.add_light(
        "fill",
        Light::Point {
            color: [0.9, 0.95, 1.0],
            intensity: 5.0,
        },
        Transform::from_translation(Vec3::new(-1.2, 1.8, 1.0)),
    )?;
    Ok(s)
}

/// Wire radii of the `thin` scene, in metres (its bounding radius is ≈ 1.35 m).
const THIN_WIRE_RADII: [(&str, f32); 4] = [
    ("wire_cube", 0.009),
    ("spring", 0.008),
    ("lattice", 0.012),
    ("stem", 0.01),
];

fn thin_radius(name: &str) -> f32 {
    THIN_WIRE_RADII
        .iter()
        .find(|(n, _)| *n == name)
        .map_or(0.01, |(_, r)| *r)
}

// Long by design: the scene is a flat list of its materials and objects (base, wire cube,
// leaves, lights), each a few lines, read top to bottom like the scene description it is.
fn thin() -> Result<SceneBuilder, SceneGenError> {
    let mut s = SceneBuilder::new("thin");
    let base = s.add_material(Material::diffuse("base", [0.7, 0.7, 0.7]))?;
    let copper = s.add_material(
        Material::diffuse("copper", [0.7, 0.3, 0.15]).with_metallic_roughness(1.0, 0.4),
    )?;
    let dark = s.add_material(
        Material::diffuse("dark_wire", [0.12, 0.12, 0.14]).with_metallic_roughness(0.0, 0.6),
    )?;
    let blue = s.add_material(
        Material::diffuse("blue_wire", [0.1, 0.25, 0.7]).with_metallic_roughness(0.0, 0.5),
    )?;
    let leaf = s.add_material(
        Material::diffuse("leaf", [0.15, 0.5, 0.12])
            .with_metallic_roughness(0.0, 0.7)
            .double_sided(),
    )?;

    s.add_mesh("base", Mesh::disc(0.9, 64, 1.0), base, Transform::IDENTITY)?;

    // Wire-frame cube, side 0.7 m, resting on the base; wire diameter 1.8 cm.
    let (h, lift) = (0.35f32, 0.01f32);
    let corner = |i: u32| {
        Vec3::new(
            if i & 1 == 0 { -h } else { h },
            lift + if i & 2 == 0 { 0.0 } else { 2.0 * h },
            if i & 4 == 0 { -h } else { h },
        )
    };
    let mut frame = Mesh::empty();
    for a in 0..8u32 {
        for bit in [1u32, 2, 4] {
            if a & bit == 0 {
                frame.append(&Mesh::cylinder_between(
                    corner(a),
                    corner(a | bit),
                    thin_radius("wire_cube"),
                    8,
                ));
            }
        }
    }
    s.add_mesh("wire_cube", frame, copper, Transform::IDENTITY)?;

    // Helical spring inside the cube: 4 turns, radius 0.15 m, wire diameter 1.6 cm.
    let mut spring = Mesh::empty();
    let steps = 96;
    let helix = |k: u32| {
        let t = k as f32 / steps as f32;
        let a = t * 4.0 * 2.0 * PI;
        Vec3::new(0.15 * a.cos(), 0.05 + 0.55 * t, 0.15 * a.sin())
    };
    for k in 0..steps {
        spring.append(&Mesh::cylinder_between(
            helix(k),
            helix(k + 1),
            thin_radius("spring"),
            6,
        ));
    }
    s.add_mesh("spring", spring, blue, Transform::IDENTITY)?;

    // Fence lattice behind the cube: 8 posts and 6 rails of 2.4 cm wire.
    let mut lattice = Mesh::empty();
    let (zf, r) = (-0.6f32, thin_radius("lattice"));
    for i in 0..8 {
        let x = -0.7 + 1.4 * i as f32 / 7.0;
        lattice.append(&Mesh::cylinder_between(
            Vec3::new(x, 0.0, zf),
            Vec3::new(x, 0.85, zf),
            r,
            8,
        ));
    }
    for j in 0..6 {
        let y = 0.1 + 0.7 * j as f32 / 5.0;
        lattice.append(&Mesh::cylinder_between(
            Vec3::new(-0.72, y, zf),
            Vec3::new(0.72, y, zf),
            r,
            8,
        ));
    }
    s.add_mesh("lattice", lattice, dark, Transform::IDENTITY)?;

    // A plant: a stem with thin double-sided leaves (zero thickness).
    let stem_base = Vec3::new(0.6, 0.0, 0.45);
    let stem_top = Vec3::new(0.62, 0.85, 0.42);
    s.add_mesh(
        "stem",
        Mesh::cylinder_between(stem_base, stem_top, thin_radius("stem"), 8),
        dark,
        Transform::IDENTITY,
    )?;
    let mut leaves = Mesh::empty();
    for k in 0..7 {
        let t = 0.2 + 0.1 * k as f32;
        let at = stem_base.lerp(stem_top, t);
        let yaw = deg(137.5 * k as f32);
        let dir = Vec3::new(yaw.cos(), 0.35, yaw.sin()).normalize();
        let side = Vec3::Y.cross(dir).normalize() * 0.03;
        let tip = at + dir * 0.2;
        let mid = at + dir * 0.1;
        leaves.append(&Mesh::quad_from_corners([at, mid - side, tip, mid + side]));
    }
    s.add_mesh("leaves", leaves, leaf, Transform::IDENTITY)?;

    s.add_light(
        "sun",
        Light::Directional {
            color: [1.0, 0.98, 0.95],
            illuminance: 2.5,
        },
        sun_from(Vec3::new(-1.0, 3.0, 2.0)),
    )?;
    s.add_light(
        "fill",
        Light::Point {
            color: [1.0; 3],
            intensity: 4.0,
        },
        Transform::from_translation(Vec3::new(1.0, 1.6, 1.0)),
    )?;
    Ok(s)
}

fn deep() -> Result<SceneBuilder, SceneGenError> {
    let mut s = SceneBuilder::new("deep");
    let floor_tex = s.add_texture("floor", checker(128, 4, [190, 180, 160], [110, 100, 90]))?;
    let floor = s.add_material(Material::diffuse("floor", [1.0; 3]).with_texture(floor_tex))?;
    let stone = s.add_material(Material::diffuse("stone", [0.6, 0.57, 0.52]))?;
    let wall = s.add_material(Material::diffuse("wall", [0.45, 0.3, 0.25]))?;
    let brass = s.add_material(
        Material::diffuse("brass", [0.8, 0.6, 0.3]).with_metallic_roughness(1.0, 0.35),
    )?;
    let globe = s.add_material(
        Material::diffuse("globe", [0.85, 0.85, 0.8]).with_metallic_roughness(0.0, 0.2),
    )?;

    // Floor from z = 2 to z = -24, 8 m wide; 0.5 m checker cells.
    let floor_mesh = Mesh::quad(Vec2::new(8.0, 26.0), 1.0)
        .transformed(&glam::Mat4::from_translation(Vec3::new(0.0, 0.0, -11.0)))
        .with_planar_uvs(2.0);
    s.add_mesh("floor", floor_mesh, floor, Transform::IDENTITY)?;

    let pillar = s.add_geometry("pillar", Mesh::cylinder(0.2, 3.0, 24))?;
    for k in 0..10 {
        let z = -1.5 - 2.0 * k as f32;
        for x in [-1.8f32, 1.8] {
            let name = format!("pillar_{}_{k}", if x < 0.0 { "l" } else { "r" });
            s.add_instance(
                &name,
                pillar,
                stone,
                Transform::from_translation(Vec3::new(x, 0.0, z)),
            )?;
        }
    }
    let lintel = s.add_geometry("lintel", Mesh::cuboid(Vec3::new(0.25, 0.1, 9.6)))?;
    for x in [-1.8f32, 1.8] {
        let name = if x < 0.0 { "lintel_l" } else { "lintel_r" };
        s.add_instance(
            name,
            lintel,
            stone,
            Transform::from_translation(Vec3::new(x, 3.1, -10.5)),
        )?;
    }
    s.add_mesh(
        "back_wall",
        Mesh::cuboid(Vec3::new(3.0, 2.0, 0.2)),
        wall,
        Transform::from_translation(Vec3::new(0.0, 2.0, -21.0)),
    )?;

    // The near object: a lamp post with a globe 0.5 m in front of the camera.
    let post = Mesh::cylinder_between(
        Vec3::new(-0.18, 0.0, -0.6),
        Vec3::new(-0.18, 1.3, -0.6),
        0.02,
        12,
    );
    s.add_mesh("lamp_post", post, brass, Transform::IDENTITY)?;
    s.add_mesh(
        "lamp_globe",
        Mesh::uv_sphere(0.1, 24, 12),
        globe,
        Transform::from_translation(Vec3::new(-0.18, 1.4, -0.6)),
    )?;

    let camera = PerspectiveCamera {
        yfov: deg(50.0),
        znear: 0.05,
        zfar: None,
        aspect_ratio: None,
    };
    s.add_camera(
        "camera",
        camera,
        Transform::look_at(
            Vec3::new(0.0, 1.6, 0.0),
            Vec3::new(0.0, 1.2, -20.0),
            Vec3::Y,
        ),
    )?;

    s.add_light(
        "sun",
        Light::Directional {
            color: [1.0, 0.95, 0.85],
            illuminance: 2.0,
        },
        sun_from(Vec3::new(1.0, 1.0, 0.3)),
    )?;
    for (k, z) in [-4.0f32, -10.0, -16.0].into_iter().enumerate() {
        s.add_light(
            &format!("lamp_{k}"),
            Light::Point {
                color: [1.0, 0.85, 0.6],
                intensity: 3.0,
            },
            Transform::from_translation(Vec3::new(0.0, 2.5, z)),
        )?;
    }
    Ok(s)
}

fn materials() -> Result<SceneBuilder, SceneGenError> {
    let mut s = SceneBuilder::new("materials");
    let ground_tex = s.add_texture("ground", checker(128, 4, [210, 210, 210], [120, 120, 130]))?;
    let bumps = Bumps {
        cells: 4,
        radius: 0.4,
        height: 0.02,
    };
    let normal_tex = s.add_texture("bumps_normal", bump_normal_map(256, &bumps))?;

    let ground = s.add_material(
        Material::diffuse("ground", [1.0; 3])
            .with_texture(ground_tex)
            .with_metallic_roughness(0.0, 0.9),
    )?;
    s.add_mesh(
        "ground",
        Mesh::quad(Vec2::new(3.2, 3.2), 1.0).with_planar_uvs(1.0),
        ground,
        Transform::IDENTITY,
    )?;

    let sphere = s.add_geometry("sphere", Mesh::uv_sphere(0.2, 48, 24))?;
    let roughness = [0.05f32, 0.25, 0.5, 0.75, 1.0];
    for (row, (metallic, colour, z)) in [
        (0.0f32, [0.8f32, 0.1, 0.1], 0.0f32),
        (1.0, [1.0, 0.77, 0.34], -0.6),
    ]
    .into_iter()
    .enumerate()
    {
        for (i, &r) in roughness.iter().enumerate() {
            let name = format!(
                "{}_r{:03}",
                if row == 0 { "dielectric" } else { "metal" },
                (r * 100.0).round() as u32
            );
            let mat = s.add_material(
                Material::diffuse(&name, colour).with_metallic_roughness(metallic, r),
            )?;
            let x = -1.0 + 0.5 * i as f32;
            s.add_instance(
                &name,
                sphere,
                mat,
                Transform::from_translation(Vec3::new(x, 0.2, z)),
            )?;
        }
    }

    let bumpy = s.add_material(
        Material::diffuse("bumpy", [0.6, 0.6, 0.65])
            .with_metallic_roughness(0.0, 0.5)
            .with_normal_map(normal_tex, 1.0),
    )?;
    let box_at = Transform::from_translation_rotation(
        Vec3::new(0.0, 0.3, -1.4),
        Quat::from_rotation_y(deg(25.0)),
    );
    s.add_mesh(
        "bumpy_box",
        Mesh::cuboid(Vec3::splat(0.3)).with_tangents(),
        bumpy,
        box_at,
    )?;

    s.add_light(
        "sun",
        Light::Directional {
            color: [1.0, 0.97, 0.92],
            illuminance: 2.0,
        },
        sun_from(Vec3::new(-1.0, 2.0, 2.0)),
    )?;
    s.add_light(
        "point",
        Light::Point {
            color: [1.0; 3],
            intensity: 3.0,
        },
        Transform::from_translation(Vec3::new(1.5, 1.5, 1.0)),
    )?;
    s.add_light(
        "spot",
        Light::Spot {
            color: [1.0, 0.95, 0.9],
            intensity: 15.0,
            inner_cone_angle: deg(12.0),
            outer_cone_angle: deg(20.0),
        },
        Transform::look_at(
            Vec3::new(-1.2, 2.0, 0.5),
            Vec3::new(0.0, 0.3, -1.4),
            Vec3::Y,
        ),
    )?;
    Ok(s)
}

/// The ground disc and lights the `skinned` and `morphed` scenes share.
fn deform_stage(name: &str) -> Result<SceneBuilder, SceneGenError> {
    let mut s = SceneBuilder::new(name);
    let ground = s.add_material(Material::diffuse("ground", [0.55, 0.55, 0.5]))?;
    s.add_mesh("ground", Mesh::disc(1.2, 48, 1.0), ground, Transform::IDENTITY)?;
    s.add_light(
        "sun",
        Light::Directional { color: [1.0, 0.97, 0.92], illuminance: 2.5 },
        sun_from(Vec3::new(-1.0, 2.0, 1.5)),
    )?;
    s.add_light(
        "point",
        Light::Point { color: [1.0; 3], intensity: 4.0 },
        Transform::from_translation(Vec3::new(1.2, 1.6, 1.0)),
    )?;
    Ok(s)
}

/// An open tube along +Y from 0 to `height` with a flat top cap: `rings` rings of
/// `segments` vertices (the seam duplicated for UVs), radial normals.
fn tube(radius: f32, height: f32, segments: u32, rings: u32) -> Mesh {
    let mut m = Mesh::empty();
    for r in 0..=rings {
        let y = height * r as f32 / rings as f32;
        for k in 0..=segments {
            let a = 2.0 * std::f64::consts::PI * f64::from(k) / f64::from(segments);
            let (sin, cos) = (a.sin() as f32, a.cos() as f32);
            m.positions.push(Vec3::new(radius * cos, y, -radius * sin));
            m.normals.push(Vec3::new(cos, 0.0, -sin));
            m.uvs.push(Vec2::new(k as f32 / segments as f32, y / height));
        }
    }
    let row = segments + 1;
    for r in 0..rings {
        for k in 0..segments {
            let (a, b) = (r * row + k, r * row + k + 1);
            let (c, d) = (a + row, b + row);
            m.indices.extend([a, b, d, a, d, c]);
        }
    }
    let centre = m.positions.len() as u32;
    m.positions.push(Vec3::new(0.0, height, 0.0));
    m.normals.push(Vec3::Y);
    m.uvs.push(Vec2::new(0.5, 0.5));
    let top = rings * row;
    for k in 0..segments {
        let (a, b) = (top + k, top + k + 1);
        let (pa, pb) = (m.positions[a as usize], m.positions[b as usize]);
        // The cap's rim repeats the top ring with an upward normal (flat cap shading).
        let base = m.positions.len() as u32;
        m.positions.extend([pa, pb]);
        m.normals.extend([Vec3::Y, Vec3::Y]);
        m.uvs.extend([Vec2::new(0.5, 0.5), Vec2::new(0.5, 0.5)]);
        m.indices.extend([base, base + 1, centre]);
    }
    m
}

fn skinned() -> Result<SceneBuilder, SceneGenError> {
    let mut s = deform_stage("skinned")?;
    let grey = s.add_material(Material::diffuse("box", [0.6, 0.6, 0.65]).with_metallic_roughness(0.0, 0.6))?;
    s.add_mesh("box", Mesh::cuboid(Vec3::splat(0.15)), grey, Transform::from_translation(Vec3::new(-0.6, 0.15, -0.3)))?;

    let (bone, rings, height) = (0.4f32, 24u32, 1.2f32);
    let mesh = tube(0.09, height, 24, rings);
    let armature = s.add_joint(
        "armature",
        Transform::from_translation_rotation(Vec3::new(0.15, 0.0, 0.1), Quat::from_rotation_y(deg(30.0))),
        None,
    )?;
    let j0 = s.add_joint("bone0", Transform::IDENTITY, Some(armature))?;
    let j1 = s.add_joint(
        "bone1",
        Transform::from_translation_rotation(Vec3::new(0.0, bone, 0.0), Quat::from_rotation_z(deg(35.0))),
        Some(j0),
    )?;
    let j2 = s.add_joint(
        "bone2",
        Transform::from_translation_rotation(Vec3::new(0.0, bone, 0.0), Quat::from_rotation_z(deg(40.0)))
            .with_scale(Vec3::new(1.0, 1.0, 0.7)),
        Some(j1),
    )?;
    // Bind pose: the straight tube, joint k at height k · bone.
    let inverse_bind_matrices = (0..3).map(|k| glam::Mat4::from_translation(Vec3::new(0.0, -bone * k as f32, 0.0))).collect();
    let (mut vertex_joints, mut vertex_weights) = (Vec::new(), Vec::new());
    for p in &mesh.positions {
        // Joint k owns [k·bone, (k+1)·bone]; blend linearly across each joint's centre.
        let t = (p.y / bone - 0.5).clamp(0.0, 2.0);
        let k = (t.floor() as u8).min(1);
        let f = t - f32::from(k);
        vertex_joints.push([k, k + 1, 0, 0]);
        vertex_weights.push([1.0 - f, f, 0.0, 0.0]);
    }
    let red = s.add_material(Material::diffuse("tube", [0.75, 0.2, 0.15]).with_metallic_roughness(0.0, 0.45))?;
    s.add_skinned_mesh(
        "tube",
        mesh,
        red,
        crate::deform::Skin { joints: vec![j0, j1, j2], inverse_bind_matrices, vertex_joints, vertex_weights },
    )?;
    Ok(s)
}

fn morphed() -> Result<SceneBuilder, SceneGenError> {
    let mut s = deform_stage("morphed")?;
    let radius = 0.3f32;
    let sphere = Mesh::uv_sphere(radius, 48, 24);
    let scale = Vec3::new(1.4, 0.75, 1.0);
    let stretch = crate::deform::MorphTarget {
        positions: sphere.positions.iter().map(|&p| p * scale - p).collect(),
        normals: Some(sphere.normals.iter().map(|&n| (n / scale).normalize() - n).collect()),
    };
    let cap = 0.8f32; // sin 53°
    let bump = crate::deform::MorphTarget {
        positions: sphere
            .normals
            .iter()
            .map(|&n| if n.y > cap { n * 0.2 * ((n.y - cap) / (1.0 - cap)).powi(2) } else { Vec3::ZERO })
            .collect(),
        normals: None,
    };
    let g = s.add_morphed_geometry("blob", sphere, vec![stretch, bump], vec![0.6, 0.8])?;
    let blue = s.add_material(Material::diffuse("blob", [0.2, 0.35, 0.75]).with_metallic_roughness(0.0, 0.4))?;
    s.add_instance("blob_mesh_weights", g, blue, Transform::from_translation(Vec3::new(-0.45, 0.28, 0.0)))?;
    let right = s.add_instance("blob_node_weights", g, blue, Transform::from_translation(Vec3::new(0.45, 0.25, 0.0)))?;
    s.set_morph_weights(right, vec![1.0, 0.0])?;
    Ok(s)
}

fn glass() -> Result<SceneBuilder, SceneGenError> {
    let mut s = SceneBuilder::new("glass");
    let ground_tex = s.add_texture("ground", checker(128, 8, [210, 210, 210], [60, 60, 70]))?;
    let ground = s.add_material(
        Material::diffuse("ground", [1.0; 3])
            .with_texture(ground_tex)
            .with_metallic_roughness(0.0, 0.9),
    )?;
    s.add_mesh(
        "ground",
        Mesh::quad(Vec2::new(2.4, 2.4), 1.0).with_planar_uvs(0.6),
        ground,
        Transform::IDENTITY,
    )?;
    let clear = Glass {
        transmission: 1.0,
        ior: 1.5,
        thickness: 0.5,
        attenuation_color: [1.0; 3],
        attenuation_distance: None,
    };
    let tinted = s.add_material(
        Material::diffuse("green_glass", [1.0; 3])
            .with_metallic_roughness(0.0, 0.0)
            .with_glass(Glass {
                attenuation_color: [0.6, 0.9, 0.7],
                attenuation_distance: Some(0.5),
                ..clear.clone()
            }),
    )?;
    s.add_mesh(
        "glass_sphere",
        Mesh::uv_sphere(0.25, 64, 32),
        tinted,
        Transform::from_translation(Vec3::new(-0.3, 0.25, 0.2)),
    )?;
    let frosted = s.add_material(
        Material::diffuse("frosted_glass", [1.0; 3])
            .with_metallic_roughness(0.0, 0.3)
            .with_glass(clear),
    )?;
    s.add_mesh(
        "glass_block",
        Mesh::cuboid(Vec3::new(0.15, 0.2, 0.1)),
        frosted,
        Transform::from_translation_rotation(Vec3::new(0.35, 0.2, 0.25), Quat::from_rotation_y(deg(-30.0))),
    )?;
    let red = s.add_material(Material::diffuse("red", [0.7, 0.12, 0.1]))?;
    s.add_mesh(
        "red_box",
        Mesh::cuboid(Vec3::splat(0.18)),
        red,
        Transform::from_translation_rotation(Vec3::new(0.1, 0.18, -0.45), Quat::from_rotation_y(deg(20.0))),
    )?;
    let gold = s.add_material(
        Material::diffuse("gold", [1.0, 0.77, 0.34]).with_metallic_roughness(1.0, 0.35),
    )?;
    s.add_mesh(
        "gold_sphere",
        Mesh::uv_sphere(0.2, 48, 24),
        gold,
        Transform::from_translation(Vec3::new(-0.55, 0.2, -0.45)),
    )?;
    s.add_light(
        "sun",
        Light::Directional {
            color: [1.0, 0.97, 0.92],
            illuminance: 2.5,
        },
        sun_from(Vec3::new(1.0, 2.0, 1.5)),
    )?;
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thin_wires_are_one_to_two_pixels_wide() {
        // The renderer frames the bounding sphere with a ~40° FOV; at 200×200 a
        // pixel then spans 2·tan(20°)/200 ≈ 0.0036 of the camera distance
        // R / sin(20°), i.e. ≈ 0.0107 R. Wires should be 0.01–0.02 R across.
        let scene = build_scene("thin").unwrap();
        let (lo, hi) = scene.bounds().unwrap();
        let radius = ((hi - lo) * 0.5).length();
        let fov = 40f32.to_radians();
        let pixel = 2.0 * (fov / 2.0).tan() / 200.0 * radius / (fov / 2.0).sin();
        for (name, r) in THIN_WIRE_RADII {
            let d = 2.0 * r;
            assert!(
                (0.01..=0.02).contains(&(d / radius)),
                "{name}: diameter {d} vs radius {radius}"
            );
            assert!(
                (0.9..=2.0).contains(&(d / pixel)),
                "{name}: {} pixels",
                d / pixel
            );
        }
    }

    #[test]
    fn every_scene_has_a_description_and_builds() {
        for name in scene_names() {
            assert!(
                scene_description(name).is_some_and(|d| d.len() > 100),
                "{name}"
            );
            let s = build_scene(name).unwrap();
            assert!(s.bounds().is_some());
        }
        assert!(matches!(
            build_scene("none"),
            Err(SceneGenError::UnknownScene { .. })
        ));
    }
}

fn coated() -> Result<SceneBuilder, SceneGenError> {
    let mut s = SceneBuilder::new("coated");
    let ground = s.add_material(Material::diffuse("ground", [0.5, 0.5, 0.5]).with_metallic_roughness(0.0, 0.9))?;
    s.add_mesh("ground", Mesh::quad(Vec2::new(2.4, 2.4), 1.0).with_planar_uvs(0.6), ground, Transform::IDENTITY)?;
    let sphere = s.add_geometry("sphere", Mesh::uv_sphere(0.2, 48, 24))?;
    let tangent_sphere = s.add_geometry("tangent_sphere", Mesh::uv_sphere(0.2, 48, 24).with_tangents())?;
    let bumps = Bumps { cells: 8, radius: 0.4, height: 0.02 };
    let coat_bumps = s.add_texture("coat_bumps_normal", bump_normal_map(128, &bumps))?;
    let spheres = [
        Material::diffuse("coated_red", [0.7, 0.1, 0.08])
            .with_metallic_roughness(0.0, 0.7)
            .with_clearcoat(1.0, 0.05)
            .with_clearcoat_normal_map(coat_bumps, 1.0),
        Material::diffuse("coated_blue", [0.1, 0.2, 0.7]).with_metallic_roughness(0.0, 0.6).with_clearcoat(1.0, 0.4),
        Material::diffuse("coated_gold", [1.0, 0.77, 0.34]).with_metallic_roughness(1.0, 0.5).with_clearcoat(0.5, 0.1),
        Material::diffuse("velvet", [0.05, 0.01, 0.015]).with_metallic_roughness(0.0, 0.9).with_sheen([1.0, 0.6, 0.6], 0.3),
        Material::diffuse("blue_sheen", [0.02, 0.02, 0.02]).with_metallic_roughness(0.0, 0.9).with_sheen([0.3, 0.5, 1.0], 0.6),
        Material::diffuse("sheen_and_coat", [0.1, 0.5, 0.15]).with_metallic_roughness(0.0, 0.5).with_sheen([0.5; 3], 0.5).with_clearcoat(0.6, 0.2),
    ];
    for (k, m) in spheres.into_iter().enumerate() {
        let name = format!("{}_sphere", m.name);
        let id = s.add_material(m)?;
        let (x, z) = (-0.5 + 0.5 * (k % 3) as f32, if k < 3 { -0.25 } else { 0.3 });
        let g = if k == 0 { tangent_sphere } else { sphere };
        s.add_instance(&name, g, id, Transform::from_translation(Vec3::new(x, 0.2, z)))?;
    }
    s.add_light(
        "sun",
        Light::Directional {
            color: [1.0, 0.97, 0.92],
            illuminance: 2.5,
        },
        sun_from(Vec3::new(1.0, 2.0, 1.5)),
    )?;
    s.add_light(
        "lamp",
        Light::Point {
            color: [1.0, 1.0, 1.0],
            intensity: 4.0,
        },
        Transform::from_translation(Vec3::new(-0.8, 1.2, 0.9)),
    )?;
    Ok(s)
}
