#!/usr/bin/env python3
"""Blender Cycles' time to a relative RMS error against a reference, measured: the
comparison `livebake bench --only convergence` makes with Cycles when it is given a Python
that has `bpy` (Blender as a Python module, `pip install bpy`) in LIVEBAKE_CYCLES_PYTHON.

    PYTHON_WITH_BPY scripts/cycles_time_to_error.py SCENE.gltf POINTS.json REFERENCE.json
        [--texel-size 0.012] [--targets 0.10,0.05] [--threads 2] [--max-samples 4096]
        [--out OUT.json]

What Cycles does is what livebake does: it bakes the scene's irradiance into a light map at
the same texel size, and the map is read at the reference points. The scene is imported with
Blender's glTF importer, its meshes joined, welded, unwrapped (Smart UV Project, islands
packed with a 2-texel margin) and the image's resolution chosen so that the mean texel edge
is TEXEL_SIZE. Materials become what the reference renders: a Lambertian Diffuse BSDF of
the base colour; an emissive material emits its emissive colour × strength from its front
face only (glTF's single-sided surfaces; Cycles' emission is two-sided otherwise). The world
is black. Cycles bakes the DIFFUSE pass, direct + indirect light without the colour, so a
texel holds E/π; E = π × the bilinear read at the point's UV. Cycles settings: CPU, THREADS
threads, no denoising, no clamping, no light-path cut short (max and diffuse bounces 1024:
Russian roulette ends paths, as in the reference), the light tree, 16 px bake margin.

The samples per texel double from 1 until the error is below the smallest target (or
MAX_SAMPLES). Seconds are the wall time of `bpy.ops.object.bake` alone: Cycles' scene sync,
BVH build, the path tracing and the write into the image; the import, the unwrap and the
reading of the points are excluded (and reported apart as `setup_seconds`). The time to an
error is interpolated log-log between the runs around it, as the bench does for livebake.
The error is livebake's RelativeRmsError: sqrt(max(Σ|E−E_ref|² − Σσ², 0) / Σ|E_ref|²), the
reference's own variance σ² removed.
"""

import argparse
import json
import math
import sys
import time

import bpy  # first: bmesh and mathutils are bpy's modules
import bmesh
import numpy as np
from mathutils import Vector
from mathutils.bvhtree import BVHTree


def gltf_to_blender(v):
    """glTF is +Y up, Blender +Z up: the importer maps (x, y, z) to (x, −z, y)."""
    return Vector((v[0], -v[2], v[1]))


def input_value(node, *names):
    for name in names:
        if name in node.inputs:
            return node.inputs[name].default_value
    return None


