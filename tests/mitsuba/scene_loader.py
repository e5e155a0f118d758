"""Build a Mitsuba 3 scene from an export folder written by `pathtracer::export::export_scene`.

The export holds the scene exactly as our renderer loaded it (world-space triangles, resolved
materials, lights in physical units, the dataset cameras). Geometry is placed in the scene's
local frame (world - origin), as our renderer does, so both trace in the same f32 frame.

Mapping (ours -> Mitsuba):
- triangles of material k -> one `mi.Mesh` with vertex normals and TEXCOORD_0;
- exactly Lambertian material (metallic 0 and specular weight 0): `diffuse` with reflectance
  clamp(base_color_factor x base_color_texture x COLOR_0, 0, 1) (texture: `bitmap`, raw linear
  texels, glTF filter and wrap; vertex colours: `mesh_attribute`); double-sided -> `twosided`;
- every other material -> the `gltf` BSDF plugin of `gltf_bsdf.py` (our glTF BRDF, written
  from the Rust doc comments, evaluated in our shading frame: normal map with the exported
  per-corner tangents, back-facing shading normals bent, directions below the geometric
  surface rejected), with the same base colour and metallic-roughness textures; the
  KHR_materials_clearcoat and _sheen layers are the plugin's too (a clearcoat normal map on
  another UV set than the base's is `Unsupported`);
- transmissive material (`transmission` > 0, KHR_materials_transmission): smooth and
  thin-walled -> `thindielectric`; with a volume -> `dielectric` (roughness 0) or
  `roughdielectric` (GGX, alpha = max(roughness^2, 1e-3), visible normals), int_ior = ior,
  specular_transmittance = the base colour; transmission t < 1 or metallic m > 0 ->
  `blendbsdf` with weight w = (1 - m) t on the dielectric and the `gltf` plugin with metallic
  m / (1 - w) (material.rs `Transmissive`); a volume's attenuation -> the shape's `interior`
  `homogeneous` medium with sigma_t = -ln(attenuation_color) / attenuation_distance and
  albedo 0 (pure absorption), rendered with `volpath`. Rough thin-walled transmission (ours
  mirrors the reflected lobe below the surface) has no Mitsuba counterpart: `Unsupported`;
- emissive material -> `area` emitter, radiance = emissive (x emissive texture);
- point -> `point` (intensity W/sr = candela); directional -> `directional` (irradiance = lux);
  spot -> `gltf_spot` (glTF's smooth falloff, `gltf_lights.py`);
- environment -> `constant`; environment map -> `gltf_envmap` (`gltf_lights.py`: our
  nearest-texel map and its importance sampling; Mitsuba's `envmap` has our orientation, which
  `envmap_agreement` checks, but interpolates bilinearly);
- camera -> `perspective`, to_world = M @ diag(-1, 1, -1, 1) (Mitsuba: x left, y up, z forward),
  fov_axis y from fl_y and height, box pixel filter (colour = average over the pixel area);
- integrator -> `path`, max_depth = max_bounces + 1 (Mitsuba counts path segments: 1 shows
  emitters only, 2 is direct light; ours counts scattering events: 0 emitters only, 1 direct).

Anything the mapping cannot reproduce exactly raises `Unsupported` naming it.
"""

import json
import math
import os

import numpy as np


class Unsupported(Exception):
    """The exported scene uses a feature this harness cannot reproduce exactly in Mitsuba."""


WRAP = {"repeat": "repeat", "mirrored_repeat": "mirror", "clamp_to_edge": "clamp"}
FILTER = {"nearest": "nearest", "linear": "bilinear"}


def load_export(folder):
    """The manifest (dict) and the arrays (dict of numpy arrays) of an export folder."""
    with open(os.path.join(folder, "scene.json")) as f:
        man = json.load(f)
    arrays = {}
    for name in ["positions", "normals", "tangents", "uv0", "uv1", "colors", "indices", "material"]:
        arrays[name] = np.load(os.path.join(folder, name + ".npy"))
    arrays["textures"] = [np.load(os.path.join(folder, t["file"])) for t in man["textures"]]
    corner = os.path.join(folder, "corner_tangents.npy")
    arrays["corner_tangents"] = np.load(corner) if os.path.exists(corner) else None
    env = man.get("environment_map")
    arrays["environment_map"] = np.load(os.path.join(folder, env["file"])) if env else None
    return man, arrays


def rgb(v):
    return {"type": "rgb", "value": [float(x) for x in v[:3]]}


