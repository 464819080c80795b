#!/usr/bin/env python3
"""Surface points seen from an eye, for the runtime benches' references: rays in N uniform
directions from EYE, the first hit within RADIUS metres whose front faces the eye (the side a
viewer standing there sees), at most COUNT of them, written in probe's points format with the
eye recorded. Feed the file to the Mitsuba tool (../shared/tools/mitsuba_ref) for the
reference irradiance. Needs the Mitsuba tool's Python environment (mitsuba, numpy).

Usage: scripts/make_view_points.py SCENE.gltf EX,EY,EZ COUNT RADIUS OUT.json [--seed S]
       (MITSUBA_REF: the directory of mitsuba_irradiance.py, for its glTF reader)"""
import argparse, json, os, sys

import numpy as np
import mitsuba as mi

def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene"); ap.add_argument("eye"); ap.add_argument("count", type=int)
    ap.add_argument("radius", type=float); ap.add_argument("out"); ap.add_argument("--seed", type=int, default=7)
    a = ap.parse_args()
    sys.path.insert(0, os.environ.get("MITSUBA_REF", "../shared/tools/mitsuba_ref"))
    mi.set_variant("llvm_ad_rgb")
    from mitsuba_irradiance import load_gltf
    _, groups, _, _ = load_gltf(a.scene)
    V = np.concatenate([v[f].reshape(-1, 3) for parts in groups.values() for v, f, _ in parts]).astype(np.float32)
    F = np.arange(len(V), dtype=np.uint32).reshape(-1, 3)
    mesh = mi.Mesh("scene", len(V), len(F))
    p = mi.traverse(mesh); p["vertex_positions"] = V.ravel(); p["faces"] = F.ravel(); p.update()
    scene = mi.load_dict({"type": "scene", "m": mesh})
    eye = np.array([float(v) for v in a.eye.split(",")], dtype=np.float32)
    d = np.random.default_rng(a.seed).normal(size=(20 * a.count + 1000, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1)[:, None]
    o = np.repeat(eye[None], len(d), 0)
    si = scene.ray_intersect(mi.Ray3f(mi.Point3f(*o.T), mi.Vector3f(*d.T)))
    t = np.array(si.t); n = np.stack([np.array(c) for c in (si.n.x, si.n.y, si.n.z)], 1)
    hit = np.stack([np.array(c) for c in (si.p.x, si.p.y, si.p.z)], 1)
    ok = np.isfinite(t) & (t <= a.radius) & ((n * d).sum(1) < -0.05)
    pts = [{"p": hit[i].tolist(), "n": n[i].tolist()} for i in np.nonzero(ok)[0][: a.count]]
    json.dump({"eye": eye.tolist(), "radius": a.radius, "points": pts}, open(a.out, "w"), indent=0)
    print(f"{len(pts)} points ({ok.mean():.2f} of the rays hit a front face within {a.radius} m)")

main()
