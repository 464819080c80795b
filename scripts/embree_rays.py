#!/usr/bin/env python3
"""Embree's incoherent rays per second on one core, for a glTF scene: what the benches'
fixed Embree anchor (2.3 M rays/s a core, src/cli/bench/mod.rs) stands for, measured on the
machine at hand.

    PYTHON scripts/embree_rays.py SCENE.gltf [--rays 2000000] [--repeats 5]

PYTHON needs numpy, trimesh and embreex (`pip install embreex trimesh`: Embree 4 through
embreex's Cython loop of rtcIntersect1, one thread). The rays start at random points of the
scene's surfaces (area-weighted, 10⁻⁴ m off the surface) in random directions of the
hemisphere the face's normal points into: the incoherent rays of a path tracer's bounces.
Prints the best of the repeats.
"""

import argparse
import time

import numpy as np
import trimesh
from embreex import rtcore_scene as rtcs
from embreex.mesh_construction import TriangleMesh


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--rays", type=int, default=2_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    mesh = trimesh.load(args.scene, force="scene").to_geometry()
    tris = np.asarray(mesh.vertices, dtype=np.float32)[np.asarray(mesh.faces)]
    scene = rtcs.EmbreeScene()
    TriangleMesh(scene, tris)
    points, faces = trimesh.sample.sample_surface(mesh, args.rays, seed=1)
    normals = mesh.face_normals[faces]
    d = np.random.default_rng(1).normal(size=(args.rays, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    d = np.where((d * normals).sum(1)[:, None] < 0, -d, d)
    origins = (points + normals * 1e-4).astype(np.float32)
    d = d.astype(np.float32)
    best = 0.0
    for _ in range(args.repeats):
        t = time.perf_counter()
        hits = scene.run(origins, d)
        best = max(best, args.rays / (time.perf_counter() - t))
    print(f"{args.scene}: {len(tris)} triangles, {best / 1e6:.2f} M rays/s on one core (hit {np.mean(hits >= 0):.3f})")


if __name__ == "__main__":
    main()