def lambertian_materials():
    """Every material becomes a Diffuse BSDF of its base colour; emitters emit from the front."""
    for mat in bpy.data.materials:
        if mat.node_tree is None:
            continue
        tree = mat.node_tree
        principled = next((n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"), None)
        if principled is None:
            sys.exit(f"material {mat.name}: no Principled BSDF to read")
        base = list(input_value(principled, "Base Color"))
        emission = list(input_value(principled, "Emission Color", "Emission") or (0, 0, 0, 1))
        strength = input_value(principled, "Emission Strength") or 0.0
        if principled.inputs["Base Color"].is_linked:
            sys.exit(f"material {mat.name}: textured base colour (this script handles factors only)")
        tree.nodes.clear()
        out = tree.nodes.new("ShaderNodeOutputMaterial")
        diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
        diffuse.inputs["Color"].default_value = base
        diffuse.inputs["Roughness"].default_value = 0.0
        if strength > 0 and max(emission[:3]) > 0:
            emit = tree.nodes.new("ShaderNodeEmission")
            emit.inputs["Color"].default_value = emission
            emit.inputs["Strength"].default_value = strength
            front = tree.nodes.new("ShaderNodeAddShader")
            tree.links.new(diffuse.outputs[0], front.inputs[0])
            tree.links.new(emit.outputs[0], front.inputs[1])
            geometry = tree.nodes.new("ShaderNodeNewGeometry")
            mix = tree.nodes.new("ShaderNodeMixShader")
            tree.links.new(geometry.outputs["Backfacing"], mix.inputs["Fac"])
            tree.links.new(front.outputs[0], mix.inputs[1])
            tree.links.new(diffuse.outputs[0], mix.inputs[2])
            tree.links.new(mix.outputs[0], out.inputs["Surface"])
        else:
            tree.links.new(diffuse.outputs[0], out.inputs["Surface"])


def joined_mesh():
    """All meshes joined into one object, welded and triangulated."""
    meshes = [o for o in bpy.data.objects if o.type == "MESH"]
    if not meshes:
        sys.exit("the scene has no mesh")
    bpy.ops.object.select_all(action="DESELECT")
    for o in meshes:
        o.select_set(True)
    bpy.context.view_layer.objects.active = meshes[0]
    if len(meshes) > 1:
        bpy.ops.object.join()
    obj = bpy.context.view_layer.objects.active
    bpy.ops.object.transform_apply(location=True, rotation=True, scale=True)
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bmesh.ops.remove_doubles(bm, verts=bm.verts, dist=1e-6)
    bm.to_mesh(obj.data)
    bm.free()
    bm = bmesh.new()
    bm.from_mesh(obj.data)
    bmesh.ops.triangulate(bm, faces=bm.faces)
    bm.to_mesh(obj.data)
    bm.free()
    return obj


def uv_area_and_area(obj):
    mesh = obj.data
    uv = mesh.uv_layers.active.data
    area3d = sum(p.area for p in mesh.polygons)
    area_uv = 0.0
    for p in mesh.polygons:
        a, b, c = (uv[i].uv for i in p.loop_indices)
        area_uv += abs((b - a).cross(c - a)) / 2
    return area3d, area_uv


def unwrap(obj, margin):
    """Smart UV Project: islands split at 66°, packed into the unit square `margin` apart."""
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    bpy.ops.uv.smart_project(angle_limit=math.radians(66), island_margin=margin, scale_to_bounds=False)
    bpy.ops.object.mode_set(mode="OBJECT")


def point_uvs(obj, points):
    """The light map's UV at each point: the triangle a short ray along −n meets."""
    mesh = obj.data
    verts = [v.co.copy() for v in mesh.vertices]
    tris = [list(p.vertices) for p in mesh.polygons]
    tree = BVHTree.FromPolygons(verts, tris)
    uv = mesh.uv_layers.active.data
    out = []
    for k, pt in enumerate(points):
        p, n = gltf_to_blender(pt["p"]), gltf_to_blender(pt["n"]).normalized()
        hit, _, index, _ = tree.ray_cast(p + n * 1e-3, -n, 2e-3)
        if hit is None:
            sys.exit(f"point {k} {pt['p']}: no surface within 1 mm along its normal")
        poly = mesh.polygons[index]
        a, b, c = (verts[i] for i in poly.vertices)
        # Barycentrics of the hit in its triangle.
        v0, v1, v2 = b - a, c - a, hit - a
        d00, d01, d11 = v0.dot(v0), v0.dot(v1), v1.dot(v1)
        d20, d21 = v2.dot(v0), v2.dot(v1)
        den = d00 * d11 - d01 * d01
        w1 = (d11 * d20 - d01 * d21) / den
        w2 = (d00 * d21 - d01 * d20) / den
        w0 = 1 - w1 - w2
        ua, ub, uc = (uv[i].uv for i in poly.loop_indices)
        out.append(ua * w0 + ub * w1 + uc * w2)
    return out


def bilinear(pixels, res, u, v):
    """Bilinear read at UV (u, v); texel (i, j) is centred at ((i+½)/res, (j+½)/res), row 0 at v = 0."""
    x, y = u * res - 0.5, v * res - 0.5
    x0, y0 = int(math.floor(x)), int(math.floor(y))
    fx, fy = x - x0, y - y0
    acc = np.zeros(3)
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            i, j = min(max(x0 + dx, 0), res - 1), min(max(y0 + dy, 0), res - 1)
            acc += wx * wy * pixels[j, i, :3]
    return acc


def relative_rms(got, reference):
    err = want2 = var = 0.0
    for e, r in zip(got, reference):
        s = r.get("E_stderr", [0.0, 0.0, 0.0])
        err += sum((a - b) ** 2 for a, b in zip(e, r["E"]))
        want2 += sum(b * b for b in r["E"])
        var += sum(x * x for x in s)
    return math.sqrt(max(err - var, 0.0) / want2)


def mean_bias(got, reference):
    lum = lambda c: 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
    ratios = [lum(e) / lum(r["E"]) for e, r in zip(got, reference) if lum(r["E"]) > 0]
    return sum(ratios) / len(ratios) - 1.0


def time_to(curve, target):
    for (t0, e0), (t1, e1) in zip(curve, curve[1:]):
        if e0 >= target >= e1:
            if e0 == e1:
                return t0
            f = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0)))
    return None


