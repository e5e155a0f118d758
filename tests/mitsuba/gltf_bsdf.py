"""glTF 2.0 metallic-roughness BRDF as a Mitsuba 3 BSDF plugin (`gltf`), written from the doc
comments of `crates/pathtracer/src/material.rs` (`MetallicRoughness`), so that both renderers
integrate the same model. Works in scalar and vectorised variants (only Dr.Jit operations).

Naming: Mitsuba's `si.wi` (towards the viewer) is glTF's V (our `wo`); the `wo` argument of
`eval`/`pdf` (towards the light) is glTF's L (our `wi`). Local shading frame, N = z.

    D(H)   = a2 / (pi (Hx^2 + Hy^2 + Hz^2 a2)^2),         a = max(roughness^2, 1e-3)
    sd(c)  = c + sqrt(a2 + (1 - a2) c^2)
    Vis    = 1 / (sd(N.L) sd(N.V))
    w5     = (1 - V.H)^5
    F0     = min(((ior - 1)/(ior + 1))^2 specular_color, 1) s;  F90 = s      (RGB F0)
    F_d    = F0 + (F90 - F0) w5;  F_m = rho + (1 - rho) w5
    f      = (1 - m) ((1 - max(F_d)) rho / pi + F_d D Vis) + m F_m D Vis
    eval   = f N.L  (0 unless N.V > 0 and N.L > 0)

Shading frame (integrator.rs / material.rs `normal_mapped`, `shading_frame`), in world space:
ns = the interpolated normal (Mitsuba's sh_frame.n), normal-mapped when the material has a
normal texture: c = normalize((2 tex - 1) (scale, scale, 1)), T = the interpolated corner
tangent (mesh attribute `vertex_tangent`, orthogonalised to ns), B = (ns x T) w,
ns' = normalize(T c.x + B c.y + ns c.z); flipped when the viewer is on the other side of the
geometric normal than ns; bent towards V when N.V < 1e-3: N = normalize(N + (1e-3 - N.V) V).
Directions L below the geometric surface on the viewer's side get f = 0 (ours skips them), so
both sides of a surface shade alike (no `twosided` wrapper; ours never hits a single-sided
back face, so the difference cannot show).

Textures: base colour = clamp(factor x texture x COLOR_0, 0, 1); metallic = factor x
texture B, roughness = factor x texture G (`metallic_roughness` bitmap, raw, same filter);
s = specular x specular texture A (`specular_texture`, its A channel as a grey bitmap),
specular_color = factor x specular colour texture RGB (`specular_color_texture`). Every
bitmap carries the KHR_texture_transform matrix as its `to_uv` (scene_loader.bitmap_texture).

Sampling: specular lobe (GGX visible normals, Heitz 2018) with probability P_s, cosine lobe
otherwise; pdf = P_s D / (2 sd(N.V)) + (1 - P_s) N.L / pi, with P_s as in the Rust docs
(clamp(E_s / (E_s + E_d), 0.1, 0.9), 1 without a diffuse lobe, 0 without a specular one).
Lobe choice uses `sample1`, the direction `sample2` (a different but equally valid use of the
random numbers than ours: only the distribution matters).
"""

import math

import drjit as dr
import mitsuba as mi
import numpy as np

MIN_ALPHA = 1e-3
INV_PI = 1.0 / math.pi


def luminance(c):
    return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]


MIN_SHADING_COS = 1e-3


