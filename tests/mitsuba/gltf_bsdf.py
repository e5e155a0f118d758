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

Layers (KHR_materials_sheen, then KHR_materials_clearcoat on top), written from the extension
READMEs and the formulas in crates/pathtracer/src/material/layered.rs's docs:

    sheen: a_s = max(sheen_roughness, 0.07)^2, D_s = (2 + 1/a_s) sin^(1/a_s)(theta_h) / (2 pi),
           V_s = 1 / ((1 + lam(N.V) + lam(N.L)) 4 N.V N.L) with the README's Charlie lambda fit,
           E(mu) = the lobe's directional albedo (numpy table built here at load, Gauss-Legendre
           in cos(theta_L) x uniform phi, bilinear lookup), Ê = min(E, 1),
           under = S D_s V_s Ê/E + f (1 - max(S) Ê)   (E and Ê at N.V)
    coat:  Fc = 0.04 + 0.96 (1 - Nc.V)^5, coat = D(a_c, Nc.H) Vis(a_c, Nc.L, Nc.V) (GGX, F = 1),
           a_c = max(clearcoat_roughness^2, 1e-3), Nc = the interpolated normal mapped by the
           clearcoat normal texture if any, else unmapped when the base is normal-mapped, else N
           (flipped and bent as N)
    eval = (1 - c Fc) under N.L + c Fc coat Nc.L

