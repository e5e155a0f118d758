#!/usr/bin/env python3
"""Loads a dataset written by `xtask render` through nerfstudio's own dataparsers and loaders
and checks it against the ground truth we wrote.

    .venv-interop/bin/python tests/interop/check_nerfstudio.py DATASET [--views N]

What it checks (see tests/interop/README.md):

* nerfstudio's `NerfstudioDataParserConfig(data=DATASET)` (transforms.json, default settings):
  splits, poses (after undoing nerfstudio's dataparser_transform and dataparser_scale),
  intrinsics, rays (`Cameras.generate_rays` and the training path `RayGenerator`) against our
  pixel-centre rays, depth through `DepthDataset` / `get_depth_image_from_path` with the
  default `depth_unit_scale_factor` converted back to metres against `r_k_depth.npy` and the
  ground-truth EXR, depth as depth-nerfacto uses it (z-depth x directions_norm) against the
  EXR's distance, masks through `InputDataset` against the EXR's alpha, and the RGBA image.
* nerfstudio's `BlenderDataParserConfig(data=DATASET)` (transforms_{split}.json): splits,
  poses, intrinsics from camera_angle_x, rays, the image composited on white.
* instant-ngp's loader conventions, re-implemented from its source (src/nerf_loader.cu,
  include/neural-graphics-primitives/nerf_loader.h; instant-ngp itself needs CUDA and is not
  run): focal length, rays, and where the scene's bounding box lands in its unit cube.

Our pixel-centre ray (crates/dataset/src/camera.rs, `Camera::pixel_center_ray`): pixel
(column i, row j) goes through image point (i + 0.5, j + 0.5); in the camera frame (OpenGL:
+X right, +Y up, looking down -Z) the direction is ((u - cx)/fx, -(v - cy)/fy, -1),
normalised, rotated by the camera-to-world matrix; the origin is the camera centre.

Prints a PASS/FAIL table; exits 1 when a check fails, 2 when the dataset cannot be read.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROWS: list[tuple[str, str, str, str, str]] = []  # (section, check, measured, limit, status)


def row(section: str, check: str, measured: str, limit: str, ok: bool | None) -> None:
    status = "INFO" if ok is None else ("PASS" if ok else "FAIL")
    ROWS.append((section, check, measured, limit, status))


def err_row(section: str, check: str, err: float, tol: float, unit: str = "") -> None:
    u = f" {unit}" if unit else ""
    row(section, check, f"max |err| {err:.3g}{u}", f"<= {tol:g}{u}", bool(np.isfinite(err) and err <= tol))


def print_table() -> None:
    head = ("section", "check", "measured", "limit", "result")
    widths = [max(len(r[k]) for r in ROWS + [head]) for k in range(5)]
    line = "  ".join(h.ljust(w) for h, w in zip(head, widths))
    print(line)
    print("  ".join("-" * w for w in widths))
    for r in ROWS:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)))


# ---------------------------------------------------------------- our side, in numpy (float64)


def our_rays(c2w: np.ndarray, fx: float, fy: float, cx: float, cy: float, w: int, h: int):
    """Our pixel-centre rays for every pixel: origins [h, w, 3], unit directions [h, w, 3]."""
    j, i = np.meshgrid(np.arange(h, dtype=np.float64), np.arange(w, dtype=np.float64), indexing="ij")
    d = np.stack([(i + 0.5 - cx) / fx, -(j + 0.5 - cy) / fy, -np.ones_like(i)], axis=-1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    dw = d @ c2w[:3, :3].T
    dw /= np.linalg.norm(dw, axis=-1, keepdims=True)
    o = np.broadcast_to(c2w[:3, 3], dw.shape)
    return o, dw


def read_gt_exr(path: Path) -> dict[str, np.ndarray]:
    import OpenEXR

    with OpenEXR.File(str(path)) as f:
        return {name: np.asarray(ch.pixels, dtype=np.float64) for name, ch in f.channels().items()}


def rel_key(path: Path, root: Path) -> str:
    """'train/r_3' for DATASET/train/r_3.png (or .npy, _mask.png ...): the frame's identity."""
    p = Path(os.path.relpath(Path(path).resolve(), root.resolve())).with_suffix("")
    return p.as_posix()


