"""Mitsuba 3 timings for `cargo xtask bench render`: renders exported scenes
(`pathtracer::export::export_scene`, one folder per scene, one camera each) at the export's
resolution, spp and max depth (Mitsuba max_depth = our max_bounces + 1), and prints one JSON
object per scene and BSDF mode on stdout.

Variant: `llvm_ad_rgb` when Dr.Jit finds a working LLVM (DRJIT_LIBLLVM_PATH, set here to
/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1 when that exists and the variable is unset), else
`scalar_rgb`; `--variant` forces one.

BSDF modes:
- `gltf` (default): the same model as ours: exactly Lambertian materials (metallic 0, specular 0) as
  Mitsuba's native `diffuse`, every other one as the `gltf` Python plugin (gltf_bsdf.py; in
  llvm variants it is traced into the JIT kernel once, in scalar variants it is a Python call
  per interaction, so scalar timings with it measure Python, not Mitsuba);
- `diffuse`: every material as Mitsuba's native `diffuse` with its base colour (a cheaper
  model than ours for non-Lambertian materials: a lower bound on Mitsuba's time).

Russian roulette from the same vertex as ours: ours starts it at the third surface vertex
(bounce depth >= 2), Mitsuba's `path` when its depth counter exceeds `rr_depth`, i.e. rr_depth 2
(Mitsuba's default 5 would never terminate a path early at max_depth 5 and make its samples
costlier). The survival probabilities differ: ours min(1, 2 x the largest throughput
component), Mitsuba's min(0.95, the largest throughput component x eta^2).

Timing: `mi.render` plus evaluation of the image (dr.eval + sync); the first render of each
scene and mode (scene upload, JIT compilation, kernel caching) is reported separately as
`first_seconds`; `seconds` is the median of `--runs` further renders with new seeds, `times`
lists them all (in render order). With `--serve` the caller asks for each export when it wants
it (`serve()`): `cargo xtask bench render` right after its own renders of that image.
Scene building is not timed. Samples are camera samples: width x height x spp.

Rays per sample: Mitsuba keeps no count of the rays it traces, so `rays_per_sample` (per BSDF
mode, on each of its records; not timed) replays the control flow of its `path` integrator
(its src/integrators/path.cpp) as an evaluated Dr.Jit loop on the same scene
and counts the live lanes: one closest-hit ray per live path and iteration (the camera ray
included), and one shadow ray (`ray_test` inside `sample_emitter_direction`) per live path whose
BSDF has a smooth component and whose emitter sample has a non-zero density. The loop continues
as path.cpp's does: `depth + 1 < max_depth`, a valid hit, then Russian roulette from `rr_depth`
with survival min(0.95, max throughput x eta^2), and stops where the throughput is zero. The
counts are means over the render's samples (the independent sampler; the sampler changes which
paths are drawn, not how long they are on average).

Error: when the export folder holds `reference.npy` (our high-spp RGB image of the same camera)
and `reference_noise.json` (that image's own mean squared noise), `mse` is the mean squared RGB
error of the timed renders against it, less the reference's noise, the median over the renders
(`errors` lists them all, in the order of `times`),
and `bias2` the part of it that does not fall with more samples (mean of the renders against the
reference): near zero when both renderers converge to the same image. With `reference_mask.npy`
(1 = a pixel to measure), both are taken over those pixels only (our side leaves out the few
pixels where the reference's own noise is largest, and measures its renders on the same set).
"""

import argparse
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
LLVM19 = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"


