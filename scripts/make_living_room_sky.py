"""The living room under a sun and a sky, for the environment-map cross-check against Mitsuba.

Writes into OUT (default /tmp/lr): living_room_sun.glb (the bundled living room with a
KHR_lights_punctual directional sun, elevation 35 deg, azimuth 160 deg from -Z toward +X,
5 W/m^2, shining in through the window), sky.exr (a 256x128 sky brighter toward the sun and
the zenith, ground 0.15 below the horizon), sunny.exr (the same with a 0.53 deg sun disc of
the same irradiance drawn in) and points.json (interior points: floor, back wall, ceiling).
Run with the Mitsuba tool's Python (it has numpy, pygltflib and mitsuba).
"""
import json, math, os, sys
import numpy as np
import pygltflib
import mitsuba as mi

mi.set_variant("scalar_rgb")
out = sys.argv[1] if len(sys.argv) > 1 else "/tmp/lr"
os.makedirs(out, exist_ok=True)
root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "assets", "living_room", "living_room.glb")
ELEV, AZIM, SUN_E = 35.0, 160.0, 5.0
e, a = math.radians(ELEV), math.radians(AZIM)
toward = np.array([math.cos(e) * math.sin(a), math.sin(e), -math.cos(e) * math.cos(a)])

g = pygltflib.GLTF2().load(root)
# A node whose local -Z is the light's travel direction (-toward).
travel = -toward
z = -travel  # the node's +Z axis
x = np.cross([0.0, 1.0, 0.0], z); x /= np.linalg.norm(x)
y = np.cross(z, x)
m = np.array([x, y, z]).T
w = math.sqrt(max(0.0, 1.0 + m[0, 0] + m[1, 1] + m[2, 2])) / 2.0
q = [(m[2, 1] - m[1, 2]) / (4 * w), (m[0, 2] - m[2, 0]) / (4 * w), (m[1, 0] - m[0, 1]) / (4 * w), w]
g.extensionsUsed = list(set((g.extensionsUsed or []) + ["KHR_lights_punctual"]))
g.extensions = dict(g.extensions or {})
g.extensions["KHR_lights_punctual"] = {"lights": [{"type": "directional", "intensity": SUN_E, "color": [1.0, 0.95, 0.85], "name": "sun"}]}
g.nodes.append(pygltflib.Node(name="sun", rotation=q, extensions={"KHR_lights_punctual": {"light": 0}}))
g.scenes[g.scene or 0].nodes.append(len(g.nodes) - 1)
g.save(os.path.join(out, "living_room_sun.glb"))

W, H = 256, 128
img = np.zeros((H, W, 3), np.float32)
for j in range(H):
    th = math.pi * (j + 0.5) / H
    for i in range(W):
        phi = 2 * math.pi * ((i + 0.5) / W - 0.5)
        d = np.array([math.sin(th) * math.sin(phi), math.cos(th), -math.sin(th) * math.cos(phi)])
        if d[1] > 0:
            glow = 1.0 + 2.0 * max(0.0, float(d @ toward)) ** 8
            img[j, i] = np.array([0.35, 0.5, 0.9]) * (0.6 + 0.4 * d[1]) * glow
        else:
            img[j, i] = [0.15, 0.14, 0.1]
mi.Bitmap(img).write(os.path.join(out, "sky.exr"))
# The sunny map: a disc of 0.265 deg radius whose radiance gives SUN_E (colour as the light's).
big = 8
Wb, Hb = W * big, H * big
sunny = np.repeat(np.repeat(img, big, 0), big, 1)
r = math.radians(0.265)
disc = 2 * math.pi * (1 - math.cos(r))
L = SUN_E / disc * np.array([1.0, 0.95, 0.85])
js = np.arange(Hb); iis = np.arange(Wb)
th = math.pi * (js + 0.5) / Hb; phi = 2 * math.pi * ((iis + 0.5) / Wb - 0.5)
T, P = np.meshgrid(th, phi, indexing="ij")
D = np.stack([np.sin(T) * np.sin(P), np.cos(T), -np.sin(T) * np.cos(P)], -1)
inside = (D @ toward) >= math.cos(r)
sunny[inside] += L
mi.Bitmap(sunny.astype(np.float32)).write(os.path.join(out, "sunny.exr"))

pts = []
for xx in np.arange(-3.5, 3.51, 1.0):
    for zz in np.arange(-1.5, 1.51, 0.75):
        pts.append({"p": [float(xx), 1.0, float(zz)], "n": [0, 1, 0]})
for xx in np.arange(-3.0, 3.01, 1.5):
    for yy in [1.5, 2.25, 3.0]:
        pts.append({"p": [float(xx), float(yy), -2.0], "n": [0, 0, 1]})
for xx in [-3.0, -1.5, 0.0, 1.5, 3.0]:
    pts.append({"p": [float(xx), 3.5, 0.0], "n": [0, -1, 0]})
json.dump({"points": pts}, open(os.path.join(out, "points.json"), "w"))
print(len(pts), "points; sun toward", toward)