def to_np(t) -> np.ndarray:
    return t.detach().cpu().numpy().astype(np.float64)


# ---------------------------------------------------------------- nerfstudio dataparser


def check_nerfstudio_parser(ds: Path, max_views: int) -> None:
    import torch
    from nerfstudio.cameras.cameras import CameraType
    from nerfstudio.data.datasets.base_dataset import InputDataset
    from nerfstudio.data.datasets.depth_dataset import DepthDataset
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig
    from nerfstudio.data.utils.data_utils import get_depth_image_from_path
    from nerfstudio.model_components.ray_generators import RayGenerator
    from PIL import Image

    S = "nerfstudio"
    meta = json.loads((ds / "transforms.json").read_text())
    by_key = {Path(f["file_path"]).with_suffix("").as_posix(): f for f in meta["frames"]}
    config = NerfstudioDataParserConfig(data=ds)  # every setting at its default
    parser = config.setup()
    outs = {}
    for split in ("train", "val", "test"):
        outs[split] = parser.get_dataparser_outputs(split=split)
        want = sorted(Path(f).with_suffix("").as_posix() for f in meta[f"{split}_filenames"])
        got = sorted(rel_key(p, ds) for p in outs[split].image_filenames)
        row(S, f"{split} split = {split}_filenames", f"{len(got)} images", f"{len(want)} images", got == want)

    out = outs["train"]
    keys = [rel_key(p, ds) for p in out.image_filenames]
    n = len(keys) if max_views <= 0 else min(max_views, len(keys))

    # ---- files nerfstudio picked up
    depth_files = out.metadata.get("depth_filenames")
    row(S, "depth_file_path read for every frame", f"{0 if depth_files is None else len(depth_files)} files",
        f"{len(keys)} files", depth_files is not None and len(depth_files) == len(keys))
    row(S, "mask_path read for every frame", f"{0 if out.mask_filenames is None else len(out.mask_filenames)} files",
        f"{len(keys)} files", out.mask_filenames is not None and len(out.mask_filenames) == len(keys))
    unit = out.metadata.get("depth_unit_scale_factor")
    row(S, "depth_unit_scale_factor (parser default)", f"{unit}", "0.001 (mm files)", unit == 1e-3)
    row(S, "transforms.json has no depth_unit_scale_factor key", "absent" if "depth_unit_scale_factor" not in meta
        else f"present ({meta['depth_unit_scale_factor']}), nerfstudio ignores it", "absent",
        "depth_unit_scale_factor" not in meta)

    # ---- transforms.json against the Blender-layout files (two writers of the same cameras)
    kerr = perr = 0.0
    nblend = 0
    for split in ("train", "val", "test"):
        bm = json.loads((ds / f"transforms_{split}.json").read_text())
        bk = [float(bm.get(k, meta[k])) for k in ("fl_x", "fl_y", "cx", "cy", "w", "h")]
        kerr = max(kerr, max(abs(a - float(meta[k])) for a, k in zip(bk, ("fl_x", "fl_y", "cx", "cy", "w", "h"))))
        for f in bm["frames"]:
            key = Path(f["file_path"].replace("./", "", 1)).as_posix()
            m = by_key.get(key)
            perr = max(perr, math.inf if m is None else
                       float(np.abs(np.array(m["transform_matrix"]) - np.array(f["transform_matrix"])).max()))
            nblend += 1
    err_row(S, "transforms.json vs transforms_{split}.json: w h fl cx cy", kerr, 0.0)
    err_row(S, f"transforms.json vs transforms_{{split}}.json: {nblend} poses", perr, 0.0)

    # ---- poses: undo x_ns = s (R x + t)
    T = to_np(out.dataparser_transform)  # 3x4
    s = float(out.dataparser_scale)
    R, t = T[:, :3], T[:, 3]
    row(S, "dataparser_transform / dataparser_scale", f"|t| = {np.linalg.norm(t):.4f}, s = {s:.6f}", "-", None)
    c2w_ns = to_np(out.cameras.camera_to_worlds)  # [N, 3, 4]
    rot_err = trans_err = 0.0
    ours = []
    for k, key in enumerate(keys):
        m = np.array(by_key[key]["transform_matrix"], dtype=np.float64)
        ours.append(m)
        back_rot = R.T @ c2w_ns[k, :, :3]
        back_t = R.T @ (c2w_ns[k, :, 3] / s - t)
        rot_err = max(rot_err, np.abs(back_rot - m[:3, :3]).max())
        trans_err = max(trans_err, np.abs(back_t - m[:3, 3]).max())
    err_row(S, f"pose rotation ({len(keys)} views)", rot_err, 1e-5)
    err_row(S, f"pose translation ({len(keys)} views)", trans_err, 1e-5, "m")

    # ---- intrinsics
    cams = out.cameras
    fx, fy, cx, cy = (float(meta[k]) for k in ("fl_x", "fl_y", "cx", "cy"))
    W, H = int(meta["w"]), int(meta["h"])
    ns_k = np.stack([to_np(cams.fx[:, 0]), to_np(cams.fy[:, 0]), to_np(cams.cx[:, 0]), to_np(cams.cy[:, 0])], 1)
    kerr = np.abs(ns_k - np.array([fx, fy, cx, cy])).max()
    err_row(S, "fx fy cx cy", kerr, 1e-4, "px")
    wh_ok = bool((cams.width == W).all() and (cams.height == H).all())
    row(S, "w h", f"{int(cams.width[0])}x{int(cams.height[0])}", f"{W}x{H}", wh_ok)
    dist = to_np(cams.distortion_params) if cams.distortion_params is not None else np.zeros(1)
    persp = bool((cams.camera_type == CameraType.PERSPECTIVE.value).all())
    row(S, "camera type, distortion", f"{'PERSPECTIVE' if persp else 'other'}, max |k,p| {np.abs(dist).max():g}",
        "PERSPECTIVE, 0", persp and np.abs(dist).max() == 0.0)

    # ---- rays: full images through Cameras.generate_rays (pixel_offset 0.5 by default)
    o_err = d_err = 0.0
    half_shift = 0.0
    for k in range(n):
        rb = cams.generate_rays(camera_indices=k, keep_shape=True)
        o_ns, d_ns = to_np(rb.origins), to_np(rb.directions)
        o_back = (o_ns / s - t) @ R  # R^T (o/s - t), row vectors
        d_back = d_ns @ R
        o, d = our_rays(ours[k], fx, fy, cx, cy, W, H)
        o_err = max(o_err, np.abs(o_back - o).max())
        d_err = max(d_err, np.abs(d_back - d).max())
        if k == 0:
            # what integer pixel coordinates (no +0.5) would give: shows the convention matters
            yy, xx = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
            rb0 = cams.generate_rays(camera_indices=0, coords=torch.stack([yy, xx], -1).float())
            half_shift = np.abs(to_np(rb0.directions) @ R - d).max()
    err_row(S, f"ray origins, generate_rays ({n} views x {W * H} px)", o_err, 1e-5, "m")
    err_row(S, f"ray directions, generate_rays ({n} views x {W * H} px)", d_err, 1e-5)
    row(S, "  (same with coords = integer pixel indices)", f"max |err| {half_shift:.3g}", "-", None)

    # training path: RayGenerator with (camera, row, col) indices
    gen = RayGenerator(cams)
    rng = np.random.default_rng(0)
    idx = np.stack([rng.integers(0, len(keys), 512), rng.integers(0, H, 512), rng.integers(0, W, 512)], 1)
    idx[:4] = [[0, 0, 0], [0, H - 1, W - 1], [len(keys) - 1, 0, W - 1], [len(keys) - 1, H - 1, 0]]
    rb = gen(torch.from_numpy(idx).long())
    d_back = to_np(rb.directions) @ R
    o_back = (to_np(rb.origins) / s - t) @ R
    ge = go = 0.0
    for r, (c, j, i) in enumerate(idx):
        o, d = our_rays(ours[c], fx, fy, cx, cy, W, H)
        ge = max(ge, np.abs(d_back[r] - d[j, i]).max())
        go = max(go, np.abs(o_back[r] - o[j, i]).max())
    err_row(S, "ray directions, RayGenerator (512 training pixels)", ge, 1e-5)
    err_row(S, "ray origins, RayGenerator (512 training pixels)", go, 1e-5, "m")

    # ---- depth, masks, images through nerfstudio's datasets
    facts = json.loads((ds / "transforms_train.json").read_text()).get("scene_facts") or {}
    facts_box = np.array([facts["aabb_min"], facts["aabb_max"]]) if "aabb_min" in facts else None
    box_err = -math.inf
    depth_ds = DepthDataset(out)
    dm = dz = dd = dd_gt = 0.0
    miss_bad = mask_bad = 0
    mask_px = 0
    png_alpha_edge = 0
    img_err = 0.0
    direct_err = 0.0
    for k in range(n):
        key = keys[k]
        data = depth_ds[k]
        depth_m = to_np(data["depth_image"])[..., 0] / s  # nerfstudio units -> metres
        ref = np.load(ds / f"{key}_depth.npy").astype(np.float64)
        gt = read_gt_exr(ds / f"{key}_gt.exr")
        hit = gt["alpha"] > 0.5
        if k == 0:
            # the loader function on its own, as the brief names it
            direct = get_depth_image_from_path(
                filepath=Path(depth_files[k]), height=H, width=W,
                scale_factor=out.metadata["depth_unit_scale_factor"] * s,
            )
            direct_err = np.abs(to_np(direct)[..., 0] / s - ref)[hit].max()
            depth_first = (key, float(depth_m[hit].min()), float(depth_m[hit].max()))
        dz = max(dz, np.abs(depth_m - ref)[hit].max())
        dm = max(dm, np.abs(depth_m - gt["depth"])[hit].max())
        miss_bad += int((depth_m[~hit] != 0).sum()) + int((ref[~hit] != 0).sum())
        # depth-nerfacto (is_euclidean_depth=False): termination depth = depth * directions_norm
        rb = cams.generate_rays(camera_indices=k, keep_shape=True)
        norm = to_np(rb.metadata["directions_norm"])[..., 0]
        eucl_m = to_np(data["depth_image"])[..., 0] * norm / s
        dd = max(dd, np.abs(eucl_m - gt["distance"])[hit].max())
        # independent of our JSON: nerfstudio's ray x depth must land on the scene (inside its aabb)
        if facts_box is not None:
            pts = (to_np(rb.origins) + to_np(rb.directions) * eucl_m[..., None] * s)[hit]  # nerfstudio space
            pts = (pts / s - t) @ R  # back to ours
            outside = np.maximum(facts_box[0] - pts, pts - facts_box[1]).max()
            box_err = max(box_err, float(outside))
        mask = data["mask"].numpy()[..., 0]
        mask_bad += int((mask != hit).sum())
        mask_px += mask.size
        img = data["image"].numpy().astype(np.float64)
        png = np.asarray(Image.open(ds / f"{key}.png"), dtype=np.float64) / 255.0
        img_err = max(img_err, np.abs(img - png).max()) if img.shape == png.shape else math.inf
        png_alpha_edge += int(((png[..., 3] > 0.5) != hit).sum())
    row(S, f"depth range in metres (DepthDataset, {depth_first[0]})",
        f"{depth_first[1]:.4f} .. {depth_first[2]:.4f} m", "-", None)
    err_row(S, f"depth, get_depth_image_from_path ({depth_first[0]}) vs r_k_depth.npy", direct_err, 1e-4, "m")
    err_row(S, f"depth, DepthDataset / scale vs r_k_depth.npy ({n} views)", dz, 1e-4, "m")
    err_row(S, f"depth, DepthDataset / scale vs gt EXR depth ({n} views)", dm, 1e-4, "m")
    err_row(S, f"depth x directions_norm (depth-nerfacto) vs EXR distance", dd, 1e-4, "m")
    if facts_box is not None:
        row(S, "ray x depth lands inside the scene_facts aabb", f"max outside {max(box_err, 0.0):.3g} m",
            "<= 0.001 m", box_err <= 1e-3)
    row(S, "depth 0 where the pixel-centre ray misses", f"{miss_bad} nonzero", "0", miss_bad == 0)
    row(S, f"mask (InputDataset) vs EXR alpha > 0.5 ({n} views)", f"{mask_bad} of {mask_px} px differ", "0",
        mask_bad == 0)
    err_row(S, f"image (InputDataset, RGBA, no alpha_color) vs PNG", img_err, 1e-6)
    row(S, "  (PNG alpha > 0.5 vs mask: pixel-area coverage vs centre ray)",
        f"{png_alpha_edge} of {mask_px} px differ", "-", None)