def bitmap_texture(mi, texels, ref, scale):
    """A raw (linear) `bitmap` texture of texels[..., :3] x scale with the reference's sampler."""
    if ref["wrap_s"] != ref["wrap_t"]:
        raise Unsupported(f"texture {ref['texture']}: different wrap modes per axis ({ref['wrap_s']}, {ref['wrap_t']})")
    if ref["tex_coord"] != 0:
        raise Unsupported(f"texture {ref['texture']}: TEXCOORD_1")
    data = np.ascontiguousarray(texels[..., :3] * np.asarray(scale[:3], np.float32)[None, None, :], dtype=np.float32)
    d = {
        "type": "bitmap",
        "bitmap": mi.Bitmap(data),
        "raw": True,
        "filter_type": FILTER[ref["filter"]],
        "wrap_mode": WRAP[ref["wrap_s"]],
    }
    t = ref.get("transform")
    if t is not None:
        # KHR_texture_transform: uv' = [[a, b, c], [d, e, f]] (u, v, 1), applied by Mitsuba's
        # `to_uv` before the lookup, as ours does.
        d["to_uv"] = mi.ScalarTransform3f([[float(x) for x in t[0]], [float(x) for x in t[1]], [0.0, 0.0, 1.0]])
    return d


def lambert_reflectance(mi, mat, textures, has_vertex_colors):
    """Mitsuba texture (dict) for clamp(factor x texture x COLOR_0, 0, 1)."""
    factor = np.asarray(mat["base_color_factor"][:3], np.float32)
    tex = mat["base_color_texture"]
    if tex is not None and has_vertex_colors:
        raise Unsupported(f"material {mat['name']}: base colour texture x vertex colours")
    if tex is not None:
        texels = np.clip(textures[tex["texture"]][..., :3] * factor, 0.0, 1.0)
        return bitmap_texture(mi, texels, tex, [1.0, 1.0, 1.0])
    if has_vertex_colors:
        return {"type": "mesh_attribute", "name": "vertex_color"}
    return rgb(np.clip(factor, 0.0, 1.0))


def transmissive_bsdf(mi, mat, textures, has_vertex_colors, glossy_plugin):
    """The Mitsuba BSDF dict of a transmissive material (see the module docs)."""
    name = mat["name"]
    for key, what in [("transmission_texture", "transmission texture"), ("metallic_roughness_texture", "metallic-roughness texture"),
                      ("normal_texture", "normal map")]:
        if mat.get(key) is not None:
            raise Unsupported(f"material {name}: {what} on a transmissive material")
    ior = float(mat.get("ior", 1.5))
    r = float(mat["roughness"])
    tint = lambert_reflectance(mi, mat, textures, has_vertex_colors)
    if mat.get("volume") is None:
        if r > 0.0:
            raise Unsupported(f"material {name}: rough thin-walled transmission (Mitsuba's thindielectric is smooth)")
        glass = {"type": "thindielectric", "int_ior": ior, "ext_ior": 1.0, "specular_transmittance": tint}
    elif r > 0.0:
        glass = {"type": "roughdielectric", "distribution": "ggx", "alpha": max(r * r, 1e-3), "sample_visible": True,
                 "int_ior": ior, "ext_ior": 1.0, "specular_transmittance": tint}
    else:
        glass = {"type": "dielectric", "int_ior": ior, "ext_ior": 1.0, "specular_transmittance": tint}
    m = min(max(float(mat["metallic"]), 0.0), 1.0)
    w = (1.0 - m) * min(max(float(mat["transmission"]), 0.0), 1.0)
    if w >= 1.0:
        return glass
    if glossy_plugin is None:
        raise Unsupported(f"material {name}: partial transmission without the gltf BSDF plugin")
    base = glossy_plugin(mi, dict(mat, metallic=m / (1.0 - w)), textures, has_vertex_colors)
    return {"type": "blendbsdf", "weight": w, "bsdf_0": base, "bsdf_1": glass}


def absorption(mat):
    """sigma_a (RGB list) of a material's volume, or None without absorption."""
    vol = mat.get("volume") if mat.get("transmission", 0.0) > 0.0 else None
    if vol is None or vol.get("attenuation_distance") is None:
        return None
    c = np.clip(np.asarray(vol["attenuation_color"], np.float64), 1e-30, 1.0)
    sigma = -np.log(c) / float(vol["attenuation_distance"])
    return None if not np.any(sigma > 0.0) else [float(x) for x in sigma]


