"""Mitsuba 3 cross-check of our path tracer (started by `cargo xtask crosscheck`).

Inputs: an export folder (`pathtracer::export::export_scene`: the scene as our renderer
loaded it, the cameras, the settings) and our reference renders of the same views
(`pathtracer::export::write_reference`: mean colour, variance of the mean from G independent
groups, ground truth at the pixel-centre rays).

For every view, Mitsuba renders the same scene with the same spp, split into the same number
G of independent groups (different seeds), so both sides estimate the variance of their mean
the same way: var(mean) = sum_g (x_g - mean)^2 / (G (G - 1)). Pixel-centre rays are generated
with `dataset::Camera::pixel_ray`'s formula and intersected with `scene.ray_intersect`.

Pass criteria (per scene, all views together):
- image mean per channel within 1 % of ours, or within 3 sigma of the noise if larger;
- at most 0.5 % of pixels with any channel beyond 4 sigma, sigma^2 = var_ours + var_mitsuba;
- pixel-centre distance and z-depth equal to 1e-4 relative wherever both hit;
- pixel-centre hit masks agree on at least 99.9 % of pixels;
- with an environment map: Mitsuba's own `envmap` and the `gltf_envmap` plugin both return
  our radiance (1e-4 relative) at random directions inside our texels (orientation check).

Writes <out>/crosscheck.json, <out>/crosscheck.md and per view <out>/view_<k>_side_by_side.png
(ours | Mitsuba | 4 x |difference|) and <out>/view_<k>_zscore.png (red: Mitsuba brighter,
blue: ours brighter, full at 4 sigma). Exits 1 when a criterion fails, 2 on unsupported input, 3 on a harness error.
"""

import argparse
import json
import math
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import scene_loader  # noqa: E402

MEAN_REL_TOL = 0.01
MEAN_SIGMAS = 3.0
PIXEL_SIGMAS = 4.0
PIXEL_OUTLIER_FRACTION = 0.005
DEPTH_REL_TOL = 1e-4
MASK_AGREEMENT = 0.999
FLOAT_RTOL = 1e-5


def parse_args():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--export", required=True, help="export folder (scene.json + arrays)")
    p.add_argument("--ours", required=True, help="folder with our view_<k>_*.npy reference renders")
    p.add_argument("--out", required=True, help="report folder")
    p.add_argument("--groups", type=int, required=True, help="independent groups per view (as ours)")
    p.add_argument("--variant", default="scalar_rgb", help="Mitsuba variant (default scalar_rgb)")
    p.add_argument("--seed", type=int, default=1000, help="first Mitsuba seed")
    return p.parse_args()


def load_ours(folder, k):
    f = lambda name: np.load(os.path.join(folder, f"view_{k}_{name}.npy"))  # noqa: E731
    return {n: f(n) for n in ["mean", "var", "depth", "distance", "alpha", "normal"]}


def render_mitsuba(mi, scene, spp_total, groups, seed):
    spp = spp_total // groups
    s = s2 = None
    for g in range(groups):
        img = np.array(mi.render(scene, spp=spp, seed=seed + g), dtype=np.float64)
        s = img if s is None else s + img
        s2 = img * img if s2 is None else s2 + img * img
    mean = s / groups
    var = np.maximum(s2 / groups - mean * mean, 0.0) * groups / (groups - 1) / groups
    return mean, var


import drjit as dr  # noqa: E402  (after the variant is chosen it is the same module)


def scalar(x):
    """A Python float/bool from a scalar or width-1 vectorised Dr.Jit value."""
    a = np.asarray(x).ravel()
    return a[0].item() if a.size else x


