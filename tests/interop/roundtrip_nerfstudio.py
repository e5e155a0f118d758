#!/usr/bin/env python3
"""A real round trip through nerfstudio on the CPU: nerfacto trained on one of our datasets,
its test renders, depth and mesh scored against our exact ground truth, beside our own fast and
auto models trained for the same wall-clock time on the same machine.

    .venv-interop/bin/python tests/interop/roundtrip_nerfstudio.py DATASET OUT [options]

Steps (each prints `== step NAME`; a failure prints `FAILED at step NAME` and exits 1):

  ns-train   nerfacto, `--max-num-iterations N` on the CPU (torch implementation, no pose
             optimisation, white background, masks ignored); times its training loop
  ns-render  `ns-render dataset --split test --image-format png` (its default is JPEG) into
             OUT/ns_render: rgb (8-bit PNG), depth (colour-mapped PNG) and raw-depth,
             raw-expected_depth, raw-accumulation (gzipped .npy)
  ns-export  `ns-export tsdf` into OUT/ns_export (tsdf_mesh.ply, nerfstudio's frame)
  ns-eval    `ns-eval` on the test split into OUT/ns_eval.json (nerfstudio's PSNR/SSIM/LPIPS)
  facts      what the steps above wrote (layout, dtypes, shapes, dataparser transform, mesh)
             into OUT/facts.json
  fast, auto `xtask train --model M --time S` (S = nerfacto's training-loop seconds), `xtask eval`
  score      `xtask score DATASET OUT/ns_render --method nerfacto --split test
             --train-seconds S --out OUT/score` (plus --score-args)
  compare    `xtask compare OUT/runs/fast OUT/runs/auto OUT/score --out OUT/compare`

A finished step leaves OUT/.done/STEP and is skipped when the script runs again with the same
OUT (score and compare always run), so a rerun after a failure resumes where it stopped.
nerfstudio's commands run through ns_offline.py (LPIPS' AlexNet weights cannot be downloaded
here: nerfstudio's LPIPS values are meaningless then; facts.json says which).
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent


class StepFailed(Exception):
    pass


def run(cmd: list[str], log: Path, cwd: Path | None = None) -> float:
    """Runs cmd with stdout/stderr into log (and the last lines on failure); returns seconds."""
    print("   $ " + " ".join(str(c) for c in cmd), flush=True)
    t0 = time.perf_counter()
    with open(log, "w") as f:
        rc = subprocess.run([str(c) for c in cmd], stdout=f, stderr=subprocess.STDOUT, cwd=cwd).returncode
    dt = time.perf_counter() - t0
    if rc != 0:
        tail = log.read_text(errors="replace").splitlines()[-25:]
        print("\n".join("   | " + line for line in tail))
        raise StepFailed(f"exit status {rc} after {dt:.1f} s (log: {log})")
    print(f"   ok in {dt:.1f} s (log: {log})", flush=True)
    return dt


def cpu_model() -> str:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
        for line in out.splitlines():
            if line.startswith("Model name:"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def npy_gz(path: Path) -> np.ndarray:
    with gzip.open(path, "rb") as f:
        return np.load(f)


def facts(ds: Path, out: Path, ns_run: Path) -> dict:
    """What nerfstudio wrote, measured: the facts a reader of these outputs needs."""
    import OpenEXR
    from PIL import Image

    render = out / "ns_render"
    f: dict = {"ns_render_files": sorted(p.relative_to(render).as_posix() for p in render.rglob("*") if p.is_file())}
    per = {}
    for p in sorted(render.rglob("*")):
        if not p.is_file() or p.name == "dataparser_transforms.json":
            continue
        kind = p.parent.name
        if kind in per:
            continue
        if p.suffix == ".png":
            im = Image.open(p)
            a = np.asarray(im)
            per[kind] = {"example": p.relative_to(render).as_posix(), "format": "PNG", "mode": im.mode,
                         "dtype": str(a.dtype), "shape": list(a.shape)}
        elif p.name.endswith(".npy.gz"):
            a = npy_gz(p)
            per[kind] = {"example": p.relative_to(render).as_posix(), "format": "gzip of .npy", "dtype": str(a.dtype),
                         "shape": list(a.shape), "min": float(a.min()), "max": float(a.max())}
    f["ns_render_outputs"] = per

    # raw-depth against our ground truth: is it ray distance or z-depth, in metres?
    meta = json.loads((ds / "transforms_test.json").read_text())
    err = {"vs_distance": [], "vs_z_depth": []}
    for fr in meta["frames"]:
        stem = Path(fr["file_path"]).name
        p = render / "test" / "raw-depth" / f"{stem}.npy.gz"
        if not p.is_file():
            continue
        d = npy_gz(p)[..., 0].astype(np.float64)
        with OpenEXR.File(str(ds / fr["gt_file_path"])) as e:
            ch = {k: np.asarray(v.pixels, dtype=np.float64) for k, v in e.channels().items()}
        hit = ch["alpha"] > 0.999
        err["vs_distance"].append(float(np.median(np.abs(d - ch["distance"])[hit])))
        err["vs_z_depth"].append(float(np.median(np.abs(d - ch["depth"])[hit])))
    f["raw_depth_median_abs_err_m"] = {k: (float(np.median(v)) if v else None) for k, v in err.items()}

    dpt = json.loads((ns_run / "dataparser_transforms.json").read_text())
    f["dataparser_transforms"] = dpt
    T = np.array(dpt["transform"], dtype=np.float64)  # 3x4
    s = float(dpt["scale"])
    facts_box = meta.get("scene_facts") or {}
    if "aabb_min" in facts_box:
        lo, hi = np.array(facts_box["aabb_min"]), np.array(facts_box["aabb_max"])
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        ns = s * (corners @ T[:, :3].T + T[:, 3])
        f["scene_box_in_nerfstudio_frame"] = {"min": ns.min(0).tolist(), "max": ns.max(0).tolist(),
                                             "map": "x_ns = scale * (transform[:, :3] @ x + transform[:, 3])"}

    mesh = out / "ns_export" / "tsdf_mesh.ply"
    if mesh.is_file():
        import trimesh

        m = trimesh.load(mesh, process=False)
        v = np.asarray(m.vertices, dtype=np.float64)
        header = mesh.read_bytes()[:400].split(b"end_header")[0].decode(errors="replace")
        back = ((v / s) - T[:, 3]) @ T[:, :3]  # inverse of the map above (T[:, :3] is a rotation)
        f["mesh"] = {"file": mesh.relative_to(out).as_posix(), "bytes": mesh.stat().st_size, "ply_header": header,
                     "vertices": len(v), "faces": int(len(m.faces)),
                     "bbox_nerfstudio_frame": [v.min(0).tolist(), v.max(0).tolist()],
                     "bbox_dataset_frame": [back.min(0).tolist(), back.max(0).tolist()]}
    ev = json.loads((out / "ns_eval.json").read_text())
    f["ns_eval"] = ev["results"]
    f["ns_train"] = json.loads((out / "ns_train_timing.json").read_text())
    return f


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dataset", type=Path, help="dataset folder written by `xtask render`")
    ap.add_argument("out", type=Path, help="output folder (created; a rerun resumes it)")
    ap.add_argument("--iterations", type=int, default=100, help="nerfacto training iterations (default 100)")
    ap.add_argument("--rays", type=int, default=512, help="nerfacto rays per batch (default 512; nerfstudio's 4096 "
                    "costs about 8x more per iteration on the CPU)")
    ap.add_argument("--xtask", type=Path, default=REPO / "target" / "release" / "xtask",
                    help="the xtask binary (default target/release/xtask: `cargo build --release -p xtask`)")
    ap.add_argument("--score-args", default="", help="extra arguments for `xtask score`, split on spaces")
    ap.add_argument("--skip-ours", action="store_true", help="run only nerfstudio's steps and facts")
    args = ap.parse_args()

    ds, out = args.dataset.resolve(), args.out.resolve()
    if not (ds / "transforms.json").is_file():
        print(f"error: {ds / 'transforms.json'} not found (is {ds} a dataset written by `xtask render`?)",
              file=sys.stderr)
        return 2
    if not args.skip_ours and not args.xtask.is_file():
        print(f"error: xtask binary {args.xtask} not found (cargo build --release -p xtask --locked, or --xtask)",
              file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    done, logs = out / ".done", out / "logs"
    done.mkdir(exist_ok=True)
    logs.mkdir(exist_ok=True)
    py = sys.executable
    off = [py, str(HERE / "ns_offline.py")]
    ns_out = out / "nerfstudio"
    ns_run = ns_out / "nerfacto" / "nerfacto" / "run"
    config = ns_run / "config.yml"
    hw = {"cpu": cpu_model(), "cores": os.cpu_count(), "loadavg_start": list(os.getloadavg())}
    print(f"dataset {ds}\nout     {out}\ncpu     {hw['cpu']} ({hw['cores']} logical cores), load average "
          f"{hw['loadavg_start'][0]:.1f}", flush=True)
    xtask = [str(args.xtask)]

    def budget() -> float:
        return json.loads((out / "ns_train_timing.json").read_text())["train_loop_s"]

    def ns_train():
        # nerfacto's defaults except: CPU, fp32, the torch hash grid (tiny-cuda-nn needs CUDA), no
        # evaluation during training, no camera pose optimisation (our poses are exact), a white
        # background (what our eval composites the ground truth on), every pixel supervised
        # (the masks would leave the background unconstrained), fewer rays per batch.
        if ns_out.exists():
            shutil.rmtree(ns_out)
        run(off + ["--timing", out / "ns_train_timing.json", "ns-train", "nerfacto",
                   "--data", ds, "--output-dir", ns_out, "--experiment-name", "nerfacto", "--timestamp", "run",
                   "--vis", "tensorboard", "--viewer.quit-on-train-completion", "True",
                   "--machine.device-type", "cpu", "--mixed-precision", "False",
                   "--max-num-iterations", args.iterations, "--steps-per-save", 10**9,
                   "--steps-per-eval-batch", 0, "--steps-per-eval-image", 0, "--steps-per-eval-all-images", 0,
                   "--pipeline.model.implementation", "torch",
                   "--pipeline.model.camera-optimizer.mode", "off",
                   "--pipeline.model.background-color", "white",
                   "--pipeline.datamanager.train-num-rays-per-batch", args.rays,
                   "--pipeline.datamanager.pixel-sampler.ignore-mask", "True",
                   "nerfstudio-data"], logs / "ns-train.log")
        t = json.loads((out / "ns_train_timing.json").read_text())
        # the machine's load matters as much as its model: the timing is wall-clock
        t.update(cpu=hw["cpu"], cores=hw["cores"], loadavg_start=hw["loadavg_start"], loadavg_end=list(os.getloadavg()))
        tmp = out / "ns_train_timing.json.tmp"
        tmp.write_text(json.dumps(t, indent=2) + "\n")
        tmp.replace(out / "ns_train_timing.json")
        print(f"   nerfacto: {t['iterations']} iterations, training loop {t['train_loop_s']:.1f} s "
              f"(iterations alone {t['iteration_s']:.1f} s), process {t['process_s']:.1f} s")

    def ns_render():
        dst = out / "ns_render"
        if dst.exists():
            shutil.rmtree(dst)
        run(off + ["ns-render", "dataset", "--load-config", config, "--output-path", dst, "--split", "test",
                   "--image-format", "png", "--rendered-output-names", "rgb", "depth", "raw-depth",
                   "raw-expected_depth", "raw-accumulation"], logs / "ns-render.log")
        # where a reader of the renders finds the transform nerfstudio applied to the poses
        shutil.copy2(ns_run / "dataparser_transforms.json", dst / "dataparser_transforms.json")

    def ns_export():
        import ctypes.util

        if ctypes.util.find_library("usb-1.0") is None:
            raise StepFailed("ns-export imports open3d, which needs the system library libusb-1.0 "
                             "(Debian/Ubuntu: apt-get install libusb-1.0-0)")
        # --texture-method tsdf: the NeRF texture pass renders a 2048^2 atlas (hours on a CPU)
        run(off + ["ns-export", "tsdf", "--load-config", config, "--output-dir", out / "ns_export",
                   "--texture-method", "tsdf"], logs / "ns-export.log")

    def ns_eval():
        run(off + ["ns-eval", "--load-config", config, "--output-path", out / "ns_eval.json"], logs / "ns-eval.log")

    def do_facts():
        f = facts(ds, out, ns_run)
        f["hardware"] = hw
        f["lpips_valid"] = f["ns_train"].get("lpips_valid")
        tmp = out / "facts.json.tmp"
        tmp.write_text(json.dumps(f, indent=2) + "\n")
        tmp.replace(out / "facts.json")
        print(json.dumps({k: f[k] for k in f if k != "ns_render_files"}, indent=2))

    def ours(model: str):
        def step():
            s = budget()
            run_dir = out / "runs" / model
            run(xtask + ["train", ds, "--out", run_dir, "--model", model, "--time", f"{s:.1f}s", "--force"],
                logs / f"train-{model}.log")
            run(xtask + ["eval", run_dir], logs / f"eval-{model}.log")
        return step

    def score():
        mesh = out / "ns_export" / "tsdf_mesh.ply"  # nerfstudio's frame: score undoes it
        geometry = ["--geometry", mesh] if mesh.is_file() else []
        run(xtask + ["score", ds, out / "ns_render", "--method", "nerfacto",
                     "--split", "test", "--train-seconds", f"{budget():.1f}", "--out", out / "score"]
            + geometry + args.score_args.split(), logs / "score.log")

    def compare():
        run(xtask + ["compare", out / "runs" / "fast", out / "runs" / "auto", out / "score",
                     "--out", out / "compare"], logs / "compare.log")
        print((out / "compare" / "compare.md").read_text())

    steps = [("ns-train", ns_train, True), ("ns-render", ns_render, True), ("ns-export", ns_export, True),
             ("ns-eval", ns_eval, True), ("facts", do_facts, True)]
    if not args.skip_ours:
        steps += [("fast", ours("fast"), True), ("auto", ours("auto"), True), ("score", score, False),
                  ("compare", compare, False)]
    t_all = time.perf_counter()
    for name, fn, once in steps:
        marker = done / name
        if once and marker.exists():
            print(f"== step {name}: done before ({marker}), skipped", flush=True)
            continue
        print(f"== step {name}", flush=True)
        try:
            fn()
        except (StepFailed, OSError, KeyError, ValueError) as e:
            print(f"FAILED at step {name}: {type(e).__name__}: {e}", flush=True)
            return 1
        if once:
            marker.write_text(time.strftime("%Y-%m-%dT%H:%M:%S") + "\n")
    print(f"all steps done in {time.perf_counter() - t_all:.1f} s; load average now {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
