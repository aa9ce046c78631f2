#!/usr/bin/env python3
"""Writes the assets of scenes/textured-sky.toml and scenes/gltf-boxes.toml: an HDR sky, four
small PNG textures (one a normal map) and a glTF file. Everything here is made from scratch; run it from this folder
to remake them (`python3 make_assets.py`). Standard library only."""

import base64
import json
import math
import struct
import zlib


def png(path, width, height, pixel):
    """An 8-bit RGBA PNG; pixel(x, y) gives (r, g, b, a), row 0 at the top."""
    raw = bytearray()
    for y in range(height):
        raw.append(0)
        for x in range(width):
            raw.extend(pixel(x, y))

    def chunk(kind, data):
        c = struct.pack(">I", len(data)) + kind + data
        return c + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(bytes(raw), 9))
                + chunk(b"IEND", b""))


def rgbe(r, g, b):
    m = max(r, g, b)
    if m < 1e-32:
        return bytes(4)
    mantissa, exponent = math.frexp(m)
    scale = mantissa * 256.0 / m
    return bytes([int(r * scale), int(g * scale), int(b * scale), exponent + 128])


def hdr(path, width, height, radiance):
    """A Radiance HDR file with flat (uncompressed) scanlines; radiance(u, v) at texel centres."""
    with open(path, "wb") as f:
        f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n")
        f.write(f"-Y {height} +X {width}\n".encode())
        for y in range(height):
            for x in range(width):
                f.write(rgbe(*radiance((x + 0.5) / width, (y + 0.5) / height)))


def sky(u, v):
    """Equirectangular, as Arbor maps it: v = 0 straight up, u = 0 looking along -z."""
    elevation = (0.5 - v) * math.pi
    phi = 2 * math.pi * u
    d = (math.sin(phi) * math.cos(elevation), math.sin(elevation), -math.cos(phi) * math.cos(elevation))
    # The sun: 35 degrees up, a little toward +x and +z, about 2 degrees across.
    s_el, s_phi = math.radians(35), 2 * math.pi * 0.3
    s = (math.sin(s_phi) * math.cos(s_el), math.sin(s_el), -math.cos(s_phi) * math.cos(s_el))
    cos_sun = sum(a * b for a, b in zip(d, s))
    if cos_sun > math.cos(math.radians(1.2)):
        return (2600.0, 2300.0, 1900.0)
    if elevation < 0:
        return (0.22, 0.19, 0.15)
    t = elevation / (math.pi / 2)
    horizon, zenith = (0.85, 0.9, 1.0), (0.18, 0.35, 0.85)
    glow = 0.6 * max(cos_sun, 0.0) ** 8
    return tuple((1 - t) * h + t * z + glow for h, z in zip(horizon, zenith))