def material_bsdf(mi, mat, textures, has_vertex_colors, glossy_plugin):
    if mat["alpha_mode"] == "mask":
        raise Unsupported(f"material {mat['name']}: alpha mask")
    if mat.get("transmission", 0.0) > 0.0:
        return transmissive_bsdf(mi, mat, textures, has_vertex_colors, glossy_plugin)
    # Ours shades exactly Lambertian only when metallic and the specular weight are both 0
    # (material.rs `resolve`); everything else goes through the glTF BRDF.
    lambertian = mat["metallic"] <= 0.0 and mat.get("specular", 1.0) <= 0.0 and mat["metallic_roughness_texture"] is None
    # Clearcoat and sheen layers (KHR_materials_clearcoat, _sheen) are the plugin's.
    lambertian = lambertian and mat.get("clearcoat") is None and mat.get("sheen") is None
    if not lambertian:
        if glossy_plugin is None:
            raise Unsupported(f"material {mat['name']}: glTF BRDF without the gltf BSDF plugin")
        # The plugin handles both sides itself (our shading frame, see gltf_bsdf.py).
        return glossy_plugin(mi, mat, textures, has_vertex_colors)
    else:
        inner = {"type": "diffuse", "reflectance": lambert_reflectance(mi, mat, textures, has_vertex_colors)}
    if mat["double_sided"]:
        return {"type": "twosided", "bsdf": inner}
    return inner


def emitter(mi, mat, textures):
    if max(mat["emissive"]) <= 0.0:
        return None
    if mat["double_sided"]:
        raise Unsupported(f"material {mat['name']}: double-sided emitter (Mitsuba's area light is one-sided)")
    tex = mat["emissive_texture"]
    if tex is not None:
        radiance = bitmap_texture(mi, textures[tex["texture"]], tex, mat["emissive"])
    else:
        radiance = rgb(mat["emissive"])
    return {"type": "area", "radiance": radiance}


def build_meshes(mi, man, arrays, glossy_plugin=None):
    """One `mi.Mesh` per material, in the scene's local frame."""
    origin = np.asarray(man["origin"], np.float64)
    pos = (arrays["positions"] - origin[None, :]).astype(np.float32)
    nrm = arrays["normals"].astype(np.float32)
    uv = arrays["uv0"].astype(np.float32)
    col = arrays["colors"].astype(np.float32)
    idx = arrays["indices"].astype(np.int64)
    mat_of = arrays["material"].astype(np.int64)
    meshes = {}
    for k, mat in enumerate(man["materials"]):
        sel = mat_of == k
        tris = idx[sel]
        if len(tris) == 0:
            continue
        normal_mapped = mat["normal_texture"] is not None or (mat.get("clearcoat") or {}).get("normal_texture") is not None
        if normal_mapped:
            # One vertex per triangle corner, carrying the tangent ours uses there
            # (corner_tangents.npy; linear over the triangle, so Mitsuba's interpolation of the
            # corners reproduces ours exactly, including per-triangle generated tangents).
            if arrays.get("corner_tangents") is None:
                raise Unsupported(f"material {mat['name']}: normal map without corner_tangents.npy (export format < 2)")
            used = tris.ravel()
            faces = np.arange(3 * len(tris), dtype=np.uint32).reshape(-1, 3)
            corner_t = arrays["corner_tangents"][sel].reshape(-1, 4).astype(np.float32)
        else:
            used, inverse = np.unique(tris.ravel(), return_inverse=True)
            faces = inverse.reshape(-1, 3).astype(np.uint32)
        vcol = col[used, :3] * np.asarray(mat["base_color_factor"][:3], np.float32)[None, :]
        has_vc = bool(np.any(np.abs(col[used, :3] - 1.0) > 0.0))
        props = mi.Properties()
        props["bsdf"] = mi.load_dict(material_bsdf(mi, mat, arrays["textures"], has_vc, glossy_plugin))
        em = emitter(mi, mat, arrays["textures"])
        if em is not None:
            props["emitter"] = mi.load_dict(em)
        sigma = absorption(mat)
        if sigma is not None:
            # An `rgb` value must lie in [0, 1]: sigma_t = value x scale.
            scale = max(sigma)
            props["interior"] = mi.load_dict({"type": "homogeneous", "sigma_t": {"type": "rgb", "value": [x / scale for x in sigma]},
                                              "scale": scale, "albedo": 0.0})
        if np.any(np.linalg.norm(nrm[used], axis=1) < 1e-6):
            raise Unsupported(f"material {mat['name']}: vertices without normals")
        mesh = mi.Mesh(f"material_{k}", len(used), len(faces), props, has_vertex_normals=True, has_vertex_texcoords=True)
        params = mi.traverse(mesh)
        floats, uints = type(params["vertex_positions"]), type(params["faces"])
        params["vertex_positions"] = floats(pos[used].ravel())
        params["vertex_normals"] = floats(nrm[used].ravel())
        params["vertex_texcoords"] = floats(uv[used].ravel())
        params["faces"] = uints(faces.ravel())
        params.update()
        if has_vc:
            mesh.add_attribute("vertex_color", 3, floats(np.clip(vcol, 0.0, 1.0).ravel()))
        if normal_mapped:
            mesh.add_attribute("vertex_tangent", 3, floats(np.ascontiguousarray(corner_t[:, :3]).ravel()))
            mesh.add_attribute("vertex_tangent_w", 1, floats(np.where(corner_t[:, 3] < 0, -1.0, 1.0).astype(np.float32)))
        meshes[f"material_{k}"] = mesh
    return meshes