class GltfBSDF(mi.BSDF):
    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        bc = props["base_color"]
        # An `rgb` value arrives as a colour, a texture (bitmap, mesh_attribute) as an object.
        self.base_color = bc if isinstance(bc, mi.Texture) else None
        self.base_color_const = None if self.base_color is not None else mi.Color3f(bc[0], bc[1], bc[2])
        self.metallic = min(max(float(props["metallic"]), 0.0), 1.0)
        self.roughness = min(max(float(props["roughness"]), 0.0), 1.0)
        self.specular = min(max(float(props["specular"]), 0.0), 1.0)
        sc = props["specular_color"] if props.has_property("specular_color") else [1.0, 1.0, 1.0]
        self.specular_color = mi.Color3f(max(sc[0], 0.0), max(sc[1], 0.0), max(sc[2], 0.0))
        ior = float(props["ior"]) if props.has_property("ior") else 1.5
        r = (ior - 1.0) / (ior + 1.0) if math.isfinite(ior) and ior >= 0.0 else 0.2
        self.f0_ior = r * r
        self.specular_texture = props["specular_texture"] if props.has_property("specular_texture") else None
        self.specular_color_texture = props["specular_color_texture"] if props.has_property("specular_color_texture") else None
        self.mr_texture = props["metallic_roughness"] if props.has_property("metallic_roughness") else None
        self.normal_texture = props["normal_texture"] if props.has_property("normal_texture") else None
        self.normal_scale = float(props["normal_scale"]) if props.has_property("normal_scale") else 1.0
        self.metallic_factor = float(props["metallic"])
        self.roughness_factor = float(props["roughness"])
        flags = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
        self.m_components = [mi.BSDFFlags.DiffuseReflection | flags, mi.BSDFFlags.GlossyReflection | flags]
        self.m_flags = self.m_components[0] | self.m_components[1]

    # --- parameters at a hit -------------------------------------------------------------
    def params(self, si, active):
        """(rho, metallic, alpha, (F0, F90)) at the hit."""
        if self.base_color is None:
            rho = dr.clip(self.base_color_const, 0.0, 1.0)
        else:
            rho = dr.clip(self.base_color.eval(si, active), 0.0, 1.0)
        if self.mr_texture is None:
            m = self.metallic
            r = self.roughness
        else:
            t = self.mr_texture.eval(si, active)
            m = dr.clip(self.metallic_factor * t[2], 0.0, 1.0)
            r = dr.clip(self.roughness_factor * t[1], 0.0, 1.0)
        a = dr.maximum(r * r, MIN_ALPHA)
        s = mi.Float(self.specular)
        if self.specular_texture is not None:
            s = dr.clip(s * self.specular_texture.eval(si, active)[0], 0.0, 1.0)
        color = self.specular_color
        if self.specular_color_texture is not None:
            color = color * self.specular_color_texture.eval(si, active)
        f0 = dr.minimum(self.f0_ior * color, 1.0) * s
        return rho, m, a, (f0, s)

    def frame(self, si, active):
        """(our shading frame, the geometric normal on the viewer's side, V) in world space."""
        v = si.to_world(si.wi)
        ng = mi.Vector3f(si.n)
        ng_f = dr.select(dr.dot(ng, v) < 0, -ng, ng)
        ns_front = mi.Vector3f(si.sh_frame.n)
        flipped = dr.dot(ns_front, ng_f) < 0
        ns = ns_front
        if self.normal_texture is not None:
            t = si.shape.eval_attribute_3("vertex_tangent", si, active)
            w = si.shape.eval_attribute_1("vertex_tangent_w", si, active)
            t = t - ns * dr.dot(ns, t)
            tl = dr.norm(t)
            t_ok = (tl > 0) & dr.isfinite(tl)
            t = t / dr.select(t_ok, tl, 1.0)
            b = dr.cross(ns, t) * dr.select(w < 0, -1.0, 1.0)
            c = mi.Vector3f(self.normal_texture.eval(si, active)) * 2.0 - 1.0
            c = mi.Vector3f(c.x * self.normal_scale, c.y * self.normal_scale, c.z)
            cl = dr.norm(c)
            c = c / dr.select(cl > 0, cl, 1.0)
            m = t * c.x + b * c.y + ns * c.z
            ml = dr.norm(m)
            ok = t_ok & (cl > 0) & (ml > 0) & dr.isfinite(ml)
            ns = dr.select(ok, m / dr.select(ml > 0, ml, 1.0), ns)
        n = dr.select(flipped, -ns, ns)
        cv = dr.dot(n, v)
        bent = n + (MIN_SHADING_COS - cv) * v
        bl = dr.norm(bent)
        bent = dr.select(bl > 0, bent / dr.select(bl > 0, bl, 1.0), v)
        n = dr.select(cv >= MIN_SHADING_COS, n, bent)
        return mi.Frame3f(n), ng_f, v

    # --- the model -----------------------------------------------------------------------
    @staticmethod
    def d(a, h):
        a2 = a * a
        den = h.x * h.x + h.y * h.y + h.z * h.z * a2
        return dr.select(h.z > 0, a2 / (math.pi * den * den), 0.0)

    @staticmethod
    def sd(a, c):
        a2 = a * a
        return c + dr.sqrt(a2 + (1.0 - a2) * c * c)

    @staticmethod
    def fresnel_dielectric(fr, w5):
        f0, f90 = fr
        return f0 + (f90 - f0) * w5

    def f(self, rho, m, a, fr, v, l):
        h = dr.normalize(v + l)
        vh = dr.clip(dr.dot(v, h), 0.0, 1.0)
        w5 = dr.power(1.0 - vh, 5.0)
        # Both Smith denominators are > 0 wherever the result is used (v.z > 0, l.z > 0); the
        # guard only keeps scalar variants, which evaluate every lane's expression in Python
        # floats, from raising ZeroDivisionError on directions the select below discards.
        den = self.sd(a, l.z) * self.sd(a, v.z)
        spec = self.d(a, h) / dr.select(den > 0.0, den, 1.0)
        fd = self.fresnel_dielectric(fr, w5)
        dielectric = rho * ((1.0 - dr.max(fd)) * INV_PI) + fd * spec
        metal = (rho + (1.0 - rho) * w5) * spec
        val = dielectric * (1.0 - m) + metal * m
        return dr.select((v.z > 0) & (l.z > 0), val, 0.0)

    def p_spec(self, rho, m, fr, v):
        s = fr[1]
        w5 = dr.power(1.0 - dr.clip(v.z, 0.0, 1.0), 5.0)
        fd = dr.max(self.fresnel_dielectric(fr, w5))
        es = (1.0 - m) * fd + m * luminance(rho + (1.0 - rho) * w5)
        ed = (1.0 - m) * (1.0 - fd) * luminance(rho)
        p = dr.clip(es / (es + ed), 0.1, 0.9)
        p = dr.select(dr.isfinite(p), p, 0.5)
        has_diffuse = (m < 1.0) & (dr.max(rho) > 0.0)
        has_specular = (m > 0.0) | (s > 0.0)
        return dr.select(has_specular, dr.select(has_diffuse, p, 1.0), 0.0)

    def pdf_l(self, rho, m, a, fr, v, l):
        ps = self.p_spec(rho, m, fr, v)
        h = dr.normalize(v + l)
        pdf = ps * self.d(a, h) / (2.0 * self.sd(a, v.z)) + (1.0 - ps) * l.z * INV_PI
        return dr.select((v.z > 0) & (l.z > 0), pdf, 0.0)

    @staticmethod
    def sample_visible_normal(a, v, u):
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
        rho, m, a, fres = self.params(si, active)
        fr, ng_f, v_w = self.frame(si, active)
        v = fr.to_local(v_w)
        ps = self.p_spec(rho, m, fres, v)
        spec = sample1 < ps
        h = self.sample_visible_normal(a, v, sample2)
        l_spec = dr.normalize(2.0 * dr.dot(v, h) * h - v)
        l_diff = mi.warp.square_to_cosine_hemisphere(sample2)
        l = dr.select(spec, l_spec, l_diff)
        l_w = fr.to_world(l)
        pdf = self.pdf_l(rho, m, a, fres, v, l)
        val = self.f(rho, m, a, fres, v, l) * l.z
        ok = active & (v.z > 0) & (l.z > 0) & (pdf > 0) & (dr.dot(l_w, ng_f) > 0)
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = si.to_local(l_w)
        bs.pdf = dr.select(ok, pdf, 0.0)
        bs.eta = 1.0
        bs.sampled_type = dr.select(spec, mi.UInt32(+mi.BSDFFlags.GlossyReflection), mi.UInt32(+mi.BSDFFlags.DiffuseReflection))
        bs.sampled_component = dr.select(spec, mi.UInt32(1), mi.UInt32(0))
        weight = dr.select(ok, val / dr.select(ok, pdf, 1.0), 0.0)
        return bs, mi.Color3f(weight)

    def eval_pdf(self, ctx, si, wo, active=True):
        rho, m, a, fres = self.params(si, active)
        fr, ng_f, v_w = self.frame(si, active)
        l_w = si.to_world(wo)
        v, l = fr.to_local(v_w), fr.to_local(l_w)
        ok = active & (dr.dot(l_w, ng_f) > 0)
        val = dr.select(ok, self.f(rho, m, a, fres, v, l) * l.z, 0.0)
        pdf = dr.select(ok, self.pdf_l(rho, m, a, fres, v, l), 0.0)
        return mi.Color3f(val), pdf

    def eval(self, ctx, si, wo, active=True):
        return self.eval_pdf(ctx, si, wo, active)[0]

    def pdf(self, ctx, si, wo, active=True):
        return self.eval_pdf(ctx, si, wo, active)[1]

    def traverse(self, callback):
        pass

    def to_string(self):
        return f"GltfBSDF[metallic={self.metallic}, roughness={self.roughness}, specular={self.specular}, normal map={self.normal_texture is not None}]"


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
    d = {
        "type": "gltf",
        "base_color": scene_loader.lambert_reflectance(mi_module, mat, textures, has_vertex_colors),
        "metallic": float(mat["metallic"]),
        "roughness": float(mat["roughness"]),
        "specular": float(mat.get("specular", 1.0)),
        "specular_color": [float(x) for x in mat.get("specular_color", [1.0, 1.0, 1.0])],
        "ior": float(mat.get("ior", 1.5)),
    }
    st = mat.get("specular_texture")
    if st is not None:
        alpha = textures[st["texture"]][..., 3:4]
        d["specular_texture"] = scene_loader.bitmap_texture(mi_module, np.repeat(alpha, 3, axis=2), st, [1.0, 1.0, 1.0])
    sct = mat.get("specular_color_texture")
    if sct is not None:
        d["specular_color_texture"] = scene_loader.bitmap_texture(mi_module, textures[sct["texture"]], sct, [1.0, 1.0, 1.0])
    mr = mat["metallic_roughness_texture"]
    if mr is not None:
        d["metallic_roughness"] = scene_loader.bitmap_texture(mi_module, textures[mr["texture"]], mr, [1.0, 1.0, 1.0])
    nt = mat["normal_texture"]
    if nt is not None:
        d["normal_texture"] = scene_loader.bitmap_texture(mi_module, textures[nt["texture"]], nt, [1.0, 1.0, 1.0])
        d["normal_scale"] = float(mat["normal_scale"])
    return d
