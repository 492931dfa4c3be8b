"""The glTF 2.0 document of the ``gltf`` preset: one textured quad, its buffer embedded."""

from __future__ import annotations

import base64

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.version import __version__

# --------------------------------------------------------------------------
# glTF document
# --------------------------------------------------------------------------

_FLOAT, _USHORT = 5126, 5123
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


def gltf_quad():
    """The quad's vertex data: a 2 x 2 square in the XY plane facing +Z.

    glTF's UV (0, 0) is the image's top-left corner, so the top edge (y = +1)
    gets v = 0 and the image appears upright; row 0 is +Y as in our maps. The
    tangent (+X, w = +1) makes the bitangent cross(N, T) = +Y, matching the
    OpenGL normal map.

    Returns:
        dict of float32 ``POSITION`` (4, 3), ``NORMAL`` (4, 3), ``TANGENT``
        (4, 4), ``TEXCOORD_0`` (4, 2) and uint16 ``indices`` (6,)
        (counter-clockwise seen from +Z).
    """
    s = cv.SURFACE_HALF_SIZE
    pos = np.array([[-s, -s, 0], [s, -s, 0], [s, s, 0], [-s, s, 0]], np.float32)
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)
    return {"POSITION": pos,
            "NORMAL": np.tile(np.array([0, 0, 1], np.float32), (4, 1)),
            "TANGENT": np.tile(np.array([1, 0, 0, 1], np.float32), (4, 1)),
            "TEXCOORD_0": uv,
            "indices": np.array([0, 1, 2, 0, 2, 3], np.uint16)}


def gltf_document(base_colour, metallic_roughness, normal, name="material", extras=None):
    """A glTF 2.0 JSON document: one textured quad, buffer embedded as base64.

    Args:
        base_colour: the base colour image's URI (a relative path).
        metallic_roughness: the metallic-roughness image's URI.
        normal: the normal map's URI.
        name: node, mesh and material name.
        extras: JSON-able dict stored as the material's ``extras``.

    Returns:
        The document as a dict (``json.dump`` it to a ``.gltf`` file).
    """
    quad = gltf_quad()
    blob, views, accessors, attributes = b"", [], [], {}
    for key in ("POSITION", "NORMAL", "TANGENT", "TEXCOORD_0", "indices"):
        a = quad[key]
        data = a.astype("<u2" if key == "indices" else "<f4").tobytes()  # glTF is little-endian
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data),
                      "target": _ELEMENT_ARRAY_BUFFER if key == "indices" else _ARRAY_BUFFER})
        acc = {"bufferView": len(views) - 1, "componentType": _USHORT if key == "indices" else _FLOAT,
               "count": int(a.shape[0]),
               "type": "SCALAR" if a.ndim == 1 else ("VEC2", "VEC3", "VEC4")[a.shape[1] - 2]}
        if key == "POSITION":
            acc["min"] = [float(v) for v in a.min(0)]
            acc["max"] = [float(v) for v in a.max(0)]
        accessors.append(acc)
        if key != "indices":
            attributes[key] = len(accessors) - 1
        blob += data + b"\0" * (-len(data) % 4)  # keep every view 4-byte aligned
    uri = "data:application/octet-stream;base64," + base64.b64encode(blob).decode("ascii")
    material = {"name": name,
                "pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                         "metallicRoughnessTexture": {"index": 1},
                                         "metallicFactor": 1.0, "roughnessFactor": 1.0},
                "normalTexture": {"index": 2},
                "occlusionTexture": {"index": 1},  # R of the metallicRoughness image
                "doubleSided": True}
    if extras:
        material["extras"] = extras
    return {
        "asset": {"version": "2.0", "generator": f"svbrdf {__version__}"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": name}],
        "meshes": [{"name": name, "primitives": [{"attributes": attributes, "indices": len(accessors) - 1,
                                                   "material": 0, "mode": 4}]}],
        "materials": [material],
        "textures": [{"sampler": 0, "source": i} for i in range(3)],
        "images": [{"uri": u} for u in (base_colour, metallic_roughness, normal)],
        "samplers": [{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}],
        "buffers": [{"byteLength": len(blob), "uri": uri}],
        "bufferViews": views,
        "accessors": accessors,
    }