# ---------------------------------------------------------------- Blender dataparser


def check_blender_parser(ds: Path, max_views: int) -> None:
    from nerfstudio.cameras.cameras import CameraType
    from nerfstudio.data.datasets.base_dataset import InputDataset
    from nerfstudio.data.dataparsers.blender_dataparser import BlenderDataParserConfig
    from PIL import Image

    S = "blender"
    parser = BlenderDataParserConfig(data=ds).setup()  # every setting at its default
    outs = {}
    metas = {}
    for split in ("train", "val", "test"):
        metas[split] = json.loads((ds / f"transforms_{split}.json").read_text())
        outs[split] = parser.get_dataparser_outputs(split=split)
        exist = all(Path(p).exists() for p in outs[split].image_filenames)
        row(S, f"{split} split: images found", f"{len(outs[split].image_filenames)} images"
            f"{'' if exist else ', some missing'}", f"{len(metas[split]['frames'])} images",
            exist and len(outs[split].image_filenames) == len(metas[split]["frames"]))

    meta, out = metas["train"], outs["train"]
    cams = out.cameras
    frames = meta["frames"]
    n = len(frames) if max_views <= 0 else min(max_views, len(frames))
    c2w_ns = to_np(cams.camera_to_worlds)
    ours = [np.array(f["transform_matrix"], dtype=np.float64) for f in frames]
    err = max(np.abs(c2w_ns[k] - ours[k][:3, :4]).max() for k in range(len(frames)))
    err_row(S, f"pose (no transform, scale_factor 1; {len(frames)} views)", err, 1e-5)

    W, H = int(meta.get("w", int(cams.width[0]))), int(meta.get("h", int(cams.height[0])))
    fx = float(meta.get("fl_x", 0.5 * W / math.tan(0.5 * meta["camera_angle_x"])))
    fy = float(meta.get("fl_y", fx))
    cx, cy = float(meta.get("cx", W / 2)), float(meta.get("cy", H / 2))
    ns_k = np.array([float(cams.fx[0]), float(cams.fy[0]), float(cams.cx[0]), float(cams.cy[0])])
    err_row(S, "fx fy cx cy (from camera_angle_x) vs our fl_x fl_y cx cy", np.abs(ns_k - [fx, fy, cx, cy]).max(),
            1e-3, "px")
    row(S, "w h (from the first image)", f"{int(cams.width[0])}x{int(cams.height[0])}", f"{W}x{H}",
        int(cams.width[0]) == W and int(cams.height[0]) == H)
    row(S, "camera type", "PERSPECTIVE" if bool((cams.camera_type == CameraType.PERSPECTIVE.value).all())
        else "other", "PERSPECTIVE", bool((cams.camera_type == CameraType.PERSPECTIVE.value).all()))

    o_err = d_err = 0.0
    for k in range(n):
        rb = cams.generate_rays(camera_indices=k, keep_shape=True)
        o, d = our_rays(ours[k], fx, fy, cx, cy, W, H)
        o_err = max(o_err, np.abs(to_np(rb.origins) - o).max())
        d_err = max(d_err, np.abs(to_np(rb.directions) - d).max())
    err_row(S, f"ray origins ({n} views x {W * H} px)", o_err, 1e-5, "m")
    err_row(S, f"ray directions ({n} views x {W * H} px)", d_err, 1e-5)

    ds_in = InputDataset(out)
    img = ds_in[0]["image"].numpy().astype(np.float64)
    png = np.asarray(Image.open(out.image_filenames[0]), dtype=np.float64) / 255.0
    want = png[..., :3] * png[..., 3:] + (1.0 - png[..., 3:])
    e = np.abs(img - want).max() if img.shape == want.shape else math.inf
    err_row(S, "image 0 (InputDataset: RGB over white, alpha_color default)", e, 1e-6)

    facts = meta.get("scene_facts") or {}
    if "aabb_min" in facts:
        lo, hi = np.array(facts["aabb_min"]), np.array(facts["aabb_max"])
        box = to_np(out.scene_box.aabb)
        inside = bool((lo >= box[0]).all() and (hi <= box[1]).all())
        row(S, "scene_facts aabb inside the parser's scene_box [-1.5, 1.5]^3",
            f"{np.round(lo, 3).tolist()} .. {np.round(hi, 3).tolist()}", "inside (models that use the box)", None)
        if not inside:  # only models that bound sampling by the scene box care: a warning, not a failure
            ROWS[-1] = ROWS[-1][:4] + ("WARN",)


