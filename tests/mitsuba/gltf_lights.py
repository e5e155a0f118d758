"""Our lights that Mitsuba 3 cannot express exactly, as Python emitter plugins (written from
the doc comments of `crates/pathtracer/src/light.rs`). Work in scalar and vectorised variants.

`gltf_spot`: glTF's spot light (KHR_lights_punctual). A point light of intensity I (W/sr)
times the smooth cone falloff

    a(cd) = clamp((cd - cos(outer)) / max(1e-3, cos(inner) - cos(outer)), 0, 1)^2

with cd the cosine between the spot axis and the direction from the light to the lit point;
irradiance at normal incidence I a / r^2. (Mitsuba's own `spot` falls off linearly in the
angle between beam_width and cutoff_angle, so it cannot reproduce this profile.)

`gltf_envmap`: our equirectangular environment map (`light.rs` `EnvironmentMap`): nearest
texel, u = atan2(x, -z) / 2pi, v = acos(y) / pi, row 0 = +Y; importance sampled with texel
weights Y(L) sin(theta_row) (Y Rec. 709 luminance; a black-luminance texel with some positive
channel gets 1e-3 x max channel), uniform inside the texel, pdf per steradian
p_texel W H / (2 pi^2 sin theta). Mitsuba's `envmap` interpolates bilinearly with rows centred
pole to pole, which differs from nearest lookup in bands around every texel edge; this plugin
integrates exactly our model.
"""

import math

import drjit as dr
import mitsuba as mi
import numpy as np


def _zeros(cls):
    """`dr.zeros(cls)`, or the default constructor where Dr.Jit cannot build the type (scalar
    variants: records with an emitter pointer)."""
    try:
        return dr.zeros(cls)
    except Exception:
        return cls()


def _spot_falloff(cd, cos_inner, cos_outer):
    scale = 1.0 / max(cos_inner - cos_outer, 1e-3)
    a = dr.clip((cd - cos_outer) * scale, 0.0, 1.0)
    return a * a


class GltfSpot(mi.Emitter):
    def __init__(self, props):
        mi.Emitter.__init__(self, props)
        p, d, i = props["position"], props["direction"], props["intensity"]
        self.position = mi.ScalarPoint3f(p[0], p[1], p[2])
        self.axis = dr.normalize(mi.ScalarVector3f(d[0], d[1], d[2]))
        self.intensity = mi.ScalarColor3f(i[0], i[1], i[2])
        self.cos_inner = math.cos(float(props["inner_cone_angle"]))
        self.cos_outer = math.cos(float(props["outer_cone_angle"]))
        self.m_flags = mi.EmitterFlags.DeltaPosition

    def sample_direction(self, it, sample, active=True):
        ds = _zeros(mi.DirectionSample3f)
        ds.p = mi.Point3f(self.position)
        ds.n = mi.Normal3f(0.0)
        ds.uv = mi.Point2f(0.0)
        ds.time = it.time
        ds.pdf = 1.0
        ds.delta = True
        d = ds.p - it.p
        dist = dr.norm(d)
        inv = dr.rcp(dist)
        ds.d = d * inv
        ds.dist = dist
        cd = dr.dot(mi.Vector3f(self.axis), -ds.d)
        spec = mi.Color3f(self.intensity) * (_spot_falloff(cd, self.cos_inner, self.cos_outer) * inv * inv)
        return ds, dr.select(active, spec, 0.0)

    def pdf_direction(self, it, ds, active=True):
        return 0.0

    def eval_direction(self, it, ds, active=True):
        d = mi.Vector3f(self.position) - it.p
        dist = dr.norm(d)
        cd = dr.dot(mi.Vector3f(self.axis), -d / dist)
        return mi.Color3f(self.intensity) * (_spot_falloff(cd, self.cos_inner, self.cos_outer) / (dist * dist))

    def eval(self, si, active=True):
        return mi.Color3f(0.0)

    def sample_ray(self, time, sample1, sample2, sample3, active=True):
        raise NotImplementedError("gltf_spot: light tracing is not supported")

    def sample_position(self, time, sample, active=True):
        ps = _zeros(mi.PositionSample3f)
        ps.p = mi.Point3f(self.position)
        ps.pdf = 1.0
        ps.delta = True
        return ps, mi.Float(1.0)

    def bbox(self):
        return mi.ScalarBoundingBox3f(self.position)

    def traverse(self, callback):
        pass

    def to_string(self):
        return f"GltfSpot[position={self.position}, axis={self.axis}, cos_inner={self.cos_inner}, cos_outer={self.cos_outer}]"