Their sampling here is this plugin's own: coat visible normals with probability c Fc, uniform
hemisphere with (1 - c Fc) max(S) E, the base lobes otherwise.

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
        opt = lambda key, default: props[key] if props.has_property(key) else default
        self.clearcoat = float(opt("clearcoat", 0.0))
        self.clearcoat_roughness = float(opt("clearcoat_roughness", 0.0))
        self.clearcoat_texture = opt("clearcoat_texture", None)
        self.clearcoat_roughness_texture = opt("clearcoat_roughness_texture", None)
        sc = opt("sheen_color", [0.0, 0.0, 0.0])
        self.sheen_color = [float(sc[0]), float(sc[1]), float(sc[2])]
        self.sheen_roughness = float(opt("sheen_roughness", 0.0))
        self.sheen_color_texture = opt("sheen_color_texture", None)
        self.sheen_roughness_texture = opt("sheen_roughness_texture", None)
        self.clearcoat_normal_texture = opt("clearcoat_normal_texture", None)
        self.clearcoat_normal_scale = float(opt("clearcoat_normal_scale", 1.0))
        self.has_coat = self.clearcoat > 0.0
        self.has_sheen = max(self.sheen_color) > 0.0
        if self.has_sheen:
            self.sheen_table = sheen_albedo_table()
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
            ns = self.mapped(si, active, ns, self.normal_texture, self.normal_scale)
        n = dr.select(flipped, -ns, ns)
        cv = dr.dot(n, v)
        bent = n + (MIN_SHADING_COS - cv) * v
        bl = dr.norm(bent)
        bent = dr.select(bl > 0, bent / dr.select(bl > 0, bl, 1.0), v)
        n = dr.select(cv >= MIN_SHADING_COS, n, bent)
        return mi.Frame3f(n), ng_f, v

    @staticmethod
    def mapped(si, active, ns, texture, scale):
        """ns normal-mapped by `texture` with `scale`, in the exported corner tangents' frame."""
        t = si.shape.eval_attribute_3("vertex_tangent", si, active)
        w = si.shape.eval_attribute_1("vertex_tangent_w", si, active)
        t = t - ns * dr.dot(ns, t)
        tl = dr.norm(t)
        t_ok = (tl > 0) & dr.isfinite(tl)
        t = t / dr.select(t_ok, tl, 1.0)
        b = dr.cross(ns, t) * dr.select(w < 0, -1.0, 1.0)
        c = mi.Vector3f(texture.eval(si, active)) * 2.0 - 1.0
        c = mi.Vector3f(c.x * scale, c.y * scale, c.z)
        cl = dr.norm(c)
        c = c / dr.select(cl > 0, cl, 1.0)
        m = t * c.x + b * c.y + ns * c.z
        ml = dr.norm(m)
        ok = t_ok & (cl > 0) & (ml > 0) & dr.isfinite(ml)
        return dr.select(ok, m / dr.select(ml > 0, ml, 1.0), ns)

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

    # --- the layers --------------------------------------------------------------------
    def layers(self, si, active):
        """(clearcoat, a_c, sheen colour, sheen roughness) at the hit."""
        c = mi.Float(self.clearcoat)
        if self.clearcoat_texture is not None:
            c = c * self.clearcoat_texture.eval(si, active)[0]
        cr = mi.Float(self.clearcoat_roughness)
        if self.clearcoat_roughness_texture is not None:
            cr = cr * self.clearcoat_roughness_texture.eval(si, active)[1]
        cr = dr.clip(cr, 0.0, 1.0)
        s = mi.Color3f(self.sheen_color[0], self.sheen_color[1], self.sheen_color[2])
        if self.sheen_color_texture is not None:
            s = s * self.sheen_color_texture.eval(si, active)
        sr = mi.Float(self.sheen_roughness)
        if self.sheen_roughness_texture is not None:
            sr = sr * self.sheen_roughness_texture.eval(si, active)[0]
        return dr.clip(c, 0.0, 1.0), dr.maximum(cr * cr, MIN_ALPHA), dr.clip(s, 0.0, 1.0), dr.clip(sr, 0.0, 1.0)

    def coat_normal(self, si, fr, v_w, active=True):
        """The coat's normal (world): its own normal map's, else the unmapped interpolated
        one where the base is normal-mapped, else the frame's; flipped and bent like the
        frame's."""
        if self.normal_texture is None and self.clearcoat_normal_texture is None:
            return fr.n
        ng = mi.Vector3f(si.n)
        ng_f = dr.select(dr.dot(ng, v_w) < 0, -ng, ng)
        ns_front = mi.Vector3f(si.sh_frame.n)
        ns = ns_front
        if self.clearcoat_normal_texture is not None:
            ns = self.mapped(si, active, ns, self.clearcoat_normal_texture, self.clearcoat_normal_scale)
        n = dr.select(dr.dot(ns_front, ng_f) < 0, -ns, ns)
        cv = dr.dot(n, v_w)
        bent = n + (MIN_SHADING_COS - cv) * v_w
        bl = dr.norm(bent)
        bent = dr.select(bl > 0, bent / dr.select(bl > 0, bl, 1.0), v_w)
        return dr.select(cv >= MIN_SHADING_COS, n, bent)

    def sheen_e(self, mu, r):
        return table_lookup(self.sheen_table, mu, r)

    def layered(self, si, active, fr, v_w, l_w, rho, m, a, fres):
        """(eval = f cos, pdf) of the whole layered material for world directions V, L."""
        v, l = fr.to_local(v_w), fr.to_local(l_w)
        base = self.f(rho, m, a, fres, v, l)
        base_pdf = self.pdf_l(rho, m, a, fres, v, l)
        c, ac, s, sr = self.layers(si, active)
        p_coat, p_sheen, under = 0.0, 0.0, base
        cf = 0.0
        if self.has_sheen:
            e = self.sheen_e(dr.clip(v.z, 0.0, 1.0), sr)
            se = dr.max(s) * dr.minimum(e, 1.0)
            h = dr.normalize(v + l)
            # Where the fitted lambda lets the lobe's albedo exceed 1, the lobe is divided by it.
            lobe = charlie_d(h.z, sr) * charlie_vis(v.z, l.z, sr) / dr.maximum(e, 1.0)
            under = s * lobe + base * (1.0 - se)
            p_sheen = se
        val = under * l.z
        pdf = 0.0
        if self.has_coat:
            nc = self.coat_normal(si, fr, v_w, active)
            cv, cl = dr.dot(nc, v_w), dr.dot(nc, l_w)
            cf = dr.select(cv > 0, c * (0.04 + 0.96 * dr.power(1.0 - dr.minimum(cv, 1.0), 5.0)), 0.0)
            hc = dr.normalize(v_w + l_w)
            ch = dr.dot(nc, hc)
            a2 = ac * ac
            dd = ch * ch * (a2 - 1.0) + 1.0
            d = dr.select(ch > 0, a2 / (math.pi * dd * dd), 0.0)
            den = self.sd(ac, dr.maximum(cl, 0.0)) * self.sd(ac, dr.maximum(cv, 1e-9))
            coat = dr.select((cl > 0) & (cv > 0), d / dr.select(den > 0, den, 1.0) * cl, 0.0)
            val = val * (1.0 - cf) + cf * coat
            p_coat = cf
            pdf = pdf + cf * dr.select((cl > 0) & (cv > 0), d / (2.0 * self.sd(ac, dr.maximum(cv, 1e-9))), 0.0)
        p_sheen = (1.0 - p_coat) * p_sheen
        p_base = 1.0 - p_coat - p_sheen
        pdf = pdf + p_sheen * (0.5 / math.pi) + p_base * base_pdf
        ok = (v.z > 0) & (l.z > 0)
        return dr.select(ok, val, 0.0), dr.select(ok, pdf, 0.0), (p_coat, p_sheen)

    def sample_layered(self, si, sample1, sample2, active):
        rho, m, a, fres = self.params(si, active)
        fr, ng_f, v_w = self.frame(si, active)
        v = fr.to_local(v_w)
        c, ac, s, sr = self.layers(si, active)
        p_coat = 0.0
        if self.has_coat:
            nc = self.coat_normal(si, fr, v_w, active)
            cv = dr.dot(nc, v_w)
            p_coat = dr.select(cv > 0, c * (0.04 + 0.96 * dr.power(1.0 - dr.minimum(cv, 1.0), 5.0)), 0.0)
        p_sheen = 0.0
        if self.has_sheen:
            p_sheen = (1.0 - p_coat) * dr.max(s) * dr.minimum(self.sheen_e(dr.clip(v.z, 0.0, 1.0), sr), 1.0)
        # The base's own choice of lobe and direction.
        ub = (sample1 - p_coat - p_sheen) / dr.maximum(1.0 - p_coat - p_sheen, 1e-9)
        ps = self.p_spec(rho, m, fres, v)
        h = self.sample_visible_normal(a, v, sample2)
        l_base = dr.select(ub < ps, dr.normalize(2.0 * dr.dot(v, h) * h - v), mi.warp.square_to_cosine_hemisphere(sample2))
        l_w = fr.to_world(l_base)
        if self.has_sheen:
            l_w = dr.select(sample1 < p_coat + p_sheen, fr.to_world(mi.warp.square_to_uniform_hemisphere(sample2)), l_w)
        if self.has_coat:
            cfr = mi.Frame3f(nc)
            vc = cfr.to_local(v_w)
            hc = self.sample_visible_normal(ac, vc, sample2)
            l_w = dr.select(sample1 < p_coat, cfr.to_world(dr.normalize(2.0 * dr.dot(vc, hc) * hc - vc)), l_w)
        val, pdf, _ = self.layered(si, active, fr, v_w, l_w, rho, m, a, fres)
        ok = active & (pdf > 0) & (dr.dot(l_w, ng_f) > 0)
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = si.to_local(l_w)
        bs.pdf = dr.select(ok, pdf, 0.0)
        bs.eta = 1.0
        bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
        bs.sampled_component = mi.UInt32(1)
        return bs, mi.Color3f(dr.select(ok, val / dr.select(ok, pdf, 1.0), 0.0))

    # --- Mitsuba's interface -----------------------------------------------------------
    def sample(self, ctx, si, sample1, sample2, active=True):
        if self.has_coat or self.has_sheen:
            return self.sample_layered(si, sample1, sample2, active)
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
        ok = active & (dr.dot(l_w, ng_f) > 0)
        if self.has_coat or self.has_sheen:
            val, pdf, _ = self.layered(si, active, fr, v_w, l_w, rho, m, a, fres)
            return mi.Color3f(dr.select(ok, val, 0.0)), dr.select(ok, pdf, 0.0)
        v, l = fr.to_local(v_w), fr.to_local(l_w)
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


