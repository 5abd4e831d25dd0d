"""Derive laplab/sensors/data/camera_looks.json from a deepracer-simapp checkout (its bundle/ folder).

    python scripts/derive_camera_looks.py /path/to/deepracer-simapp/bundle [--commit SHA]

For every route ``routes/<name>.npy`` it reads the route's world (``worlds/<name>.world``: its lights,
the sky or background), the track model it includes (``models/<model>/*.sdf``) and the COLLADA meshes
that model shows (``meshes/...``), and writes numbers only: per surface (road, border lines, centre
line, field, walls) the albedo (mean RGB of the diffuse texture, or the diffuse colour), the grey
standard deviation of the texture over 5 mm squares of ground (``std``) and its grain
(autocorrelation half-width, metres on the ground); the widths of the border and centre lines, the
dash length and gap of the centre line, the walls' height and the room they close, the lights.
Surfaces are recognised by their node, material and texture names (``road``, ``ol``/``il``/outer/inner
line, ``cl``/centre line, ``field``/grass, ``wall``); anything else taller than 0.3 m (grandstands,
buildings) counts as background scenery, summarised as a wall of its median height and mean colour. A
route whose road or lines are not recognised gets no entry (laplab then uses its default look and says
so).

The shipped file was derived from the last Gazebo-classic release (commit b7599b42, "2024 February
Release"): Gazebo classic's grey background and its shading of these lights match the frames in
../shared/real-deepracer/frames (docs/camera.md). Needs numpy and Pillow.
"""

from __future__ import annotations

import argparse
import glob
import json
import math
import os
import re
import sys
import xml.etree.ElementTree as ET

import numpy as np
from PIL import Image

from collada_reader import floats, read_collada  # scripts/collada_reader.py, beside this file

GAZEBO_SUN = {"type": "directional", "diffuse": [0.8, 0.8, 0.8], "direction": [-0.5, 0.1, -0.9]}
GAZEBO_BACKGROUND = [178, 178, 178]  # Gazebo classic's default background colour, 0.7 grey
GAZEBO_SKY = [148, 176, 212]  # <sky/>: SkyX's sky is not in the files; a mid sky blue stands in
STD_TEXEL = 0.005  # m: "std" is the grey standard deviation of the texture averaged over squares this wide
KINDS = ("road", "border", "center", "field", "wall")


def classify(node, material, texture):
    text = f"{node} {material} {os.path.basename(texture or '')}".lower()
    name = node.lower()
    if re.search(r"start|finish|gravel|pit|logo|barrier|side.?edge|red_border", text):
        return None
    if name in ("cl",) or re.search(r"cent(er|re)", text) or "dashed" in text:
        return "center"
    if name in ("ol", "il") or re.search(r"outer.?line|inner.?line|edge_white|border|solidline|outerlines", text):
        return "border"
    if re.search(r"road|track_road|^track\b|asphalt", text) or name in ("road", "track", "road_clean"):
        return "road"
    if re.search(r"field|grass", text):
        return "field"
    if "wall" in text:
        return "wall"
    return "scenery"