class GltfEnvmap(mi.Emitter):
    def __init__(self, props):
        mi.Emitter.__init__(self, props)
        texels = np.array(props["bitmap"], np.float32)[..., :3]  # (H, W, 3), already scaled
        self.h, self.w = texels.shape[:2]
        self.texture = mi.load_dict({
            "type": "bitmap",
            "bitmap": mi.Bitmap(np.ascontiguousarray(texels)),
            "raw": True,
            "filter_type": "nearest",
            "wrap_mode": "clamp",
        })
        y = 0.2126 * texels[..., 0] + 0.7152 * texels[..., 1] + 0.0722 * texels[..., 2]
        y = np.where(y > 0, y, 1e-3 * texels.max(axis=-1))
        sin_t = np.sin(math.pi * (np.arange(self.h) + 0.5) / self.h)
        weights = (y.astype(np.float64) * sin_t[:, None]).ravel()
        if not weights.sum() > 0:
            weights = np.ones_like(weights)
        self.dist = mi.DiscreteDistribution(mi.Float(weights.astype(np.float32)) if dr.is_jit_v(mi.Float) else weights.astype(np.float32).tolist())
        self.radius = float(props["radius"])
        self.m_flags = mi.EmitterFlags.Infinite | mi.EmitterFlags.SpatiallyVarying

    def _uv(self, d):
        u = dr.atan2(d.x, -d.z) * (0.5 / math.pi)
        u = u - dr.floor(u)
        u = dr.select(u < 1.0, u, 0.0)
        v = dr.safe_acos(d.y) * (1.0 / math.pi)
        return mi.Point2f(u, v)

    def _radiance(self, uv, active=True):
        si = _zeros(mi.SurfaceInteraction3f)
        si.uv = uv
        return self.texture.eval(si, active)

    def _pdf(self, d, uv):
        sin_t = dr.sqrt(dr.maximum(d.x * d.x + d.z * d.z, 0.0))
        i = mi.UInt32(dr.minimum(mi.UInt32(uv.x * self.w), self.w - 1))
        j = mi.UInt32(dr.minimum(mi.UInt32(uv.y * self.h), self.h - 1))
        pmf = self.dist.eval_pmf_normalized(j * self.w + i)
        pdf = pmf * (self.w * self.h) / (2.0 * math.pi * math.pi * sin_t)
        return dr.select(sin_t > 0, pdf, 0.0)

    def eval(self, si, active=True):
        d = -si.wi
        return dr.select(active, self._radiance(self._uv(d), active), 0.0)

    def sample_direction(self, it, sample, active=True):
        idx, rx = self.dist.sample_reuse(sample.x, active)
        j = idx // self.w
        i = idx - j * self.w
        uv = mi.Point2f((mi.Float(i) + rx) / self.w, (mi.Float(j) + sample.y) / self.h)
        phi, theta = 2.0 * math.pi * uv.x, math.pi * uv.y
        st, ct = dr.sin(theta), dr.cos(theta)
        d = mi.Vector3f(dr.sin(phi) * st, ct, -dr.cos(phi) * st)
        pmf = self.dist.eval_pmf_normalized(idx)
        pdf = pmf * (self.w * self.h) / (2.0 * math.pi * math.pi * st)
        ok = active & (st > 0) & (pdf > 0)
        ds = _zeros(mi.DirectionSample3f)
        ds.d = d
        ds.dist = 4.0 * self.radius
        ds.p = it.p + d * ds.dist
        ds.n = -d
        ds.uv = uv
        ds.time = it.time
        ds.pdf = dr.select(ok, pdf, 0.0)
        ds.delta = False
        weight = self._radiance(uv, ok) / dr.select(ok, pdf, 1.0)
        return ds, dr.select(ok, weight, 0.0)

    def pdf_direction(self, it, ds, active=True):
        return dr.select(active, self._pdf(ds.d, self._uv(ds.d)), 0.0)

    def eval_direction(self, it, ds, active=True):
        return dr.select(active, self._radiance(self._uv(ds.d), active), 0.0)

    def sample_ray(self, time, sample1, sample2, sample3, active=True):
        raise NotImplementedError("gltf_envmap: light tracing is not supported")

    def sample_position(self, time, sample, active=True):
        raise NotImplementedError("gltf_envmap: position sampling is not supported")

    def bbox(self):
        return mi.ScalarBoundingBox3f()

    def traverse(self, callback):
        pass

    def to_string(self):
        return f"GltfEnvmap[{self.w}x{self.h}]"


_registered = False


def register():
    global _registered
    if not _registered:
        mi.register_emitter("gltf_spot", lambda props: GltfSpot(props))
        mi.register_emitter("gltf_envmap", lambda props: GltfEnvmap(props))
        _registered = True


def spot_dict(light, origin):
    """The `gltf_spot` dict for an exported spot light (local frame)."""
    register()
    p = (np.asarray(light["position"], np.float64) - origin).tolist()
    return {
        "type": "gltf_spot",
        "position": [float(x) for x in p],
        "direction": [float(x) for x in light["direction"]],
        "intensity": [float(x) for x in light["intensity"]],
        "inner_cone_angle": float(light["inner_cone_angle"]),
        "outer_cone_angle": float(light["outer_cone_angle"]),
    }


def envmap_dict(texels, scale, radius):
    """The `gltf_envmap` dict for our map `texels` (H, W, 3) times `scale` (RGB); `radius`
    bounds the scene (the local frame's origin to its farthest vertex)."""
    register()
    t = np.asarray(texels, np.float32)[..., :3] * np.asarray(scale[:3], np.float32)[None, None, :]
    return {"type": "gltf_envmap", "bitmap": mi.Bitmap(np.ascontiguousarray(t)), "radius": float(radius)}
