"""The living room with glazing: the bundled room's open window frame given glass panes, under a
sun and a sky, for the glass cross-check against the Mitsuba tool.

Run make_living_room_sky.py OUT first (it writes OUT/living_room_sun.glb, OUT/sky.exr and
OUT/points.json: 60 interior points on the floor, the back wall and the ceiling); this adds
to OUT:
* living_room_blend.glb: one double-sided quad per opening of the window frame (three, at the
  frame's mid-depth z = 2.25, x in [-3.4, -0.6], [-0.5, 0.5], [0.6, 3.4], y in [1.1, 3.4]),
  material "glass_blend": alphaMode BLEND, baseColorFactor (0.8, 0.9, 0.9, 0.25): T = 0.75
  untinted, reflectance 0.25 a;
* living_room_transmission.glb: the same panes with "glass_transmission":
  KHR_materials_transmission 0.85, baseColorFactor (0.75, 0.9, 0.85, 1): T = 0.85 a (tinted),
  reflectance 0.15 a.
Run with the Mitsuba tool's Python (it has numpy and pygltflib).
"""
import copy, os, struct, sys
import pygltflib

out = sys.argv[1] if len(sys.argv) > 1 else "/tmp/lr"
src = os.path.join(out, "living_room_sun.glb")
OPENINGS = [(-3.4, -0.6), (-0.5, 0.5), (0.6, 3.4)]
Y0, Y1, Z = 1.1, 3.4, 2.25
MATERIALS = {
    "blend": pygltflib.Material(
        name="glass_blend", alphaMode="BLEND", doubleSided=True,
        pbrMetallicRoughness=pygltflib.PbrMetallicRoughness(baseColorFactor=[0.8, 0.9, 0.9, 0.25], metallicFactor=0.0),
    ),
    "transmission": pygltflib.Material(
        name="glass_transmission", doubleSided=True,
        pbrMetallicRoughness=pygltflib.PbrMetallicRoughness(baseColorFactor=[0.75, 0.9, 0.85, 1.0], metallicFactor=0.0),
        extensions={"KHR_materials_transmission": {"transmissionFactor": 0.85}},
    ),
}

for kind, material in MATERIALS.items():
    g = pygltflib.GLTF2().load(src)
    blob = bytearray(g.binary_blob())
    positions, normals, indices = [], [], []
    for x0, x1 in OPENINGS:
        base = len(positions)
        # Counter-clockwise seen from the room (front toward -Z, into the room).
        positions += [(x1, Y0, Z), (x0, Y0, Z), (x0, Y1, Z), (x1, Y1, Z)]
        normals += [(0.0, 0.0, -1.0)] * 4
        indices += [base, base + 1, base + 2, base, base + 2, base + 3]

    def view(data, target):
        while len(blob) % 4:
            blob.append(0)
        g.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data), target=target))
        blob.extend(data)
        return len(g.bufferViews) - 1

    pos_bytes = b"".join(struct.pack("<3f", *p) for p in positions)
    nrm_bytes = b"".join(struct.pack("<3f", *n) for n in normals)
    idx_bytes = b"".join(struct.pack("<H", i) for i in indices)
    lo = [min(p[k] for p in positions) for k in range(3)]
    hi = [max(p[k] for p in positions) for k in range(3)]
    g.accessors.append(pygltflib.Accessor(bufferView=view(pos_bytes, 34962), componentType=5126, count=len(positions),
                                          type="VEC3", min=lo, max=hi))
    pa = len(g.accessors) - 1
    g.accessors.append(pygltflib.Accessor(bufferView=view(nrm_bytes, 34962), componentType=5126, count=len(normals), type="VEC3"))
    na = len(g.accessors) - 1
    g.accessors.append(pygltflib.Accessor(bufferView=view(idx_bytes, 34963), componentType=5123, count=len(indices), type="SCALAR"))
    ia = len(g.accessors) - 1
    g.materials.append(copy.deepcopy(material))
    prim = pygltflib.Primitive(attributes=pygltflib.Attributes(POSITION=pa, NORMAL=na), indices=ia, material=len(g.materials) - 1)
    g.meshes.append(pygltflib.Mesh(name="glazing", primitives=[prim]))
    g.nodes.append(pygltflib.Node(name="glazing", mesh=len(g.meshes) - 1))
    g.scenes[g.scene or 0].nodes.append(len(g.nodes) - 1)
    if kind == "transmission":
        g.extensionsUsed = sorted(set((g.extensionsUsed or []) + ["KHR_materials_transmission"]))
    g.buffers[0].byteLength = len(blob)
    g.set_binary_blob(bytes(blob))
    path = os.path.join(out, f"living_room_{kind}.glb")
    g.save(path)
    print("wrote", path)