def texture_stats(path, colour, block=1):
    """(mean rgb 0..255, grey std of ``block`` x ``block`` texel averages, autocorrelation half-width in
    texels, texture width in texels)."""
    if path and os.path.isfile(path):
        image = np.asarray(Image.open(path).convert("RGB"), dtype=np.float64)
        tint = np.array(colour[:3]) if colour else np.ones(3)
        if colour and np.allclose(colour[:3], 0):  # a black diffuse colour with a texture: the texture rules
            tint = np.ones(3)
        image = image * tint
        grey = image @ np.array([0.299, 0.587, 0.114])
        centred = grey - grey.mean()
        power = np.abs(np.fft.fft2(centred)) ** 2
        corr = np.real(np.fft.ifft2(power))[0]
        corr = corr / corr[0] if corr[0] > 0 else corr
        below = np.nonzero(corr[: corr.size // 2] < 0.5)[0]
        half = float(below[0]) if below.size else 1.0
        h, w = (grey.shape[0] // block) * block, (grey.shape[1] // block) * block
        coarse = grey[:h, :w].reshape(h // block, block, w // block, block).mean(axis=(1, 3))
        return image.reshape(-1, 3).mean(0), float(coarse.std()), half, image.shape[1]
    if colour:
        return np.array(colour[:3]) * 255.0, 0.0, 1.0, 1
    return None


def metres_per_uv(tris, uv):
    """Median ground metres per texture-coordinate unit over the triangles' edges (None without UVs)."""
    if uv is None or len(uv) == 0:
        return None
    d_world = np.linalg.norm(tris[:, 1] - tris[:, 0], axis=1)
    d_uv = np.linalg.norm(uv[:, 1] - uv[:, 0], axis=1)
    ok = (d_uv > 1e-9) & (d_world > 1e-6)
    return float(np.median(d_world[ok] / d_uv[ok])) if ok.any() else None


def strip_width(tris):
    """Median width of a strip of thin quads: 2 * area / the middle edge of each triangle."""
    a, b, c = tris[:, 0, :2], tris[:, 1, :2], tris[:, 2, :2]
    edges = np.sort(np.stack([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1),
                              np.linalg.norm(a - c, axis=1)], 1), axis=1)
    area = 0.5 * np.abs((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    ok = area > 1e-9
    return float(np.median(2 * area[ok] / edges[ok, 1])) if ok.any() else None


def arc_positions(points, line):
    """Arc length along ``line`` (M, 2) of the nearest point of each of ``points`` (P, 2)."""
    a, b = line[:-1], line[1:]
    d = b - a
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(d, axis=1))])
    result = np.empty(len(points))
    for start in range(0, len(points), 2000):
        p = points[start:start + 2000]
        t = np.clip(((p[:, None] - a[None]) * d[None]).sum(-1) / np.maximum((d * d).sum(-1), 1e-12)[None], 0, 1)
        dist = np.linalg.norm(p[:, None] - (a[None] + t[..., None] * d[None]), axis=-1)
        i = dist.argmin(1)
        result[start:start + 2000] = cum[i] + t[np.arange(len(p)), i] * (cum[i + 1] - cum[i])
    return result, cum[-1]


def distance_to(points, line):
    """Distance (m) of each of ``points`` (P, 2) to the polyline ``line`` (M, 2)."""
    a, d = line[:-1], line[1:] - line[:-1]
    result = np.empty(len(points))
    for start in range(0, len(points), 2000):
        p = points[start:start + 2000]
        t = np.clip(((p[:, None] - a[None]) * d[None]).sum(-1) / np.maximum((d * d).sum(-1), 1e-12)[None], 0, 1)
        result[start:start + 2000] = np.linalg.norm(p[:, None] - (a[None] + t[..., None] * d[None]), axis=-1).min(1)
    return result


def on_route(found, route):
    """Keep the road, line and centre parts that lie where the route says they are: the road within
    the route's half width (+5 cm) of the centre line, tape within 15 cm of a border, centre line
    within 10 cm of the centre line (median over a part's vertices); a road may also be one sheet under
    the whole route. City worlds name other meshes "road" or "track"; this drops them."""
    centre, inner, outer = route[:, 0:2], route[:, 2:4], route[:, 4:6]
    half = 0.5 * float(np.median(np.linalg.norm(inner - outer, axis=1)))
    tests = {"road": lambda p: np.median(distance_to(p, centre)) < half + 0.05,
             "border": lambda p: np.median(np.minimum(distance_to(p, inner), distance_to(p, outer))) < 0.15,
             "center": lambda p: np.median(distance_to(p, centre)) < 0.10}
    sheets = [part for part in found["road"] if inside_share(centre[:: max(1, len(centre) // 20)], part[4]) > 0.8]
    for kind, test in tests.items():
        found[kind] = [part for part in found[kind] if test(part[4].reshape(-1, 3)[::7, :2])]
    # Failing those, what lies under the route is the field (the carpet, concrete and wood worlds: the
    # field and the road share one texture, and their road mesh lies elsewhere).
    under = [part for part in found["field"] if inside_share(centre[:: max(1, len(centre) // 20)], part[4]) > 0.8]
    found["road"] = found["road"] or sheets or under


def inside_share(points, tris):
    """Share of ``points`` (P, 2) that lie in one of the triangles ``tris`` (T, 3, 3) seen from above."""
    a, b, c = tris[None, :, 0, :2], tris[None, :, 1, :2], tris[None, :, 2, :2]
    p = points[:, None, :]

    def cross(u, v, w):
        return (v[..., 0] - u[..., 0]) * (w[..., 1] - u[..., 1]) - (v[..., 1] - u[..., 1]) * (w[..., 0] - u[..., 0])
    d1, d2, d3 = cross(a, b, p), cross(b, c, p), cross(c, a, p)
    inside = ~(((d1 < 0) | (d2 < 0) | (d3 < 0)) & ((d1 > 0) | (d2 > 0) | (d3 > 0)))
    return float(inside.any(axis=1).mean())


def dash_pattern(tris, centre):
    """(dash length, gap, offset) of a centre line made of separate quads, or (None, None, None) for a
    solid strip. The offset is where along the route's centre line (m from its row 0) a dash starts,
    from a least-squares fit of the dashes' starts to offset + k * period (the fit's residuals stay
    within ~3 cm: the mesh's dashes follow their own curve)."""
    keys = np.round(tris.reshape(-1, 3)[:, :2], 4)
    _, vertex_id = np.unique(keys, axis=0, return_inverse=True)
    vertex_id = vertex_id.reshape(-1, 3)
    parent = np.arange(vertex_id.max() + 1)

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for v0, v1, v2 in vertex_id:
        for other in (v1, v2):
            ra, rb = find(v0), find(other)
            if ra != rb:
                parent[rb] = ra
    component = np.array([find(v) for v in vertex_id[:, 0]])
    labels = np.unique(component)
    if len(labels) < 8:
        return None, None, None
    starts, ends = [], []
    for label in labels:
        pts = tris[component == label].reshape(-1, 3)[:, :2]
        s, total = arc_positions(pts, centre)
        if s.max() - s.min() > 0.5 * total:  # wraps over the start line
            s = np.where(s < 0.5 * total, s + total, s)
        starts.append(s.min())
        ends.append(s.max())
    order = np.argsort(starts)
    starts, ends = np.array(starts)[order], np.array(ends)[order]
    length = float(np.median(ends - starts))
    gap = float(np.median(starts[1:] - ends[:-1]))
    period, offset = np.polyfit(np.arange(len(starts)), starts, 1)
    return length, max(gap, 0.0), float(offset % period)


def world_lights(world_path, bundle):
    text = open(world_path, encoding="utf-8").read()
    root = ET.fromstring(text)
    lights = []
    for include in root.iter("include"):
        if (include.findtext("uri") or "").strip() == "model://sun":
            lights.append(dict(GAZEBO_SUN))
    for light in root.iter("light"):
        pose = floats(light.findtext("pose") or "0 0 0 0 0 0")
        pose = np.concatenate([pose, np.zeros(6 - pose.size)])
        direction = floats(light.findtext("direction") or "0 0 -1")
        roll, pitch, yaw = pose[3:6]
        cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                                  math.cos(yaw), math.sin(yaw))
        rot = np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], [-sp, cp * sr, cp * cr]])
        # Gazebo reads colours as ignition::math::Color, whose Clamp() takes a component above 1 as a
        # 0..255 value (the city worlds' "64 64 64" is 0.25) and one below 0 as 0.
        diffuse = floats(light.findtext("diffuse") or "1 1 1")[:3]
        diffuse = np.round(np.clip(np.where(diffuse > 1.0, diffuse / 255.0, diffuse), 0.0, 1.0), 4)
        entry = {"type": light.get("type"), "diffuse": diffuse.tolist()}
        if light.get("type") == "directional":
            entry["direction"] = (rot @ direction).round(4).tolist()
        else:
            att = light.find("attenuation")
            entry["position"] = pose[:3].tolist()
            entry["attenuation"] = [float(att.findtext(k) or d) if att is not None else d
                                    for k, d in (("constant", 1.0), ("linear", 0.0), ("quadratic", 0.0))]
            if light.get("type") == "spot":
                entry["direction"] = (rot @ direction).round(4).tolist()
        lights.append(entry)
    scene = root.find(".//scene")
    background = GAZEBO_BACKGROUND
    if scene is not None and scene.find("sky") is not None:
        background = GAZEBO_SKY
    elif scene is not None and scene.findtext("background"):
        background = [int(round(255 * v)) for v in floats(scene.findtext("background"))[:3]]
    return lights, background


def route_meshes(bundle, world_path):
    meshes = []
    for model in re.findall(r"model://models/([^<\s]+)", open(world_path, encoding="utf-8").read()):
        for sdf in sorted(glob.glob(os.path.join(bundle, "models", model, "*.sdf"))):
            for visual in ET.parse(sdf).getroot().iter("visual"):
                uri = visual.findtext(".//uri")
                if uri and uri.strip().endswith(".dae"):
                    meshes.append(os.path.join(bundle, uri.strip().replace("model://", "")))
    return meshes


def surface(parts, kind):
    """Albedo, std and grain (m) of the largest-area part of ``kind``."""
    best = max(parts, key=lambda p: p[4].shape[0])
    per_uv = metres_per_uv(best[4], best[5])
    width = Image.open(best[2]).size[0] if best[2] and os.path.isfile(best[2]) else 1
    block = max(1, int(round(STD_TEXEL * width / per_uv))) if per_uv else 1
    stats = texture_stats(best[2], best[3], block)
    if stats is None:
        return None
    mean, std, half, width = stats
    grain = half * per_uv / width if per_uv else 0.0
    return {"rgb": [int(round(v)) for v in np.clip(mean, 0, 255)], "std": round(std, 1), "grain": round(grain, 4)}


def derive_route(bundle, name):
    world = os.path.join(bundle, "worlds", f"{name}.world")
    if not os.path.isfile(world):
        return None, "no world file"
    route = np.load(os.path.join(bundle, "routes", f"{name}.npy"))
    centre = route[:, 0:2]
    found = {kind: [] for kind in KINDS + ("scenery",)}
    for mesh in route_meshes(bundle, world):
        if not os.path.isfile(mesh) or "collision" in os.path.basename(mesh).lower():
            continue
        for node, material, texture, colour, tris, uv in read_collada(mesh):
            kind = classify(node, material, texture)
            tex_path = os.path.normpath(os.path.join(os.path.dirname(mesh), texture)) if texture else None
            if kind is not None:
                found[kind].append((node, material, tex_path, colour, tris, uv))
    on_route(found, route)
    if not (found["road"] and found["border"] and found["center"]):
        return None, "road, border or centre line not recognised in the meshes"
    look = {kind: surface(found[kind], kind) for kind in ("road", "border", "center", "field")
            if found[kind]}
    look["border_width"] = round(float(np.median([strip_width(p[4]) for p in found["border"]])), 4)
    centre_tris = np.concatenate([p[4] for p in found["center"]])
    look["center_width"] = round(strip_width(centre_tris), 4)
    dash, gap, offset = dash_pattern(centre_tris, centre)
    if not (0.005 < look["border_width"] < 0.3 and 0.005 < look["center_width"] < 0.3):
        return None, f"implausible line widths {look['border_width']} / {look['center_width']} m"
    look["dash_length"], look["dash_gap"] = (round(dash, 4), round(gap, 4)) if dash else (None, 0.0)
    look["dash_offset"] = round(offset, 4) if dash else 0.0
    walls = found["wall"] or [p for p in found["scenery"] if p[4][..., 2].max() > 0.3]
    if walls:
        points = np.concatenate([p[4].reshape(-1, 3) for p in walls])
        heights = [float(p[4][..., 2].max()) for p in walls]
        wall = surface(walls, "wall") or {"rgb": [128, 128, 128], "std": 0.0, "grain": 0.0}
        wall["height"] = round(float(np.median(heights)), 3)
        lo, hi = points[:, :2].min(0), points[:, :2].max(0)
        everything = route.reshape(-1, 2)
        if found["wall"] and (lo < everything.min(0)).all() and (hi > everything.max(0)).all():
            wall["room"] = [round(float(v), 3) for v in (*lo, *hi)]
        wall["scenery"] = not found["wall"] or wall["height"] > 3.0  # buildings named "wall"
        look["wall"] = wall
    look["lights"], look["background"] = world_lights(world, bundle)
    return look, None


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bundle", help="deepracer-simapp's bundle/ folder")
    parser.add_argument("--commit", default="b7599b42", help="the simapp commit the bundle was taken from")
    parser.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "..", "laplab", "sensors", "data",
                                                      "camera_looks.json"))
    parser.add_argument("--merge", nargs="+", metavar="ROUTE",
                        help="derive only these routes and add them to --out, each marked with --commit "
                             "(routes newer than the file's main commit)")
    args = parser.parse_args(argv)
    routes, skipped = {}, {}
    paths = sorted(glob.glob(os.path.join(args.bundle, "routes", "*.npy")))
    if args.merge:
        paths = [os.path.join(args.bundle, "routes", f"{name}.npy") for name in args.merge]
    for path in paths:
        name = os.path.basename(path)[:-4]
        try:
            look, why = derive_route(args.bundle, name)
        except Exception as exc:  # a mesh this reader does not understand
            look, why = None, f"{type(exc).__name__}: {exc}"[:120]
        if look is None:
            skipped[name] = why
        else:
            routes[name] = look
            if args.merge:
                look["simapp_commit"] = args.commit
        print(f"{name}: {'ok' if look else why}", file=sys.stderr)
    if args.merge:
        with open(args.out, encoding="utf-8") as handle:
            payload = json.load(handle)
        payload["routes"].update(routes)
        payload["skipped"].update(skipped)
        routes = payload["routes"]
    else:
        payload = {"source": f"aws-deepracer-community/deepracer-simapp@{args.commit} bundle/ (worlds, models, "
                             "meshes); derived by scripts/derive_camera_looks.py",
                   "skipped": skipped, "routes": routes}
    with open(args.out, "w", encoding="utf-8") as handle:
        json.dump(payload, handle, separators=(",", ":"), sort_keys=True)
        handle.write("\n")
    print(f"{len(routes)} routes -> {args.out}; {len(skipped)} skipped", file=sys.stderr)


if __name__ == "__main__":
    main()
