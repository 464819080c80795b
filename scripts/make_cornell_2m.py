#!/usr/bin/env python3
"""Writes assets/cornell_2m/cornell_2m.gltf: the 2 m Cornell-style room livebake's benchmarks
and cross-checks use (the same room as tests/bundle_bake.rs). Single-sided walls facing in,
albedo 0.7 (red and green side walls), a block, a 0.5 m lamp (15 W/(sr·m²)) under the
ceiling facing down. One self-contained .gltf (data: URI buffer), flat per-face vertices."""
import base64, json, os, struct

def quad(a, b, c, d):
    return [a, b, c, d], [(0, 1, 2), (0, 2, 3)]

def box(lo, hi):
    x0, y0, z0 = lo; x1, y1, z1 = hi
    p = lambda x, y, z: ([x0, x1][x], [y0, y1][y], [z0, z1][z])
    faces = [
        [p(0,0,0), p(0,0,1), p(0,1,1), p(0,1,0)], [p(1,0,0), p(1,1,0), p(1,1,1), p(1,0,1)],
        [p(0,0,0), p(1,0,0), p(1,0,1), p(0,0,1)], [p(0,1,0), p(0,1,1), p(1,1,1), p(1,1,0)],
        [p(0,0,0), p(0,1,0), p(1,1,0), p(1,0,0)], [p(0,0,1), p(1,0,1), p(1,1,1), p(0,1,1)],
    ]
    pos, tri = [], []
    for f in faces:
        base = len(pos); pos += f
        tri += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return pos, tri

H = 0.25
meshes = [
    ("floor", quad((0,0,2), (2,0,2), (2,0,0), (0,0,0)), "white"),
    ("ceiling", quad((0,2,0), (2,2,0), (2,2,2), (0,2,2)), "white"),
    ("back", quad((0,0,0), (2,0,0), (2,2,0), (0,2,0)), "white"),
    ("front", quad((0,0,2), (0,2,2), (2,2,2), (2,0,2)), "white"),
    ("left", quad((0,0,0), (0,2,0), (0,2,2), (0,0,2)), "red"),
    ("right", quad((2,0,0), (2,0,2), (2,2,2), (2,2,0)), "green"),
    ("block", box((0.4,0,0.5), (1.0,1.1,1.1)), "white"),
    ("lamp", quad((1-H,1.99,1-H), (1+H,1.99,1-H), (1+H,1.99,1+H), (1-H,1.99,1+H)), "lamp"),
]
materials = {
    "white": {"name": "white", "pbrMetallicRoughness": {"baseColorFactor": [0.7, 0.7, 0.7, 1], "metallicFactor": 0, "roughnessFactor": 1}},
    "red": {"name": "red", "pbrMetallicRoughness": {"baseColorFactor": [0.7, 0.1, 0.1, 1], "metallicFactor": 0, "roughnessFactor": 1}},
    "green": {"name": "green", "pbrMetallicRoughness": {"baseColorFactor": [0.1, 0.7, 0.1, 1], "metallicFactor": 0, "roughnessFactor": 1}},
    "lamp": {"name": "lamp", "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 0, 1], "metallicFactor": 0, "roughnessFactor": 1},
             "emissiveFactor": [1, 1, 1], "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 15.0}}},
}
mat_names = list(materials)
blob = b""; views = []; accessors = []; gl_meshes = []
for name, (pos, tri), mat in meshes:
    # Unweld: every triangle gets its own three vertices (flat normals everywhere).
    verts = [pos[i] for t in tri for i in t]
    off = len(blob)
    blob += b"".join(struct.pack("<3f", *v) for v in verts)
    views.append({"buffer": 0, "byteOffset": off, "byteLength": 12 * len(verts)})
    lo = [min(v[k] for v in verts) for k in range(3)]; hi = [max(v[k] for v in verts) for k in range(3)]
    accessors.append({"bufferView": len(views) - 1, "componentType": 5126, "count": len(verts), "type": "VEC3", "min": lo, "max": hi})
    gl_meshes.append({"name": name, "primitives": [{"attributes": {"POSITION": len(accessors) - 1}, "material": mat_names.index(mat)}]})
doc = {
    "asset": {"version": "2.0", "generator": "livebake scripts/make_cornell_2m.py"},
    "extensionsUsed": ["KHR_materials_emissive_strength"],
    "scene": 0, "scenes": [{"nodes": list(range(len(gl_meshes)))}],
    "nodes": [{"mesh": i, "name": m["name"]} for i, m in enumerate(gl_meshes)],
    "meshes": gl_meshes, "materials": [materials[n] for n in mat_names],
    "accessors": accessors, "bufferViews": views,
    "buffers": [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
}
out = os.path.join(os.path.dirname(__file__), "..", "assets", "cornell_2m", "cornell_2m.gltf")
with open(out, "w") as f:
    json.dump(doc, f, indent=1)
print("wrote", out)