def default_llvm():
    """Points Dr.Jit at Debian's LLVM 19 (before drjit is imported) unless DRJIT_LIBLLVM_PATH
    is set or that library is missing."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(LLVM19):
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM19


def parse_args():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--export", action="append", default=[], help="export folder (repeatable)")
    p.add_argument("--serve", action="store_true",
                   help="take commands on stdin instead (see serve()): the caller asks for each export when it wants it")
    p.add_argument("--variant", default="auto", help="auto (llvm_ad_rgb if it works, else scalar_rgb), or a variant")
    p.add_argument("--runs", type=int, default=5, help="timed renders after the first (median)")
    p.add_argument("--rr-depth", type=int, default=2, help="Mitsuba's rr_depth (2 = ours; see above)")
    p.add_argument("--modes", default="gltf", help="BSDF modes, comma-separated: gltf, diffuse")
    p.add_argument("--samplers", default="independent,ldsampler,multijitter",
                   help="Mitsuba samplers, comma-separated (independent: Mitsuba's default; ldsampler: its padded, "
                        "scrambled (0,2)-sequence, the counterpart of ours; multijitter: correlated multi-jittered)")
    return p.parse_args()


# A one-sample render of Mitsuba's Cornell box in llvm_ad_rgb, run in a child process: an LLVM
# that Dr.Jit loads but cannot compile its kernels with (e.g. a distribution's LLVM 14 or 15:
# "LLVM ERROR: Cannot select ... fminimum") aborts the whole process, which no `except` can
# catch, so the variant is tried where an abort costs nothing.
LLVM_PROBE = """
import drjit as dr, mitsuba as mi
mi.set_variant("llvm_ad_rgb")
dr.eval(mi.render(mi.load_dict(mi.cornell_box()), spp=1))
"""


def llvm_probe():
    """None when llvm_ad_rgb renders in this environment, else why not."""
    import subprocess

    try:
        r = subprocess.run([sys.executable, "-c", LLVM_PROBE], capture_output=True, text=True, timeout=600)
    except subprocess.TimeoutExpired:
        return "its probe render timed out"
    if r.returncode == 0:
        return None
    lines = [line for line in (r.stderr or "").splitlines() if line.strip() and not line.startswith(" ")]
    tail = [line for line in lines if line.startswith("LLVM ERROR")][:1] or lines[-1:]
    return f"its probe render failed (exit {r.returncode}{': ' + tail[0] if tail else ''})"


def choose_variant(mi, wanted):
    if wanted != "auto":
        mi.set_variant(wanted)
        return wanted
    why = llvm_probe()
    if why is None:
        mi.set_variant("llvm_ad_rgb")
        return "llvm_ad_rgb"
    llvm = os.environ.get("DRJIT_LIBLLVM_PATH", "the libLLVM Dr.Jit found")
    print(f"bench.py: llvm_ad_rgb unavailable with {llvm}: {why}; using scalar_rgb "
          f"(Debian/Ubuntu: apt-get install libllvm19, which provides {LLVM19})", file=sys.stderr)
    mi.set_variant("scalar_rgb")
    return "scalar_rgb"


def timed_render(mi, dr, scene, spp, seed):
    t = time.perf_counter()
    img = mi.render(scene, spp=spp, seed=seed)
    dr.eval(img)
    dr.sync_thread()
    return time.perf_counter() - t, img


def ray_counts(mi, dr, scene, spp, max_depth, rr_depth, seed=7):
    """Closest-hit and shadow rays per camera sample of Mitsuba's `path` integrator on `scene`
    (see the module docs): its loop replayed on `spp` samples of every pixel."""
    sensor = scene.sensors()[0]
    size = sensor.film().crop_size()
    n = int(size.x) * int(size.y) * spp
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, n)
    idx = dr.arange(mi.UInt32, n) // spp
    pos = mi.Vector2f(mi.Float(idx % size.x), mi.Float(idx // size.x)) + sampler.next_2d()
    ray, _ = sensor.sample_ray(0.0, 0.5, pos / mi.Vector2f(size), mi.Point2f(0.5))
    beta = dr.full(mi.Spectrum, 1.0, n)
    eta = dr.full(mi.Float, 1.0, n)
    active = dr.full(mi.Bool, True, n)
    depth = dr.zeros(mi.UInt32, n)
    closest = shadow = 0

    def count(mask):
        c = dr.count(mask)
        return int(c[0]) if dr.width(c) > 0 else 0

    for _ in range(max_depth + 1):
        live = count(active)
        if live == 0:
            break
        closest += live
        si = scene.ray_intersect(ray, active)
        active_next = active & (depth + 1 < max_depth) & si.is_valid()
        bsdf = si.bsdf(ray)
        active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        ds, _ = scene.sample_emitter_direction(si, sampler.next_2d(), False, active_em)
        shadow += count(active_em & (ds.pdf != 0.0))
        bs, weight = bsdf.sample(mi.BSDFContext(), si, sampler.next_1d(), sampler.next_2d(), active_next)
        ray = si.spawn_ray(si.to_world(bs.wo))
        beta = dr.select(active_next, beta * weight, beta)
        eta = dr.select(active_next, eta * bs.eta, eta)
        depth = dr.select(active & si.is_valid(), depth + 1, depth)
        beta_max = dr.max(beta)
        rr_prob = dr.minimum(beta_max * eta * eta, 0.95)
        rr_active = depth >= rr_depth
        beta = dr.select(rr_active, beta / rr_prob, beta)
        active = active_next & (~rr_active | (sampler.next_1d() < rr_prob)) & (beta_max != 0.0)
        dr.eval(ray, beta, eta, depth, active)
    return {"closest": closest / n, "shadow": shadow / n}


def load_reference(folder):
    """Our reference image, its noise and the mask of the pixels to measure (all without
    `reference_mask.npy`)."""
    path = os.path.join(folder, "reference.npy")
    if not os.path.exists(path):
        return None, 0.0, None
    import numpy as np

    with open(os.path.join(folder, "reference_noise.json")) as f:
        noise = float(json.load(f)["mse"])
    reference = np.load(path).astype(np.float64)
    mask_path = os.path.join(folder, "reference_mask.npy")
    mask = np.load(mask_path) > 0.5 if os.path.exists(mask_path) else np.ones(reference.shape[:2], dtype=bool)
    return reference, noise, mask


class Bench:
    """The renders of one or more exports, each in every BSDF mode and sampler asked for."""

    def __init__(self, args):
        default_llvm()
        import drjit as dr
        import mitsuba as mi

        self.args, self.dr, self.mi = args, dr, mi
        self.variant = choose_variant(mi, args.variant)
        import gltf_bsdf
        import gltf_lights
        import scene_loader

        self.gltf_lights, self.scene_loader = gltf_lights, scene_loader

        def diffuse_plugin(mi_module, mat, textures, has_vertex_colors):
            return {"type": "diffuse", "reflectance": scene_loader.lambert_reflectance(mi_module, mat, textures, has_vertex_colors)}

        self.plugins = {"gltf": gltf_bsdf.bsdf_dict, "diffuse": diffuse_plugin}

    def measure(self, folder, runs):
        """The export's records, one per mode and sampler: the scene built, rendered once
        (scene upload, JIT compilation: `first_seconds`), then `runs` timed renders in a row
        (as a user renders; alternating between the samplers' scenes instead measured 25 %
        slower with the `gltf` plugin)."""
        mi, dr, args, scene_loader = self.mi, self.dr, self.args, self.scene_loader
        man, arrays = scene_loader.load_export(folder)
        spp = int(man["settings"]["spp"])
        cam = man["cameras"][0]
        samples = cam["width"] * cam["height"] * spp
        out = []
        rays = {}
        for mode, sampler in [(m, s) for m in args.modes.split(",") for s in args.samplers.split(",")]:
            rec = {"export": folder, "scene": man["scene"], "variant": self.variant, "mode": mode, "sampler": sampler, "width": cam["width"],
                   "height": cam["height"], "spp": spp, "max_depth": int(man["settings"]["max_bounces"]) + 1, "samples": samples}
            try:
                scene = scene_loader.build_scene(mi, man, arrays, 0, spp, self.plugins[mode], self.gltf_lights.spot_dict,
                                                 self.gltf_lights.envmap_dict, transparent_ok=True, rr_depth=args.rr_depth,
                                                 sampler=sampler)
                lambert = sum(1 for m in man["materials"] if m["metallic"] <= 0 and m.get("specular", 1.0) <= 0
                              and m["metallic_roughness_texture"] is None)
                glossy = len(man["materials"]) - lambert
                rec["bsdf"] = ("native diffuse (every material)" if mode == "diffuse" else
                               "native diffuse" if glossy == 0 else
                               f"gltf Python plugin ({glossy} materials)" + (f", native diffuse ({lambert})" if lambert else ""))
                rec["rr_depth"] = args.rr_depth
                rec["first_seconds"] = timed_render(mi, dr, scene, spp, 0)[0]
                finish(rec, [timed_render(mi, dr, scene, spp, 1 + k) for k in range(max(1, runs))], folder)
                if mode not in rays:  # once per mode, after its timings
                    rays[mode] = ray_counts(mi, dr, scene, spp, rec["max_depth"], args.rr_depth)
                rec["rays_per_sample"] = rays[mode]
            except scene_loader.Unsupported as e:
                rec["error"] = f"unsupported: {e}"
            out.append(rec)
        return out


def finish(rec, runs, folder):
    """Fills `rec` with the figures of `runs` (seconds, image) against the export's reference."""
    samples = rec["samples"]
    rec["times"] = [t for t, _ in runs]
    times = sorted(rec["times"])
    rec["seconds"] = times[len(times) // 2]
    rec["samples_per_second"] = samples / rec["seconds"]
    reference, noise, mask = load_reference(folder)
    if reference is not None:
        import numpy as np

        imgs = [np.array(img, dtype=np.float64)[..., :3] for _, img in runs]
        errs = [float(np.mean(((i - reference) ** 2)[mask])) - noise for i in imgs]
        rec["errors"] = errs
        # The median, as on our side: a rare caustic firefly decides a mean of a few.
        rec["mse"] = float(np.median(errs))
        rec["mse_mean"] = sum(errs) / len(errs)
        # Per render, error = variance V + squared bias B; the mean of n renders
        # has V / n + B: B estimates how far Mitsuba's expected image is from ours.
        n = len(imgs)
        if n > 1:
            mse_mean = float(np.mean(((np.mean(imgs, axis=0) - reference) ** 2)[mask])) - noise
            rec["bias2"] = (mse_mean - rec["mse_mean"] / n) / (1.0 - 1.0 / n)


def serve(bench):
    """`--serve`: commands on stdin, one JSON object a line, each answered by one JSON line on
    stdout: {"cmd": "measure", "export": DIR, "runs": N} answers {"records": [...]}, the batch
    mode's records of DIR. `cargo xtask bench render` asks for each export right after its own
    timed renders of it, so that the two renderers' figures of one image are taken within
    seconds of each other (a drift of the machine's speed during the bench then falls on both
    alike). The first line, once Mitsuba is loaded and its variant chosen, is
    {"ok": true, "variant": ...}: the caller waits for it so that none of its timings overlaps
    this start-up."""
    print(json.dumps({"ok": True, "variant": bench.variant}), flush=True)
    for line in sys.stdin:
        line = line.strip()
        if not line:
            continue
        try:
            cmd = json.loads(line)
            if cmd.get("cmd") == "measure":
                reply = {"records": bench.measure(cmd["export"], int(cmd["runs"]))}
            else:
                reply = {"error": f"unknown command {cmd.get('cmd')!r}"}
        except Exception as e:  # the caller reports it and goes on without Mitsuba
            reply = {"error": f"{type(e).__name__}: {e}"}
        print(json.dumps(reply), flush=True)
    return 0


def main():
    args = parse_args()
    if not args.serve and not args.export:
        print("bench.py: give --export DIR (repeatable) or --serve", file=sys.stderr)
        return 2
    bench = Bench(args)
    if args.serve:
        return serve(bench)
    for folder in args.export:
        for rec in bench.measure(folder, args.runs):
            print(json.dumps(rec), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