SHEEN_MIN_ROUGHNESS = 0.07


def charlie_d(nh, r):
    """The README's Charlie distribution with alpha_g = max(r, 0.07)^2."""
    ag = dr.maximum(r, SHEEN_MIN_ROUGHNESS)
    ag = ag * ag
    sin2 = dr.maximum(1.0 - nh * nh, 0.0)
    return (2.0 + 1.0 / ag) * dr.power(sin2, 0.5 / ag) / (2.0 * math.pi)


def charlie_lambda(x, r):
    ag = dr.maximum(r, SHEEN_MIN_ROUGHNESS)
    ag = ag * ag
    t = (1.0 - ag) * (1.0 - ag)

    def l_fit(y):
        a = 21.5473 + (25.3245 - 21.5473) * t
        b = 3.82987 + (3.32435 - 3.82987) * t
        c = 0.19823 + (0.16801 - 0.19823) * t
        d = -1.97760 + (-1.27393 + 1.97760) * t
        e = -4.32054 + (-4.85967 + 4.32054) * t
        return a / (1.0 + b * dr.power(dr.maximum(y, 0.0), c)) + d * y + e

    return dr.select(x < 0.5, dr.exp(l_fit(x)), dr.exp(2.0 * l_fit(0.5) - l_fit(1.0 - x)))