def checker(x, y):
    light = ((x // 8) + (y // 8)) % 2 == 0
    return (200, 200, 190, 255) if light else (60, 90, 70, 255)


def lattice(x, y):
    bar = x % 16 < 4 or y % 16 < 4
    return (150, 95, 50, 255) if bar else (0, 0, 0, 0)


def crate(x, y):
    edge = x < 4 or y < 4 or x >= 28 or y >= 28 or abs(x - y) < 3
    return (120, 75, 35, 255) if edge else (185, 140, 80, 255)


def ripples(x, y):
    """A tangent-space normal map (x, y, z stored as (v + 1) / 2) of shallow rounded tiles."""
    def slope(t):
        # The height of a tile across one axis, a smooth bump: its derivative.
        return 0.6 * math.sin(2 * math.pi * (t % 16) / 16)
    nx, ny = -slope(x + 0.5), slope(y + 0.5)
    length = math.sqrt(nx * nx + ny * ny + 1)
    return tuple(int(round((c / length + 1) / 2 * 255)) for c in (nx, ny, 1.0)) + (255,)


def cube():
    """A cube from -0.5 to 0.5: 24 vertices (4 a face) with normals and texture coordinates."""
    faces = [((1, 0, 0), (0, 0, -1)), ((-1, 0, 0), (0, 0, 1)), ((0, 1, 0), (1, 0, 0)),
             ((0, -1, 0), (1, 0, 0)), ((0, 0, 1), (1, 0, 0)), ((0, 0, -1), (-1, 0, 0))]
    pos, nrm, uv, idx = [], [], [], []
    for n, t in faces:
        b = (n[1] * t[2] - n[2] * t[1], n[2] * t[0] - n[0] * t[2], n[0] * t[1] - n[1] * t[0])
        base = len(pos) // 3
        for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            pos += [0.5 * (n[k] + su * t[k] + sv * b[k]) for k in range(3)]
            nrm += list(n)
            uv += [(su + 1) / 2, (1 - sv) / 2]  # glTF: v down from the top
        idx += [base, base + 1, base + 2, base, base + 2, base + 3]
    return pos, nrm, uv, idx


def gltf(path):
    bin_ = bytearray()
    views, accessors = [], []

    def add(values, fmt, ty, count, component, target):
        while len(bin_) % 4:
            bin_.append(0)
        data = struct.pack(f"<{len(values)}{fmt}", *values)
        views.append({"buffer": 0, "byteOffset": len(bin_), "byteLength": len(data), "target": target})
        bin_.extend(data)
        accessors.append({"bufferView": len(views) - 1, "componentType": component, "count": count, "type": ty})
        return len(accessors) - 1

    pos, nrm, uv, idx = cube()
    p = add(pos, "f", "VEC3", 24, 5126, 34962)
    accessors[p]["min"], accessors[p]["max"] = [-0.5] * 3, [0.5] * 3
    n = add(nrm, "f", "VEC3", 24, 5126, 34962)
    t = add(uv, "f", "VEC2", 24, 5126, 34962)
    i = add(idx, "H", "SCALAR", 36, 5123, 34963)
    ground_pos = [-4, 0, -4, 4, 0, -4, 4, 0, 4, -4, 0, 4]
    gp = add(ground_pos, "f", "VEC3", 4, 5126, 34962)
    accessors[gp]["min"], accessors[gp]["max"] = [-4, 0, -4], [4, 0, 4]
    gt = add([0, 0, 4, 0, 4, 4, 0, 4], "f", "VEC2", 4, 5126, 34962)
    gi = add([0, 2, 1, 0, 3, 2], "H", "SCALAR", 6, 5123, 34963)
    doc = {
        "asset": {"version": "2.0", "generator": "Arbor scenes/assets/make_assets.py"},
        "scene": 0,
        "scenes": [{"nodes": [0, 4, 5]}],
        "nodes": [
            {"name": "stack", "translation": [0, 0, 0], "children": [1, 2, 3]},
            {"name": "crate", "mesh": 0, "translation": [-0.7, 0.5, 0], "rotation": [0, 0.2588, 0, 0.9659]},
            {"name": "crate on top", "mesh": 0, "translation": [-0.6, 1.3, 0.05], "scale": [0.6, 0.6, 0.6],
             "rotation": [0, -0.3827, 0, 0.9239]},
            {"name": "mirrored metal block", "mesh": 1,
             "matrix": [-0.8, 0, 0, 0, 0, 0.8, 0, 0, 0, 0, 0.8, 0, 0.8, 0.4, 0.3, 1]},
            {"name": "ground", "mesh": 2},
            {"name": "camera", "camera": 0, "translation": [0.3, 1.6, 4.2], "rotation": [-0.1305, 0, 0, 0.9914]},
        ],
        "meshes": [
            {"name": "crate", "primitives": [{"attributes": {"POSITION": p, "NORMAL": n, "TEXCOORD_0": t},
                                               "indices": i, "material": 0}]},
            {"name": "metal block", "primitives": [{"attributes": {"POSITION": p, "NORMAL": n},
                                                     "indices": i, "material": 1}]},
            {"name": "ground", "primitives": [{"attributes": {"POSITION": gp, "TEXCOORD_0": gt},
                                                "indices": gi, "material": 2}]},
        ],
        "materials": [
            {"name": "crate", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0.0,
                                                       "roughnessFactor": 0.9}},
            {"name": "metal", "pbrMetallicRoughness": {"baseColorFactor": [0.95, 0.8, 0.55, 1],
                                                       "metallicFactor": 1.0, "roughnessFactor": 0.5}},
            {"name": "ground", "pbrMetallicRoughness": {"baseColorTexture": {"index": 1}, "metallicFactor": 0.0}},
        ],
        "textures": [{"source": 0, "sampler": 0}, {"source": 1, "sampler": 0}],
        "samplers": [{"wrapS": 10497, "wrapT": 10497}],
        "images": [{"uri": "crate.png"}, {"uri": "checker.png"}],
        "cameras": [{"type": "perspective", "perspective": {"yfov": 0.7, "znear": 0.05}}],
        "buffers": [{"byteLength": len(bin_),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(bin_)).decode()}],
        "bufferViews": views,
        "accessors": accessors,
    }
    with open(path, "w") as f:
        json.dump(doc, f, indent=1)
        f.write("\n")


if __name__ == "__main__":
    hdr("sky.hdr", 256, 128, sky)
    png("checker.png", 64, 64, checker)
    png("lattice.png", 64, 64, lattice)
    png("ripples.png", 64, 64, ripples)
    png("crate.png", 32, 32, crate)
    gltf("boxes.gltf")
