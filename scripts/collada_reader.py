"""A small COLLADA (.dae) reader for scripts/derive_camera_looks.py: triangles of every visual-scene
node in world coordinates, with their material's diffuse texture or colour and texture coordinates.

Handles ``<triangles>`` and ``<polylist>`` (fanned), node ``<matrix>``, ``<translate>``, ``<rotate>``
and ``<scale>``, and the effect -> sampler -> surface -> image chain of COLLADA 1.4. Needs numpy.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np


def floats(text):
    return np.array(text.split(), dtype=np.float64) if text and text.strip() else np.zeros(0)


def read_collada(path):
    """[(node name, material name, texture path or None, diffuse rgba or None, tris (T,3,3), uv (T,3,2) or None)]."""
    root = ET.parse(path).getroot()
    ns = root.tag.split("}")[0] + "}" if root.tag.startswith("{") else ""
    q = lambda tag: ns + tag
    images = {im.get("id"): (im.findtext(".//" + q("init_from")) or "").strip() for im in root.iter(q("image"))}
    effects = {}
    for effect in root.iter(q("effect")):
        params = {p.get("sid"): p for p in effect.iter(q("newparam"))}
        texture, colour = None, None
        diffuse = effect.find(".//" + q("diffuse"))
        if diffuse is not None:
            tex = diffuse.find(q("texture"))
            if tex is not None:
                name = tex.get("texture")
                sampler = params.get(name)
                source = sampler.findtext(".//" + q("source")) if sampler is not None else None
                surface = params.get(source.strip()) if source else None
                image = surface.findtext(".//" + q("init_from")).strip() if surface is not None else name
                texture = images.get(image, image)
            if diffuse.find(q("color")) is not None:
                colour = floats(diffuse.find(q("color")).text).tolist()
        effects[effect.get("id")] = (texture, colour)
    materials = {m.get("id"): effects.get(m.find(q("instance_effect")).get("url")[1:], (None, None))
                 for m in root.iter(q("material"))}
    geometries = {}
    for geometry in root.iter(q("geometry")):
        mesh = geometry.find(q("mesh"))
        if mesh is None:
            continue
        sources = {s.get("id"): floats(s.findtext(q("float_array"))) for s in mesh.findall(q("source"))}
        vertices = {v.get("id"): v.find(q("input")).get("source")[1:] for v in mesh.findall(q("vertices"))}
        parts = []
        for prim in mesh:
            tag = prim.tag[len(ns):]
            if tag not in ("triangles", "polylist") or prim.find(q("p")) is None:
                continue
            inputs = prim.findall(q("input"))
            stride = max(int(i.get("offset")) for i in inputs) + 1
            p = np.array(prim.find(q("p")).text.split(), dtype=np.int64).reshape(-1, stride)
            vin = [i for i in inputs if i.get("semantic") == "VERTEX"][0]
            positions = sources[vertices[vin.get("source")[1:]]].reshape(-1, 3)[p[:, int(vin.get("offset"))]]
            tin = [i for i in inputs if i.get("semantic") == "TEXCOORD"]
            uv = None
            if tin:
                uvs = sources[tin[0].get("source")[1:]]
                uv_stride = 3 if uvs.size % 3 == 0 and uvs.size % 2 != 0 else 2
                uv = uvs.reshape(-1, uv_stride)[p[:, int(tin[0].get("offset"))], :2]
            if tag == "polylist":
                counts = np.array(prim.findtext(q("vcount")).split(), dtype=np.int64)
                fan, start = [], 0
                for n in counts:
                    fan += [i for k in range(1, n - 1) for i in (start, start + k, start + k + 1)]
                    start += n
                positions = positions[fan]
                uv = uv[fan] if uv is not None else None
            parts.append((prim.get("material"), positions.reshape(-1, 3, 3),
                          None if uv is None else uv.reshape(-1, 3, 2)))
        geometries[geometry.get("id")] = parts
    out = []

    def walk(node, matrix):
        for child in node:
            tag = child.tag[len(ns):]
            if tag == "matrix":
                matrix = matrix @ floats(child.text).reshape(4, 4)
            elif tag == "translate":
                step = np.eye(4)
                step[:3, 3] = floats(child.text)
                matrix = matrix @ step
            elif tag == "scale":
                matrix = matrix @ np.diag(list(floats(child.text)) + [1.0])
            elif tag == "rotate":
                x, y, z, angle = floats(child.text)
                c, s, axis = math.cos(math.radians(angle)), math.sin(math.radians(angle)), np.array([x, y, z])
                axis = axis / (np.linalg.norm(axis) or 1.0)
                k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
                step = np.eye(4)
                step[:3, :3] = np.eye(3) * c + s * k + (1 - c) * np.outer(axis, axis)
                matrix = matrix @ step
        for inst in node.findall(q("instance_geometry")):
            bind = {m.get("symbol"): m.get("target")[1:] for m in inst.iter(q("instance_material"))}
            for material, tris, uv in geometries.get(inst.get("url")[1:], []):
                name = bind.get(material, material)
                texture, colour = materials.get(name, (None, None))
                world = tris @ matrix[:3, :3].T + matrix[:3, 3]
                out.append((node.get("name") or "", name or "", texture, colour, world, uv))
        for child in node.findall(q("node")):
            walk(child, matrix)

    for scene in root.iter(q("visual_scene")):
        for node in scene.findall(q("node")):
            walk(node, np.eye(4))
    return out