def charlie_vis(nv, nl, r):
    ok = (nv > 0) & (nl > 0)
    den = (1.0 + charlie_lambda(nv, r) + charlie_lambda(nl, r)) * 4.0 * nv * nl
    return dr.select(ok, 1.0 / dr.select(ok, den, 1.0), 0.0)


_sheen_table = None
SHEEN_TABLE_MU = 65
SHEEN_TABLE_R = 32


def sheen_albedo_table():
    """E(mu, r) on mu = t^2 for 65 t over [0, 1] x r log-spaced over [0.07, 1] (32 nodes), with
    numpy: Gauss-Legendre (64 nodes) in cos(theta_L) times 256 uniform phi steps."""
    global _sheen_table
    if _sheen_table is not None:
        return _sheen_table
    z, wz = np.polynomial.legendre.leggauss(64)
    z, wz = 0.5 * (z + 1.0), 0.5 * wz
    phi = (np.arange(256) + 0.5) * (2.0 * math.pi / 256)
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    st = np.sqrt(1.0 - zz * zz)
    lx, ly = st * np.cos(pp), st * np.sin(pp)
    w = wz[:, None] * (2.0 * math.pi / 256)

    def lam(x, ag):
        t = (1.0 - ag) ** 2
        a, b, c = 21.5473 + 3.7772 * t, 3.82987 - 0.50552 * t, 0.19823 - 0.03022 * t
        d, e = -1.97760 + 0.70367 * t, -4.32054 - 0.53913 * t
        lf = lambda y: a / (1.0 + b * np.power(np.maximum(y, 0.0), c)) + d * y + e
        return np.where(x < 0.5, np.exp(lf(x)), np.exp(2.0 * lf(0.5) - lf(1.0 - x)))

    table = np.zeros((SHEEN_TABLE_R, SHEEN_TABLE_MU))
    for j in range(SHEEN_TABLE_R):
        r = SHEEN_MIN_ROUGHNESS ** (1.0 - j / (SHEEN_TABLE_R - 1))
        ag = r * r
        for i in range(SHEEN_TABLE_MU):
            mu = max((i / (SHEEN_TABLE_MU - 1)) ** 2, 1e-4)
            vx = math.sqrt(1.0 - mu * mu)
            hx, hy, hz = vx + lx, ly, mu + zz
            nh2 = hz * hz / (hx * hx + hy * hy + hz * hz)
            dd = (2.0 + 1.0 / ag) * np.power(np.maximum(1.0 - nh2, 0.0), 0.5 / ag) / (2.0 * math.pi)
            # V_s N.L = 1 / ((1 + lam(mu) + lam(z)) 4 mu)
            vis_cos = 1.0 / ((1.0 + lam(mu, ag) + lam(zz, ag)) * 4.0 * mu)
            table[j, i] = float(np.sum(dd * vis_cos * w))
    _sheen_table = table
    return table


