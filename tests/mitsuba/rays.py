"""Mitsuba 3's ray-query throughput on an exported scene, and the rays it traced, so that ours
can be timed on exactly the same rays.

For each export folder (`pathtracer::export::export_scene`, as `cargo xtask bench render`
writes them under out/bench/mitsuba/): the pixel-centre camera rays of the export's first
camera at --width pixels wide, and one incoherent ray per camera ray that hits: from the hit
(Mitsuba's `spawn_ray` offset) in a uniformly distributed direction. Each set is timed with
`scene.ray_intersect_preliminary` (closest hit) and `scene.ray_test` (any hit), medians of
--runs evaluations on all of Dr.Jit's threads, and written to OUT/SCENE-primary.bin and
OUT/SCENE-incoherent.bin as little-endian f32 records (origin xyz, direction xyz, t_max), in
the scene's local frame, which is ours. One JSON object per scene on stdout.

    .venv/bin/python tests/mitsuba/rays.py --export out/bench/mitsuba/deep --out /tmp/rays
    cargo bench -p pathtracer --bench render -- deep --rays /tmp/rays/deep-primary.bin \\
        --rays /tmp/rays/deep-incoherent.bin
"""

import argparse
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--export", action="append", required=True, help="export folder (repeatable)")
    p.add_argument("--out", required=True, help="folder for the ray files")
    p.add_argument("--width", type=int, default=256, help="camera rays per row (and per column)")
    p.add_argument("--runs", type=int, default=30, help="timed evaluations per query (median)")
    p.add_argument("--variant", default="llvm_ad_rgb")
    args = p.parse_args()
    from bench import default_llvm

    default_llvm()
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    mi.set_variant(args.variant)
    import gltf_lights
    import scene_loader

    def diffuse(mi_module, mat, textures, has_vertex_colors):
        return {"type": "diffuse", "reflectance": scene_loader.lambert_reflectance(mi_module, mat, textures, has_vertex_colors)}

    def median_seconds(f):
        times = []
        for _ in range(args.runs):
            t = time.perf_counter()
            dr.eval(f())
            dr.sync_thread()
            times.append(time.perf_counter() - t)
        return sorted(times)[len(times) // 2]

    def save(path, rays):
        o = np.stack([np.array(rays.o[k], dtype=np.float32) for k in range(3)], 1)
        d = np.stack([np.array(rays.d[k], dtype=np.float32) for k in range(3)], 1)
        t = np.broadcast_to(np.array(rays.maxt, dtype=np.float32).reshape(-1), (o.shape[0],)).reshape(-1, 1)
        # Written whole, then renamed: a reader never sees a partial file.
        tmp = path + ".tmp"
        np.concatenate([o, d, t], 1).astype("<f4").tofile(tmp)
        os.replace(tmp, path)

    os.makedirs(args.out, exist_ok=True)
    for folder in args.export:
        man, arrays = scene_loader.load_export(folder)
        # The BSDFs do not matter to ray queries: every material as `diffuse`.
        scene = scene_loader.build_scene(mi, man, arrays, 0, 1, diffuse, gltf_lights.spot_dict, gltf_lights.envmap_dict,
                                         transparent_ok=True, rr_depth=2, sampler="independent")
        cam = man["cameras"][0]
        w = args.width
        h = max(1, round(w * cam["height"] / cam["width"]))
        idx = dr.arange(mi.UInt32, w * h)
        pos = mi.Point2f(mi.Float(idx % w) + 0.5, mi.Float(idx // w) + 0.5) / mi.ScalarVector2f(w, h)
        primary, _ = scene.sensors()[0].sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
        dr.eval(primary)
        si = scene.ray_intersect(primary)
        hit = dr.compress(si.is_valid())
        si_hit = dr.gather(type(si), si, hit)
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(1, max(1, dr.width(hit)))
        incoherent = si_hit.spawn_ray(mi.warp.square_to_uniform_sphere(sampler.next_2d()))
        dr.eval(incoherent)
        rec = {"export": folder, "scene": os.path.basename(os.path.normpath(folder)), "variant": args.variant, "threads": dr.thread_count()}
        for name, rays in [("primary", primary), ("incoherent", incoherent)]:
            n = dr.width(rays.o)
            path = os.path.join(args.out, f"{os.path.basename(os.path.normpath(folder))}-{name}.bin")
            save(path, rays)
            rec[name] = {
                "file": path,
                "rays": n,
                "closest_mrays_per_s": n / median_seconds(lambda: scene.ray_intersect_preliminary(rays).t) * 1e-6,
                "any_hit_mrays_per_s": n / median_seconds(lambda: scene.ray_test(rays)) * 1e-6,
            }
        print(json.dumps(rec), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
