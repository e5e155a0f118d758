"""Writes a small non-uniform equirectangular test map (OpenEXR, linear RGB) for the
environment-map cross-check: a blue-to-white sky gradient, a dim brown ground, a bright warm
"sun" patch at azimuth 60 deg (u = 1/6), elevation 35 deg, and a green patch on the horizon at
u = 0.75 (+X would be u = 0.25), so a mirrored or rotated map shows in the image mean.

    .venv/bin/python tests/mitsuba/make_envmap.py out/sky.exr [--width 64]
"""

import argparse
import math

import numpy as np


def sky(width):
    h = width // 2
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(width) + 0.5) / width
    uu, vv = np.meshgrid(u, v)
    elev = 0.5 * math.pi - math.pi * vv
    img = np.zeros((h, width, 3), np.float32)
    up = np.clip(np.sin(elev), 0.0, 1.0)[..., None]
    img[:] = np.where(elev[..., None] > 0, (1.0 - up) * np.array([1.0, 1.0, 1.0]) + up * np.array([0.25, 0.45, 1.0]),
                      np.array([0.12, 0.08, 0.05]))
    sun = (np.abs(uu - 1.0 / 6.0) < 0.04) & (np.abs(elev - math.radians(35)) < 0.12)
    img[sun] = [40.0, 30.0, 18.0]
    green = (np.abs(uu - 0.75) < 0.05) & (np.abs(elev) < 0.2)
    img[green] = [0.2, 3.0, 0.3]
    return img


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("out")
    p.add_argument("--width", type=int, default=64)
    a = p.parse_args()
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    mi.Bitmap(sky(a.width)).write(a.out)
    print(a.out)


if __name__ == "__main__":
    main()