def table_lookup(table, mu, r):
    """Bilinear lookup of E in the table in (sqrt(mu), log r) (r clamped to [0.07, 1])."""
    nr, nm = table.shape
    x = dr.sqrt(dr.clip(mu, 0.0, 1.0)) * (nm - 1)
    y = dr.maximum((1.0 - dr.log(dr.clip(r, SHEEN_MIN_ROUGHNESS, 1.0)) / math.log(SHEEN_MIN_ROUGHNESS)) * (nr - 1), 0.0)
    if isinstance(x, float):
        i, j = min(int(x), nm - 2), min(int(y), nr - 2)
        fx, fy = x - i, y - j
        r0 = table[j, i] + (table[j, i + 1] - table[j, i]) * fx
        r1 = table[j + 1, i] + (table[j + 1, i + 1] - table[j + 1, i]) * fx
        return float(r0 + (r1 - r0) * fy)
    flat = mi.Float(table.ravel().astype(np.float32))
    i, j = dr.minimum(mi.UInt32(x), nm - 2), dr.minimum(mi.UInt32(y), nr - 2)
    fx, fy = x - mi.Float(i), y - mi.Float(j)
    g = lambda jj, ii: dr.gather(mi.Float, flat, jj * nm + ii)
    r0 = g(j, i) + (g(j, i + 1) - g(j, i)) * fx
    r1 = g(j + 1, i) + (g(j + 1, i + 1) - g(j + 1, i)) * fx
    return r0 + (r1 - r0) * fy


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
    cc = mat.get("clearcoat")
    if cc is not None:
        cn = cc.get("normal_texture")
        if cn is not None:
            base_map = mat["normal_texture"]
            if base_map is not None and base_map["tex_coord"] != cn["tex_coord"]:
                raise scene_loader.Unsupported(f"material {mat['name']}: base and clearcoat normal maps on different UV sets")
            d["clearcoat_normal_texture"] = scene_loader.bitmap_texture(mi_module, textures[cn["texture"]], cn, [1.0, 1.0, 1.0])
            d["clearcoat_normal_scale"] = float(cc["normal_scale"])
        d["clearcoat"] = float(cc["factor"])
        d["clearcoat_roughness"] = float(cc["roughness"])
        if cc.get("texture") is not None:
            d["clearcoat_texture"] = scene_loader.bitmap_texture(mi_module, textures[cc["texture"]["texture"]], cc["texture"], [1.0, 1.0, 1.0])
        if cc.get("roughness_texture") is not None:
            rt = cc["roughness_texture"]
            d["clearcoat_roughness_texture"] = scene_loader.bitmap_texture(mi_module, textures[rt["texture"]], rt, [1.0, 1.0, 1.0])
    sh = mat.get("sheen")
    if sh is not None:
        d["sheen_color"] = [float(x) for x in sh["color"]]
        d["sheen_roughness"] = float(sh["roughness"])
        if sh.get("color_texture") is not None:
            ct = sh["color_texture"]
            d["sheen_color_texture"] = scene_loader.bitmap_texture(mi_module, textures[ct["texture"]], ct, [1.0, 1.0, 1.0])
        if sh.get("roughness_texture") is not None:
            rt = sh["roughness_texture"]
            alpha = textures[rt["texture"]][..., 3:4]
            d["sheen_roughness_texture"] = scene_loader.bitmap_texture(mi_module, np.repeat(alpha, 3, axis=2), rt, [1.0, 1.0, 1.0])
    nt = mat["normal_texture"]
    if nt is not None:
        d["normal_texture"] = scene_loader.bitmap_texture(mi_module, textures[nt["texture"]], nt, [1.0, 1.0, 1.0])
        d["normal_scale"] = float(mat["normal_scale"])
    return d