def log(what):
    print(f"[cycles_time_to_error] {what}", file=sys.stderr, flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("points")
    ap.add_argument("reference")
    ap.add_argument("--texel-size", type=float, default=0.012)
    ap.add_argument("--targets", default="0.10,0.05")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--max-samples", type=int, default=4096)
    ap.add_argument("--out")
    args = ap.parse_args([a for a in sys.argv[1:]])
    targets = sorted((float(t) for t in args.targets.split(",")), reverse=True)
    points = json.load(open(args.points))["points"]
    reference = json.load(open(args.reference))["points"]
    if len(points) != len(reference):
        sys.exit(f"{len(points)} points against {len(reference)} reference points")

    setup = time.perf_counter()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=args.scene)
    log("imported")
    lambertian_materials()
    obj = joined_mesh()
    # The margin is 2 texels of the image; the image's size follows from the packed area.
    res = 1024
    for _ in range(3):
        unwrap(obj, 2.0 / res)
        area3d, area_uv = uv_area_and_area(obj)
        res = int(math.ceil(math.sqrt(area3d / area_uv) / args.texel_size))
    area3d, area_uv = uv_area_and_area(obj)
    texel = math.sqrt(area3d / (area_uv * res * res))
    log(f"unwrapped: {res}² texels of {texel * 100:.2f} cm")
    uvs = point_uvs(obj, points)

    image = bpy.data.images.new("lightmap", res, res, float_buffer=True, alpha=False)
    for mat in obj.data.materials:
        node = mat.node_tree.nodes.new("ShaderNodeTexImage")
        node.image = image
        mat.node_tree.nodes.active = node
    world = bpy.data.worlds.new("black")
    world.use_nodes = False
    world.color = (0, 0, 0)
    scene = bpy.context.scene
    scene.world = world
    scene.render.engine = "CYCLES"
    scene.render.threads_mode = "FIXED"
    scene.render.threads = args.threads
    cycles = scene.cycles
    cycles.device = "CPU"
    cycles.use_denoising = False
    cycles.sample_clamp_direct = 0.0
    cycles.sample_clamp_indirect = 0.0
    cycles.max_bounces = cycles.diffuse_bounces = 1024
    cycles.use_light_tree = True
    cycles.seed = 1
    scene.render.bake.margin = 16
    bpy.ops.object.select_all(action="DESELECT")
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    setup = time.perf_counter() - setup

    curve = []
    samples = 1
    pixels = np.empty(res * res * 4, dtype=np.float32)
    while True:
        cycles.samples = samples
        t = time.perf_counter()
        bpy.ops.object.bake(type="DIFFUSE", pass_filter={"DIRECT", "INDIRECT"}, margin=16, use_clear=True)
        seconds = time.perf_counter() - t
        image.pixels.foreach_get(pixels)
        grid = pixels.reshape(res, res, 4)
        got = [list(math.pi * bilinear(grid, res, uv.x, uv.y)) for uv in uvs]
        error = relative_rms(got, reference)
        curve.append({"samples": samples, "seconds": seconds, "error": error, "mean_bias": mean_bias(got, reference)})
        log(json.dumps(curve[-1]))
        if error <= targets[-1] or samples >= args.max_samples:
            break
        samples *= 2

    points_curve = [(c["seconds"], c["error"]) for c in curve]
    report = {
        "renderer": f"Blender Cycles {bpy.app.version_string} (bpy), CPU, {args.threads} threads",
        "method": "DIFFUSE bake (direct + indirect, no colour) into a light map at the texel size, "
        "read bilinearly at the points, E = pi x texel",
        "seconds_include": "bpy.ops.object.bake: Cycles scene sync, BVH build, path tracing, image write",
        "seconds_exclude": "glTF import, join and weld, UV unwrap, reading the points",
        "settings": {
            "max_bounces": 1024,
            "diffuse_bounces": 1024,
            "clamp": "none",
            "denoising": False,
            "light_tree": True,
            "bake_margin_px": 16,
            "world": "black",
        },
        "resolution": res,
        "texel_size_m": texel,
        "setup_seconds": setup,
        "curve": curve,
        "time_to_error": [{"error": e, "seconds": time_to(points_curve, e)} for e in targets],
    }
    text = json.dumps(report, indent=1)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")
    else:
        print(text)


if __name__ == "__main__":
    main()
