#!/usr/bin/env python3
"""Writes assets/zdm2/: the zdm2 game map (Cube 2: Sauerbraten, as Godot's GI demo ships it)
as zdm2.gltf + zdm2.bin, the GLB's own JSON and binary chunk unchanged, and zdm2_sun.gltf: the
same file (it reads zdm2.bin) plus a KHR_lights_punctual directional light, since the map
ships without lights and real scenes have a sun.

Usage: scripts/make_zdm2.py PATH/TO/zdm2.glb"""
import json, math, os, struct, sys

SUN_ELEVATION, SUN_AZIMUTH, SUN_IRRADIANCE = 50.0, 35.0, 4.0  # degrees, degrees from -Z toward +X, W/m2

def glb_chunks(data):
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF" and version == 2 and length == len(data), "not a glTF 2.0 GLB"
    off, chunks = 12, {}
    while off < length:
        size, kind = struct.unpack_from("<I4s", data, off)
        chunks[kind] = data[off + 8 : off + 8 + size]
        off += 8 + size
    return json.loads(chunks[b"JSON"]), chunks[b"BIN\x00"]

def rotation_from_neg_z(d):
    """Unit quaternion (x, y, z, w) turning -Z onto the unit vector d (shortest arc)."""
    a = (0.0, 0.0, -1.0)
    cross = (a[1] * d[2] - a[2] * d[1], a[2] * d[0] - a[0] * d[2], a[0] * d[1] - a[1] * d[0])
    w = 1.0 + sum(x * y for x, y in zip(a, d))
    n = math.sqrt(sum(c * c for c in cross) + w * w)
    return [cross[0] / n, cross[1] / n, cross[2] / n, w / n]

def main():
    glb = open(sys.argv[1], "rb").read()
    doc, blob = glb_chunks(glb)
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "assets", "zdm2")
    os.makedirs(out, exist_ok=True)
    blob = blob[: doc["buffers"][0]["byteLength"]]
    open(os.path.join(out, "zdm2.bin"), "wb").write(blob)
    doc["buffers"][0]["uri"] = "zdm2.bin"
    json.dump(doc, open(os.path.join(out, "zdm2.gltf"), "w"), indent=1)
    el, az = math.radians(SUN_ELEVATION), math.radians(SUN_AZIMUTH)
    toward_sun = (math.cos(el) * math.sin(az), math.sin(el), -math.cos(el) * math.cos(az))
    travel = tuple(-c for c in toward_sun)
    doc.setdefault("extensionsUsed", []).append("KHR_lights_punctual")
    doc.setdefault("extensions", {})["KHR_lights_punctual"] = {
        "lights": [{"type": "directional", "name": "sun", "color": [1.0, 0.95, 0.85], "intensity": SUN_IRRADIANCE}]
    }
    doc["nodes"].append({"name": "sun", "rotation": rotation_from_neg_z(travel), "extensions": {"KHR_lights_punctual": {"light": 0}}})
    doc["scenes"][doc.get("scene", 0)]["nodes"].append(len(doc["nodes"]) - 1)
    json.dump(doc, open(os.path.join(out, "zdm2_sun.gltf"), "w"), indent=1)

main()