def pixel_center_hits(mi, scene, cam, origin):
    """Mitsuba's hit distance along our pixel-centre rays (0 where nothing is hit)."""
    o, dirs, dz = scene_loader.pixel_center_rays(cam, origin)
    h, w = dirs.shape[:2]
    dist = np.zeros((h, w), np.float64)
    if dr.is_jit_v(mi.Float):  # one wavefront of all pixel-centre rays
        d = dirs.reshape(-1, 3).astype(np.float32)
        n = d.shape[0]
        ray = mi.Ray3f(mi.Point3f(*[mi.Float(np.full(n, x, np.float32)) for x in o]), mi.Vector3f(mi.Float(d[:, 0]), mi.Float(d[:, 1]), mi.Float(d[:, 2])))
        si = scene.ray_intersect(ray)
        t = np.asarray(si.t, np.float64)
        valid = np.asarray(si.is_valid(), bool)
        dist = np.where(valid, t, 0.0).reshape(h, w)
        return dist, -dz
    oo = mi.Point3f(*[float(x) for x in o])
    for j in range(h):
        for i in range(w):
            d = dirs[j, i]
            si = scene.ray_intersect(mi.Ray3f(oo, mi.Vector3f(float(d[0]), float(d[1]), float(d[2]))))
            if scalar(si.is_valid()):
                dist[j, i] = float(scalar(si.t))
    return dist, -dz


def camera_agreement(mi, scene, cam, origin):
    """Largest angle (radians) between Mitsuba's camera ray through a pixel centre and ours."""
    sensor = scene.sensors()[0]
    _, dirs, _ = scene_loader.pixel_center_rays(cam, origin)
    h, w = dirs.shape[:2]
    worst = 0.0
    if dr.is_jit_v(mi.Float):
        jj, ii = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
        px = mi.Point2f(mi.Float(((ii.ravel() + 0.5) / w).astype(np.float32)), mi.Float(((jj.ravel() + 0.5) / h).astype(np.float32)))
        ray, _ = sensor.sample_ray(0.0, 0.5, px, mi.Point2f(0.5, 0.5))
        d = np.stack([np.asarray(ray.d[k], np.float64) for k in range(3)], axis=-1)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        c = np.clip(np.sum(d * dirs.reshape(-1, 3), axis=-1), -1.0, 1.0)
        return float(np.max(np.arccos(c)))
    for j in range(h):
        for i in range(w):
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((i + 0.5) / w, (j + 0.5) / h), mi.Point2f(0.5, 0.5))
            d = np.array([scalar(ray.d[0]), scalar(ray.d[1]), scalar(ray.d[2])], np.float64)
            c = float(np.clip(np.dot(d / np.linalg.norm(d), dirs[j, i]), -1.0, 1.0))
            worst = max(worst, math.acos(c))
    return worst


def to_display(img):
    """Linear RGB -> 8-bit sRGB."""
    x = np.clip(img, 0.0, 1.0)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    return (x * 255.0 + 0.5).astype(np.uint8)


def write_png(mi, path, rgb8, min_height=256):
    scale = max(1, int(math.ceil(min_height / rgb8.shape[0])))
    big = np.repeat(np.repeat(rgb8, scale, axis=0), scale, axis=1)
    mi.Bitmap(np.ascontiguousarray(big), mi.Bitmap.PixelFormat.RGB).write(path)


