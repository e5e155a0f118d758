"""glTF 2.0 metallic-roughness BRDF as a Mitsuba 3 BSDF plugin (`gltf`), written from the doc
comments of `crates/pathtracer/src/material.rs` (`MetallicRoughness`), so that both renderers
integrate the same model. Works in scalar and vectorised variants (only Dr.Jit operations).

Naming: Mitsuba's `si.wi` (towards the viewer) is glTF's V (our `wo`); the `wo` argument of
`eval`/`pdf` (towards the light) is glTF's L (our `wi`). Local shading frame, N = z.

    D(H)   = a2 / (pi (Hx^2 + Hy^2 + Hz^2 a2)^2),         a = max(roughness^2, 1e-3)
    sd(c)  = c + sqrt(a2 + (1 - a2) c^2)
    Vis    = 1 / (sd(N.L) sd(N.V))
    w5     = (1 - V.H)^5
    F_d    = s (0.04 + 0.96 w5);  F_m = rho + (1 - rho) w5
    f      = (1 - m) ((1 - F_d) rho / pi + F_d D Vis) + m F_m D Vis
    eval   = f N.L  (0 unless N.V > 0 and N.L > 0)

Sampling: specular lobe (GGX visible normals, Heitz 2018) with probability P_s, cosine lobe
otherwise; pdf = P_s D / (2 sd(N.V)) + (1 - P_s) N.L / pi, with P_s as in the Rust docs
(clamp(E_s / (E_s + E_d), 0.1, 0.9), 1 without a diffuse lobe, 0 without a specular one).
Lobe choice uses `sample1`, the direction `sample2` (a different but equally valid use of the
random numbers than ours: only the distribution matters).
"""

import math

import drjit as dr
import mitsuba as mi

MIN_ALPHA = 1e-3
F0 = 0.04
INV_PI = 1.0 / math.pi


def luminance(c):
    return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]


