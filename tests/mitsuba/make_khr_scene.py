"""Writes `scenes/khr_materials.gltf`: a small scene for the Mitsuba cross-check that uses
KHR_materials_specular (factor, texture, colour factor, colour texture), KHR_materials_ior
(1.8 and 0) and KHR_texture_transform (offset, rotation, scale, and a texCoord override from
1 to 0 on a mesh without TEXCOORD_1, so a missed override shows). Standard library only;
the output is byte-identical on every run.

    python3 tests/mitsuba/make_khr_scene.py  # then: cargo xtask crosscheck tests/mitsuba/scenes/khr_materials.gltf
"""

import base64
import json
import os
import struct
import zlib


def png(w, h, rgba):
    """An 8-bit RGBA PNG of `rgba` (rows top first, each a list of (r, g, b, a))."""
    raw = b"".join(b"\x00" + bytes(c for px in row for c in px) for row in rgba)

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 6, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def uri(data, mime):
    return f"data:{mime};base64,{base64.b64encode(data).decode()}"


def quad(corners, uvs):
    """Two triangles (counter-clockwise seen from the normal's side)."""
    return corners, uvs, [0, 1, 2, 0, 2, 3]


def main():
    # Floor (y = 0) and two panels standing on it, facing +z; double-sided (ours never hits a
    # single-sided back face, Mitsuba does: an open scene would show the difference).
    quads = [
        quad([(-2, 0, 2), (2, 0, 2), (2, 0, -2), (-2, 0, -2)], [(0, 0), (1, 0), (1, 1), (0, 1)]),
        quad([(-1.6, 0, 0), (-0.1, 0, 0), (-0.1, 1.5, 0), (-1.6, 1.5, 0)], [(0, 1), (1, 1), (1, 0), (0, 0)]),
        quad([(0.1, 0, 0), (1.6, 0, 0), (1.6, 1.5, 0), (0.1, 1.5, 0)], [(0, 1), (1, 1), (1, 0), (0, 0)]),
    ]
    buf = b""
    views, accessors, prims = [], [], []
    for k, (pos, uv, idx) in enumerate(quads):
        base = len(accessors)
        for data, typ, fmt, n in [(pos, "VEC3", "<3f", 3), (uv, "VEC2", "<2f", 2)]:
            b = b"".join(struct.pack(fmt, *map(float, v)) for v in data)
            views.append({"buffer": 0, "byteOffset": len(buf), "byteLength": len(b)})
            acc = {"bufferView": len(views) - 1, "componentType": 5126, "count": len(data), "type": typ}
            if typ == "VEC3":
                acc["min"] = [min(v[i] for v in data) for i in range(3)]
                acc["max"] = [max(v[i] for v in data) for i in range(3)]
            accessors.append(acc)
            buf += b
        b = b"".join(struct.pack("<H", i) for i in idx) + b"\x00\x00"
        views.append({"buffer": 0, "byteOffset": len(buf), "byteLength": 2 * len(idx)})
        accessors.append({"bufferView": len(views) - 1, "componentType": 5123, "count": len(idx), "type": "SCALAR"})
        buf += b
        prims.append({"attributes": {"POSITION": base, "TEXCOORD_0": base + 1}, "indices": base + 2, "material": k})
    # Image 0: 4x4 colour checker (sRGB); image 1: alpha ramp left to right (specular weight).
    checker = [[(230, 60, 40, 255) if (x + y) % 2 else (40, 200, 230, 255) for x in range(4)] for y in range(4)]
    ramp = [[(255, 255, 255, int(255 * (x + 1) / 4)) for x in range(4)] for y in range(4)]
    transform = {"offset": [0.25, 0.1], "rotation": 0.4, "scale": [2.0, 1.5]}
    gltf = {
        "asset": {"version": "2.0", "generator": "tests/mitsuba/make_khr_scene.py"},
        "extensionsUsed": ["KHR_lights_punctual", "KHR_materials_ior", "KHR_materials_specular", "KHR_texture_transform"],
        "buffers": [{"byteLength": len(buf), "uri": uri(buf, "application/octet-stream")}],
        "bufferViews": views,
        "accessors": accessors,
        "images": [{"uri": uri(png(4, 4, checker), "image/png")}, {"uri": uri(png(4, 4, ramp), "image/png")}],
        "samplers": [{"magFilter": 9728, "minFilter": 9728}],
        "textures": [{"source": 0, "sampler": 0}, {"source": 1, "sampler": 0}],
        "materials": [
            {"name": "floor", "doubleSided": True, "pbrMetallicRoughness": {"baseColorFactor": [0.6, 0.6, 0.6, 1], "metallicFactor": 0, "roughnessFactor": 0.8}},
            {"name": "specular colour, ior 1.8", "doubleSided": True,
             "pbrMetallicRoughness": {"baseColorFactor": [0.15, 0.15, 0.15, 1], "metallicFactor": 0, "roughnessFactor": 0.35},
             "extensions": {
                 "KHR_materials_specular": {"specularFactor": 0.9, "specularColorFactor": [1.0, 0.7, 0.4],
                                            "specularColorTexture": {"index": 0, "texCoord": 1,
                                                                     "extensions": {"KHR_texture_transform": dict(transform, texCoord=0)}}},
                 "KHR_materials_ior": {"ior": 1.8}}},
            {"name": "specular texture, ior 0", "doubleSided": True,
             "pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0, "roughnessFactor": 0.45,
                                      "baseColorTexture": {"index": 0, "extensions": {"KHR_texture_transform": {"rotation": -0.7, "scale": [3, 3]}}}},
             "extensions": {
                 "KHR_materials_specular": {"specularFactor": 0.6, "specularColorFactor": [0.5, 0.8, 1.0],
                                            "specularTexture": {"index": 1, "extensions": {"KHR_texture_transform": {"offset": [0.5, 0], "scale": [-1, 1]}}}},
                 "KHR_materials_ior": {"ior": 0}}},
        ],
        "meshes": [{"primitives": prims}],
        "extensions": {"KHR_lights_punctual": {"lights": [
            {"type": "point", "intensity": 12.0, "color": [1, 1, 1]},
            {"type": "directional", "intensity": 2.0, "color": [1, 0.95, 0.9]}]}},
        "nodes": [
            {"mesh": 0},
            {"translation": [0.6, 2.2, 2.0], "extensions": {"KHR_lights_punctual": {"light": 0}}},
            {"rotation": [-0.3826834, 0.0, 0.0, 0.9238795], "extensions": {"KHR_lights_punctual": {"light": 1}}},
        ],
        "scenes": [{"nodes": [0, 1, 2]}],
        "scene": 0,
    }
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "scenes", "khr_materials.gltf")
    with open(out, "w") as f:
        json.dump(gltf, f, indent=1)
        f.write("\n")
    print(out)


if __name__ == "__main__":
    main()