def main():
    args = parse_args()
    import mitsuba as mi

    mi.set_variant(args.variant)
    os.makedirs(args.out, exist_ok=True)
    man, arrays = scene_loader.load_export(args.export)
    origin = np.asarray(man["origin"], np.float64)
    spp = int(man["settings"]["spp"])
    groups = args.groups
    glossy = spot = envmap = None
    try:
        import gltf_bsdf

        glossy = gltf_bsdf.bsdf_dict
    except ImportError:
        pass
    try:
        import gltf_lights

        spot = gltf_lights.spot_dict
        envmap = gltf_lights.envmap_dict
    except ImportError:
        pass

    envmap_error = None
    views = []
    tot = {"sum_ours": np.zeros(3), "sum_mi": np.zeros(3), "var_sum": np.zeros(3), "pixels": 0, "outliers": 0,
           "mask_agree": 0, "both_hit": 0, "max_rel_dist": 0.0, "max_rel_depth": 0.0}
    t0 = time.time()
    for k, cam in enumerate(man["cameras"]):
        try:
            scene = scene_loader.build_scene(mi, man, arrays, k, spp, glossy, spot, envmap)
        except scene_loader.Unsupported as e:
            print(f"crosscheck: unsupported: {e}", file=sys.stderr)
            return 2
        if arrays["environment_map"] is not None and envmap_error is None:
            # Mitsuba's own envmap has our orientation; the plugin rendering it has our lookup.
            envmap_error = max(scene_loader.envmap_agreement(mi, arrays["environment_map"], man["environment"]),
                               scene_loader.envmap_agreement(mi, arrays["environment_map"], man["environment"], scene.environment()))
        ours = load_ours(args.ours, k)
        t = time.time()
        mi_mean, mi_var = render_mitsuba(mi, scene, spp, groups, args.seed + 1000 * k)
        t_render = time.time() - t
        np.save(os.path.join(args.out, f"mitsuba_view_{k}_mean.npy"), mi_mean.astype(np.float32))
        np.save(os.path.join(args.out, f"mitsuba_view_{k}_var.npy"), mi_var.astype(np.float32))
        a, va = ours["mean"][..., :3].astype(np.float64), ours["var"][..., :3].astype(np.float64)
        b, vb = mi_mean[..., :3], mi_var[..., :3]
        h, w = a.shape[:2]
        # sigma also carries f32 rounding (FLOAT_RTOL of the values): a pixel that is
        # deterministic on one side and nearly so on the other (variance ~1e-19 from rounding,
        # e.g. an environment-map background) must agree to rounding, not to that variance.
        sigma = np.sqrt(va + vb + (FLOAT_RTOL * (np.abs(a) + np.abs(b))) ** 2)
        diff = b - a
        # Deterministic pixels (both variances 0 and black) must agree to rounding.
        z = np.where(sigma > 0, diff / np.where(sigma > 0, sigma, 1.0),
                     np.where(np.abs(diff) <= 1e-7, 0.0, np.inf))
        outlier = np.any(np.abs(z) > PIXEL_SIGMAS, axis=-1)

        dist_mi, dz = pixel_center_hits(mi, scene, cam, origin)
        hit_mi = dist_mi > 0
        hit_ours = ours["alpha"] > 0.5
        both = hit_mi & hit_ours
        rel_dist = np.abs(dist_mi - ours["distance"]) / np.maximum(ours["distance"], 1e-30)
        depth_mi = dist_mi * dz
        rel_depth = np.abs(depth_mi - ours["depth"]) / np.maximum(ours["depth"], 1e-30)
        cam_angle = camera_agreement(mi, scene, cam, origin)

        v = {
            "view": k,
            "width": w,
            "height": h,
            "mitsuba_seconds": t_render,
            "mean_ours": a.mean(axis=(0, 1)).tolist(),
            "mean_mitsuba": b.mean(axis=(0, 1)).tolist(),
            "mean_sigma": (np.sqrt((va + vb).sum(axis=(0, 1))) / (h * w)).tolist(),
            "pixels_beyond_4sigma": int(outlier.sum()),
            "pixel_fraction_beyond_4sigma": float(outlier.mean()),
            "z_rms": float(np.sqrt(np.mean(np.where(np.isfinite(z), z, 0.0) ** 2))),
            "hit_mask_agreement": float((hit_mi == hit_ours).mean()),
            "pixels_both_hit": int(both.sum()),
            "max_rel_distance_error": float(rel_dist[both].max()) if both.any() else 0.0,
            "max_rel_depth_error": float(rel_depth[both].max()) if both.any() else 0.0,
            "max_camera_ray_angle_rad": cam_angle,
        }
        views.append(v)
        tot["sum_ours"] += a.sum(axis=(0, 1))
        tot["sum_mi"] += b.sum(axis=(0, 1))
        tot["var_sum"] += (va + vb).sum(axis=(0, 1))
        tot["pixels"] += h * w
        tot["outliers"] += int(outlier.sum())
        tot["mask_agree"] += int((hit_mi == hit_ours).sum())
        tot["both_hit"] += int(both.sum())
        tot["max_rel_dist"] = max(tot["max_rel_dist"], v["max_rel_distance_error"])
        tot["max_rel_depth"] = max(tot["max_rel_depth"], v["max_rel_depth_error"])

        side = np.concatenate([to_display(a), np.full((h, 1, 3), 255, np.uint8), to_display(b),
                               np.full((h, 1, 3), 255, np.uint8), to_display(4.0 * np.abs(diff))], axis=1)
        write_png(mi, os.path.join(args.out, f"view_{k}_side_by_side.png"), side)
        zz = np.where(np.isfinite(z), z, np.sign(diff) * PIXEL_SIGMAS)
        zmax = np.take_along_axis(zz, np.argmax(np.abs(zz), axis=-1)[..., None], axis=-1)[..., 0]
        s = np.clip(np.abs(zmax) / PIXEL_SIGMAS, 0, 1)
        zimg = np.stack([np.where(zmax > 0, 1.0, 1.0 - s), 1.0 - s, np.where(zmax < 0, 1.0, 1.0 - s)], axis=-1)
        write_png(mi, os.path.join(args.out, f"view_{k}_zscore.png"), (zimg * 255).astype(np.uint8))

    n = tot["pixels"]
    mean_ours = tot["sum_ours"] / n
    mean_mi = tot["sum_mi"] / n
    mean_sigma = np.sqrt(tot["var_sum"]) / n
    mean_tol = np.maximum(MEAN_REL_TOL * np.abs(mean_ours), MEAN_SIGMAS * mean_sigma)
    checks = {
        "image_mean": {
            "ours": mean_ours.tolist(),
            "mitsuba": mean_mi.tolist(),
            "rel_diff": ((mean_mi - mean_ours) / np.maximum(np.abs(mean_ours), 1e-30)).tolist(),
            "sigma": mean_sigma.tolist(),
            "tolerance": mean_tol.tolist(),
            "pass": bool(np.all(np.abs(mean_mi - mean_ours) <= mean_tol)),
        },
        "pixels_within_4sigma": {
            "fraction_beyond": tot["outliers"] / n,
            "limit": PIXEL_OUTLIER_FRACTION,
            "pass": tot["outliers"] / n <= PIXEL_OUTLIER_FRACTION,
        },
        "pixel_center_depth": {
            "pixels_both_hit": tot["both_hit"],
            "max_rel_distance_error": tot["max_rel_dist"],
            "max_rel_depth_error": tot["max_rel_depth"],
            "limit": DEPTH_REL_TOL,
            "pass": tot["max_rel_dist"] <= DEPTH_REL_TOL and tot["max_rel_depth"] <= DEPTH_REL_TOL,
        },
        "hit_mask": {
            "agreement": tot["mask_agree"] / n,
            "limit": MASK_AGREEMENT,
            "pass": tot["mask_agree"] / n >= MASK_AGREEMENT,
        },
    }
    if envmap_error is not None:
        checks["envmap_orientation"] = {"max_rel_error": envmap_error, "limit": DEPTH_REL_TOL, "pass": envmap_error <= DEPTH_REL_TOL}
    passed = all(c["pass"] for c in checks.values())
    report = {
        "scene": man["scene"],
        "renderer": man["renderer"],
        "mitsuba": mi.__version__,
        "variant": args.variant,
        "spp": spp,
        "groups": groups,
        "max_bounces": man["settings"]["max_bounces"],
        "mitsuba_max_depth": man["settings"]["max_bounces"] + 1,
        "environment": man["environment"],
        "environment_map": man.get("environment_map"),
        "views": views,
        "checks": checks,
        "pass": passed,
        "seconds": time.time() - t0,
    }
    with open(os.path.join(args.out, "crosscheck.json"), "w") as f:
        json.dump(report, f, indent=2)
    write_markdown(os.path.join(args.out, "crosscheck.md"), report)
    print(f"crosscheck {man['scene']}: {'PASS' if passed else 'FAIL'}")
    for name, c in checks.items():
        print(f"  {name}: {'pass' if c['pass'] else 'FAIL'}  " + json.dumps({k: v for k, v in c.items() if k != 'pass'}))
    print(f"report: {os.path.join(args.out, 'crosscheck.md')}")
    return 0 if passed else 1