ENVMAP_MIN_WIDTH = 1024
ENVMAP_MAX_WIDTH = 8192


def envmap_bitmap(texels):
    """Texels (H, W, 3) for Mitsuba's `envmap` that reproduce our nearest-texel lookup.

    Both use u = atan2(x, -z) / 2pi, v = acos(y) / pi, image row 0 at +Y (checked by
    `envmap_agreement`). Ours: texel (floor(u W), floor(v H)). Mitsuba: bilinear, column centres
    at u = (i + 1/2) / W' (wrapping), row centres at v = j / (H' - 1) (rows 0 and H'-1 on the
    poles). So we sample ours at Mitsuba's texel centres on a k-times finer grid; the two then
    differ only in bands 1/W', 1/H' wide around our texel edges, where Mitsuba blends the two
    neighbours."""
    h, w = texels.shape[:2]
    k = max(2, int(math.ceil(ENVMAP_MIN_WIDTH / w)))
    k = max(1, min(k, ENVMAP_MAX_WIDTH // w))
    w2, h2 = w * k, h * k
    u = (np.arange(w2) + 0.5) / w2
    v = np.arange(h2) / (h2 - 1)
    cols = np.minimum((u * w).astype(np.int64), w - 1)
    rows = np.minimum((v * h).astype(np.int64), h - 1)
    return np.ascontiguousarray(texels[rows][:, cols, :3], dtype=np.float32)


def direction(u, v):
    """Our `EnvironmentMap::direction` (image coordinates -> unit direction)."""
    phi, theta = 2.0 * math.pi * u, math.pi * v
    return np.array([math.sin(phi) * math.sin(theta), math.cos(theta), -math.cos(phi) * math.sin(theta)])


def envmap_agreement(mi, texels, scale, emitter=None, n=64, seed=0):
    """Largest relative difference between an environment emitter (default: Mitsuba's own
    `envmap` of `envmap_bitmap(texels)`) and our lookup at n random directions away from our
    texel edges (a check of the orientation convention)."""
    if emitter is None:
        emitter = mi.load_dict({"type": "envmap", "bitmap": mi.Bitmap(envmap_bitmap(texels * np.asarray(scale[:3], np.float32)))})
    rng = np.random.default_rng(seed)
    h, w = texels.shape[:2]
    worst = 0.0
    for _ in range(n):
        i, j = int(rng.integers(w)), int(rng.integers(h))
        fu, fv = rng.uniform(0.25, 0.75, 2)
        d = direction((i + fu) / w, (j + fv) / h)
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*[float(-x) for x in d])
        got = np.asarray(emitter.eval(si), np.float64).ravel()[:3]
        want = texels[j, i, :3] * np.asarray(scale[:3])
        worst = max(worst, float(np.max(np.abs(got - want) / np.maximum(np.abs(want), 1e-6))))
    return worst


def build_lights(man, spot_plugin=None, arrays=None, envmap_plugin=None):
    origin = np.asarray(man["origin"], np.float64)
    out = {}
    for k, light in enumerate(man["lights"]):
        if light.get("range") is not None:
            raise Unsupported(f"light {k}: glTF range cutoff")
        kind = light["type"]
        if kind == "point":
            p = (np.asarray(light["position"]) - origin).tolist()
            out[f"light_{k}"] = {"type": "point", "position": p, "intensity": rgb(light["intensity"])}
        elif kind == "directional":
            out[f"light_{k}"] = {"type": "directional", "direction": light["direction"], "irradiance": rgb(light["illuminance"])}
        elif kind == "spot":
            if spot_plugin is None:
                raise Unsupported(f"light {k}: spot light without the gltf_spot plugin")
            out[f"light_{k}"] = spot_plugin(light, origin)
        else:
            raise Unsupported(f"light {k}: type {kind}")
    env = man["environment"]
    texels = arrays.get("environment_map") if arrays is not None else None
    if man.get("environment_map") and texels is None:
        raise Unsupported("environment map named in scene.json but not loaded")
    if texels is not None:
        if envmap_plugin is None:
            raise Unsupported("environment map without the gltf_envmap plugin")
        if max(env) > 0.0:
            origin = np.asarray(man["origin"], np.float64)
            radius = float(np.max(np.linalg.norm(arrays["positions"] - origin[None, :], axis=1))) + 1.0
            out["environment"] = envmap_plugin(texels, env, radius)
    elif max(env) > 0.0:
        out["environment"] = {"type": "constant", "radiance": rgb(env)}
    return out


def local_c2w(cam, origin):
    m = np.asarray(cam["c2w"], np.float64).copy()
    m[:3, 3] -= origin
    return m


def sensor(mi, cam, origin, spp, sampler="independent"):
    """Mitsuba `perspective` sensor reproducing the dataset camera (see the module docs)."""
    w, h = cam["width"], cam["height"]
    if abs(cam["fl_x"] - cam["fl_y"]) > 1e-9 * cam["fl_y"]:
        raise Unsupported("non-square pixels (fl_x != fl_y)")
    fov_y = math.degrees(2.0 * math.atan(0.5 * h / cam["fl_y"]))
    to_world = local_c2w(cam, origin) @ np.diag([-1.0, 1.0, -1.0, 1.0])
    return {
        "type": "perspective",
        "fov_axis": "y",
        "fov": fov_y,
        # Mitsuba's offsets are fractions of the film size, measured from its centre.
        "principal_point_offset_x": (cam["cx"] - 0.5 * w) / w,
        "principal_point_offset_y": (cam["cy"] - 0.5 * h) / h,
        "near_clip": 1e-5,
        "far_clip": 1e7,
        "to_world": mi.ScalarTransform4f(to_world.tolist()),
        "film": {
            "type": "hdrfilm",
            "width": w,
            "height": h,
            "rfilter": {"type": "box"},
            "pixel_format": "rgba",
            "component_format": "float32",
        },
        "sampler": {"type": sampler, "sample_count": spp},
    }


def build_scene(mi, man, arrays, view, spp, glossy_plugin=None, spot_plugin=None, envmap_plugin=None, transparent_ok=False,
                rr_depth=None, sampler="independent"):
    """The Mitsuba scene of view `view`. A transparent background is unsupported (the
    comparison needs the environment behind the scene) unless `transparent_ok` (timing only:
    camera misses then show black, `hide_emitters`, where ours shows alpha 0)."""
    origin = np.asarray(man["origin"], np.float64)
    transparent = bool(man["settings"]["transparent_background"])
    d = {"type": "scene"}
    # Absorbing volumes need Mitsuba's volumetric path tracer (`path` ignores media).
    media = any(absorption(m) is not None for m in man["materials"])
    d["integrator"] = {
        "type": "volpath" if media else "path",
        "max_depth": int(man["settings"]["max_bounces"]) + 1,
        "hide_emitters": transparent,
    }
    if rr_depth is not None:
        d["integrator"]["rr_depth"] = int(rr_depth)
    if transparent and not transparent_ok:
        raise Unsupported("transparent background (render with the environment as background)")
    d.update(build_meshes(mi, man, arrays, glossy_plugin))
    d.update(build_lights(man, spot_plugin, arrays, envmap_plugin))
    d["sensor"] = sensor(mi, man["cameras"][view], origin, spp, sampler)
    return mi.load_dict(d)


def pixel_center_rays(cam, origin):
    """Origins (3,) and unit directions (H, W, 3) of the pixel-centre rays, local frame, with
    the formula of `dataset::Camera::pixel_ray`; also the camera-frame z of each direction."""
    w, h = cam["width"], cam["height"]
    i, j = np.meshgrid(np.arange(w, dtype=np.float64) + 0.5, np.arange(h, dtype=np.float64) + 0.5)
    d = np.stack([(i - cam["cx"]) / cam["fl_x"], -(j - cam["cy"]) / cam["fl_y"], -np.ones_like(i)], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    m = local_c2w(cam, origin)
    dw = d @ m[:3, :3].T
    dw /= np.linalg.norm(dw, axis=-1, keepdims=True)
    return m[:3, 3], dw, d[..., 2]