# ---------------------------------------------------------------- instant-ngp, re-implemented


def check_instant_ngp(ds: Path) -> None:
    """instant-ngp's conventions (NVlabs/instant-ngp, src/nerf_loader.cu and nerf_loader.h).

    * focal length: per json, `x_fov` (degrees), else `fl_x`, else `camera_angle_x`; fy the same.
    * principal point: cx / w, cy / h (default 0.5, 0.5); k1 k2 p1 p2 of 0 keep the pinhole.
    * pose: nerf_matrix_to_ngp: columns 1 and 2 negated (OpenGL -> ngp camera looking down +z,
      y down), translation * scale + offset, then the axes cycled (x, y, z) <- (y, z, x).
    * scale defaults to NERF_SCALE = 0.33, offset to (0.5, 0.5, 0.5), aabb_scale to 1: the
      scene must lie in the unit cube [0, 1]^3 of ngp space, i.e. within
      [-0.5/0.33, 0.5/0.33]^3 = [-1.515, 1.515]^3 of ours, unless the json sets `scale`,
      `offset`, `aabb_scale` (power of two, <= 128) or `aabb`.
    * ray through pixel (i, j): uv = (i + 0.5, j + 0.5) / (w, h);
      d_cam = ((u - ppx) w / fx, (v - ppy) h / fy, 1); d = M[:, :3] d_cam.
    """
    S = "instant-ngp*"
    meta = json.loads((ds / "transforms_train.json").read_text())
    W, H = int(meta["w"]), int(meta["h"])
    f_x = float(meta["fl_x"]) if "fl_x" in meta else 0.5 * W / math.tan(0.5 * float(meta["camera_angle_x"]))
    f_angle = 0.5 * W / math.tan(0.5 * float(meta["camera_angle_x"]))
    err_row(S, "fl_x (read first) vs camera_angle_x focal", abs(f_x - f_angle), 1e-3, "px")
    scale = float(meta.get("scale", 0.33))
    off = meta.get("offset", [0.5, 0.5, 0.5])
    off = np.array(off if isinstance(off, list) else [off] * 3, dtype=np.float64)
    aabb_scale = int(meta.get("aabb_scale", 1))
    fy = float(meta.get("fl_y", f_x))
    ppx, ppy = float(meta.get("cx", W / 2)) / W, float(meta.get("cy", H / 2)) / H

    def nerf_matrix_to_ngp(m: np.ndarray) -> np.ndarray:
        r = m[:3, :4].copy()
        r[:, 1] *= -1
        r[:, 2] *= -1
        r[:, 3] = r[:, 3] * scale + off
        return r[[1, 2, 0], :]  # rows cycled: ngp (x, y, z) = ours (y, z, x)

    derr = 0.0
    for f in meta["frames"]:
        m = np.array(f["transform_matrix"], dtype=np.float64)
        M = nerf_matrix_to_ngp(m)
        j, i = np.meshgrid(np.arange(H) + 0.5, np.arange(W) + 0.5, indexing="ij")
        u, v = i / W, j / H
        dc = np.stack([(u - ppx) * W / f_x, (v - ppy) * H / fy, np.ones_like(u)], -1)
        d = dc @ M[:, :3].T
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        d_ours = d[..., [2, 0, 1]]  # back to our axes
        _, ref = our_rays(m, float(meta["fl_x"]), fy, float(meta.get("cx", W / 2)), float(meta.get("cy", H / 2)), W, H)
        derr = max(derr, np.abs(d_ours - ref).max())
    err_row(S, f"ray directions, ngp camera model ({len(meta['frames'])} views)", derr, 1e-9)

    facts = meta.get("scene_facts") or {}
    if "aabb_min" in facts:
        lo, hi = np.array(facts["aabb_min"]), np.array(facts["aabb_max"])
        cube_lo = 0.5 - 0.5 * aabb_scale
        cube_hi = 0.5 + 0.5 * aabb_scale
        p_lo, p_hi = lo * scale + off, hi * scale + off
        inside = bool((p_lo >= cube_lo).all() and (p_hi <= cube_hi).all())
        keys = ", ".join(k for k in ("scale", "offset", "aabb_scale", "aabb") if k in meta) or "none written"
        row(S, f"scene_facts aabb in ngp's box (keys: {keys})",
            f"{np.round(p_lo, 3).tolist()} .. {np.round(p_hi, 3).tolist()}",
            f"[{cube_lo:g}, {cube_hi:g}]^3", inside)
        # what a writer could put in the json so the box fills the unit cube with a 10 % margin
        ext = float((hi - lo).max())
        s_fit = 1.0 / (1.1 * ext)
        o_fit = 0.5 - s_fit * 0.5 * (lo + hi)
        row(S, "  scale/offset that fit the aabb (+10 %) in [0,1]^3",
            f"scale {s_fit:.4f}, offset {np.round(o_fit, 4).tolist()}", "-", None)
    # given a folder, ngp loads every *.json in it and trains on the frames of all of them
    counts = {p.name: len(json.loads(p.read_text()).get("frames") or []) for p in sorted(ds.glob("*.json"))}
    with_frames = {k: v for k, v in counts.items() if v}
    row(S, "  frames ngp loads given the folder (every *.json)",
        f"{sum(with_frames.values())} from {len(with_frames)} files (" + ", ".join(f"{k} {v}" for k, v in
        with_frames.items()) + ")", "pass transforms_train.json", None)
    if len(with_frames) > 1:  # each view more than once, val/test views in training: a usage warning
        ROWS[-1] = ROWS[-1][:4] + ("WARN",)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dataset", type=Path, help="dataset folder written by `xtask render`")
    ap.add_argument("--views", type=int, default=0,
                    help="check rays/depth/masks on the first N train views only (0 = all, the default)")
    args = ap.parse_args()
    ds: Path = args.dataset
    for name in ("transforms.json", "transforms_train.json", "transforms_val.json", "transforms_test.json"):
        if not (ds / name).is_file():
            print(f"error: {ds / name} not found (is {ds} a dataset written by `xtask render`?)", file=sys.stderr)
            return 2

    import nerfstudio
    import torch

    from importlib.metadata import version

    print(f"dataset: {ds.resolve()}")
    print(f"nerfstudio {version('nerfstudio')}, torch {torch.__version__}, numpy {np.__version__}, device cpu")
    t0 = time.time()
    for section, fn in (("nerfstudio", lambda: check_nerfstudio_parser(ds, args.views)),
                        ("blender", lambda: check_blender_parser(ds, args.views)),
                        ("instant-ngp*", lambda: check_instant_ngp(ds))):
        try:
            fn()
        except Exception as e:  # a loader that raises is a failed check, not a crash of the script
            import traceback

            traceback.print_exc()
            row(section, "dataparser/loaders ran", f"{type(e).__name__}: {e}"[:120], "no exception", False)
    print()
    print_table()
    print()
    print("* instant-ngp: its loader conventions re-implemented in numpy from its source "
          "(needs CUDA; not run here).")
    fails = sum(r[4] == "FAIL" for r in ROWS)
    passes = sum(r[4] == "PASS" for r in ROWS)
    print(f"{passes} passed, {fails} failed ({time.time() - t0:.1f} s)")
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())