class GltfBSDF(mi.BSDF):
    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        bc = props["base_color"]
        # An `rgb` value arrives as a colour, a texture (bitmap, mesh_attribute) as an object.
        self.base_color = bc if isinstance(bc, mi.Texture) else None
        self.base_color_const = None if self.base_color is not None else mi.Color3f(bc[0], bc[1], bc[2])
        self.metallic = float(props["metallic"])
        r = min(max(float(props["roughness"]), 0.0), 1.0)
        self.alpha = max(r * r, MIN_ALPHA)
        self.specular = min(max(float(props["specular"]), 0.0), 1.0)
        self.metallic = min(max(self.metallic, 0.0), 1.0)
        front = mi.BSDFFlags.FrontSide
        self.m_components = [mi.BSDFFlags.DiffuseReflection | front, mi.BSDFFlags.GlossyReflection | front]
        self.m_flags = self.m_components[0] | self.m_components[1]

    # --- the model -----------------------------------------------------------------------
    def rho(self, si, active):
        if self.base_color is None:
            return dr.clip(self.base_color_const, 0.0, 1.0)
        return dr.clip(self.base_color.eval(si, active), 0.0, 1.0)

    def d(self, h):
        a2 = self.alpha * self.alpha
        den = h.x * h.x + h.y * h.y + h.z * h.z * a2
        return dr.select(h.z > 0, a2 / (math.pi * den * den), 0.0)

    def sd(self, c):
        a2 = self.alpha * self.alpha
        return c + dr.sqrt(a2 + (1.0 - a2) * c * c)

    def f(self, rho, v, l):
        h = dr.normalize(v + l)
        vh = dr.clip(dr.dot(v, h), 0.0, 1.0)
        w5 = dr.power(1.0 - vh, 5.0)
        spec = self.d(h) / (self.sd(l.z) * self.sd(v.z))
        fd = self.specular * (F0 + (1.0 - F0) * w5)
        dielectric = rho * ((1.0 - fd) * INV_PI) + fd * spec
        metal = (rho + (1.0 - rho) * w5) * spec
        val = dielectric * (1.0 - self.metallic) + metal * self.metallic
        return dr.select((v.z > 0) & (l.z > 0), val, 0.0)

    def p_spec(self, rho, v):
        m, s = self.metallic, self.specular
        has_diffuse = (m < 1.0) & (dr.max(rho) > 0.0)
        has_specular = (m > 0.0) or (s > 0.0)
        w5 = dr.power(1.0 - dr.clip(v.z, 0.0, 1.0), 5.0)
        fd = s * (F0 + (1.0 - F0) * w5)
        es = (1.0 - m) * fd + m * luminance(rho + (1.0 - rho) * w5)
        ed = (1.0 - m) * (1.0 - fd) * luminance(rho)
        p = dr.clip(es / (es + ed), 0.1, 0.9)
        p = dr.select(dr.isfinite(p), p, 0.5)
        if not has_specular:
            return dr.zeros(mi.Float) if isinstance(v.z, mi.Float) else 0.0
        return dr.select(has_diffuse, p, 1.0)

    def pdf_l(self, rho, v, l):
        ps = self.p_spec(rho, v)
        h = dr.normalize(v + l)
        pdf = ps * self.d(h) / (2.0 * self.sd(v.z)) + (1.0 - ps) * l.z * INV_PI
        return dr.select((v.z > 0) & (l.z > 0), pdf, 0.0)

    def sample_visible_normal(self, v, u):
        a = self.alpha
        vh = dr.normalize(mi.Vector3f(a * v.x, a * v.y, v.z))
        lensq = vh.x * vh.x + vh.y * vh.y
        t1 = dr.select(lensq > 0, mi.Vector3f(-vh.y, vh.x, 0.0) * dr.rsqrt(dr.maximum(lensq, 1e-30)), mi.Vector3f(1.0, 0.0, 0.0))
        t2 = dr.cross(vh, t1)
        r = dr.sqrt(u.x)
        phi = 2.0 * math.pi * u.y
        p1 = r * dr.cos(phi)
        s = 0.5 * (1.0 + vh.z)
        p2 = (1.0 - s) * dr.sqrt(dr.maximum(1.0 - p1 * p1, 0.0)) + s * r * dr.sin(phi)
        nh = p1 * t1 + p2 * t2 + dr.sqrt(dr.maximum(1.0 - p1 * p1 - p2 * p2, 0.0)) * vh
        return dr.normalize(mi.Vector3f(a * nh.x, a * nh.y, dr.maximum(nh.z, 0.0)))

    # --- Mitsuba's interface -----------------------------------------------------------
    def sample(self, ctx, si, sample1, sample2, active=True):
        v = si.wi
        rho = self.rho(si, active)
        ps = self.p_spec(rho, v)
        spec = sample1 < ps
        h = self.sample_visible_normal(v, sample2)
        l_spec = dr.normalize(2.0 * dr.dot(v, h) * h - v)
        l_diff = mi.warp.square_to_cosine_hemisphere(sample2)
        l = dr.select(spec, l_spec, l_diff)
        pdf = self.pdf_l(rho, v, l)
        val = self.f(rho, v, l) * l.z
        ok = active & (v.z > 0) & (l.z > 0) & (pdf > 0)
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = l
        bs.pdf = dr.select(ok, pdf, 0.0)
        bs.eta = 1.0
        bs.sampled_type = dr.select(spec, mi.UInt32(+mi.BSDFFlags.GlossyReflection), mi.UInt32(+mi.BSDFFlags.DiffuseReflection))
        bs.sampled_component = dr.select(spec, mi.UInt32(1), mi.UInt32(0))
        weight = dr.select(ok, val / dr.select(ok, pdf, 1.0), 0.0)
        return bs, mi.Color3f(weight)

    def eval(self, ctx, si, wo, active=True):
        rho = self.rho(si, active)
        return mi.Color3f(dr.select(active, self.f(rho, si.wi, wo) * wo.z, 0.0))

    def pdf(self, ctx, si, wo, active=True):
        rho = self.rho(si, active)
        return dr.select(active, self.pdf_l(rho, si.wi, wo), 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

    def traverse(self, callback):
        pass

    def to_string(self):
        return f"GltfBSDF[metallic={self.metallic}, alpha={self.alpha}, specular={self.specular}]"


_registered = False


def register():
    global _registered
    if not _registered:
        mi.register_bsdf("gltf", lambda props: GltfBSDF(props))
        _registered = True


def bsdf_dict(mi_module, mat, textures, has_vertex_colors):
    """The `gltf` BSDF dict for an exported material (see scene_loader)."""
    import scene_loader

    register()
    if mat["metallic_roughness_texture"] is not None:
        raise scene_loader.Unsupported(f"material {mat['name']}: metallic-roughness texture")
    if mat["normal_texture"] is not None:
        raise scene_loader.Unsupported(f"material {mat['name']}: normal map")
    return {
        "type": "gltf",
        "base_color": scene_loader.lambert_reflectance(mi_module, mat, textures, has_vertex_colors),
        "metallic": float(mat["metallic"]),
        "roughness": float(mat["roughness"]),
        "specular": float(mat.get("specular", 1.0)),
    }