def fmt3(v, f="{:.5g}"):
    return "(" + ", ".join(f.format(x) for x in v) + ")"


def write_markdown(path, r):
    c = r["checks"]
    im = c["image_mean"]
    lines = [
        f"# Mitsuba cross-check: {r['scene']}",
        "",
        f"**{'PASS' if r['pass'] else 'FAIL'}** — {r['renderer']} vs Mitsuba {r['mitsuba']} ({r['variant']}), "
        f"{len(r['views'])} view(s), {r['spp']} spp in {r['groups']} independent groups, "
        f"max_bounces {r['max_bounces']} (Mitsuba max_depth {r['mitsuba_max_depth']}), environment {r['environment']}"
        + (f" × map {r['environment_map']['width']}x{r['environment_map']['height']}" if r.get('environment_map') else "") + ".",
        "",
        "| check | result | limit | |",
        "|---|---|---|---|",
        f"| image mean (R, G, B), ours | {fmt3(im['ours'])} | | |",
        f"| image mean, Mitsuba | {fmt3(im['mitsuba'])} | | |",
        f"| relative difference | {fmt3(im['rel_diff'], '{:+.3%}')} | ±1 % or 3σ, σ = {fmt3(im['sigma'], '{:.2g}')} | {'pass' if im['pass'] else 'FAIL'} |",
        f"| pixels with a channel beyond 4σ | {c['pixels_within_4sigma']['fraction_beyond']:.3%} | ≤ 0.5 % | {'pass' if c['pixels_within_4sigma']['pass'] else 'FAIL'} |",
        f"| pixel-centre distance, max relative error | {c['pixel_center_depth']['max_rel_distance_error']:.2e} ({c['pixel_center_depth']['pixels_both_hit']} px) | ≤ 1e-4 | {'pass' if c['pixel_center_depth']['pass'] else 'FAIL'} |",
        f"| pixel-centre z-depth, max relative error | {c['pixel_center_depth']['max_rel_depth_error']:.2e} | ≤ 1e-4 | |",
        f"| hit-mask agreement | {c['hit_mask']['agreement']:.4%} | ≥ 99.9 % | {'pass' if c['hit_mask']['pass'] else 'FAIL'} |",
    ]
    if "envmap_orientation" in c:
        e = c["envmap_orientation"]
        lines.append(f"| envmap lookup vs ours, max relative error | {e['max_rel_error']:.2e} | ≤ 1e-4 | {'pass' if e['pass'] else 'FAIL'} |")
    lines += [
        "",
        "## Views",
        "",
        "| view | size | mean ours | mean Mitsuba | >4σ px | z rms | mask agree | max rel dist | camera ray angle | Mitsuba s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for v in r["views"]:
        lines.append(
            f"| {v['view']} | {v['width']}x{v['height']} | {fmt3(v['mean_ours'])} | {fmt3(v['mean_mitsuba'])} | "
            f"{v['pixels_beyond_4sigma']} | {v['z_rms']:.3f} | {v['hit_mask_agreement']:.4%} | "
            f"{v['max_rel_distance_error']:.1e} | {v['max_camera_ray_angle_rad']:.1e} | {v['mitsuba_seconds']:.1f} |"
        )
    lines += [
        "",
        "Images: `view_<k>_side_by_side.png` (ours | Mitsuba | 4×|difference|), `view_<k>_zscore.png` "
        "(per-pixel largest |z| over channels: red Mitsuba brighter, blue ours brighter, saturated at 4σ).",
        "",
        "σ² per pixel = var(ours) + var(Mitsuba), each the variance of the mean estimated from the spread of the "
        "independent groups; the z rms should be ≈ 1 when the renderers agree.",
        "",
    ]
    with open(path, "w") as f:
        f.write("\n".join(lines))


if __name__ == "__main__":
    try:
        sys.exit(main())
    except Exception:  # a harness error must not read as a comparison failure
        import traceback

        traceback.print_exc()
        sys.exit(3)
