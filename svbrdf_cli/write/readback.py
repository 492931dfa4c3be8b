"""Any texture set svbrdf wrote, read back as linear maps: what ``svbrdf view``, ``render`` and ``export`` accept.

* A **native set** (``normal/diffuse/roughness/specular.png``, :mod:`svbrdf_cli.write.mapset`) is read as it is.
* A **preset's set** (``gltf``, ``unreal``, ``unity-hdrp``, ``blender``) is read through its
  ``texture_set.json``, which names each file's role: the base colour (sRGB), the normal map (OpenGL,
  or DirectX with green flipped), and roughness and metallic wherever the preset packed them (a
  channel of ORM, metallicRoughness or MaskMap, whose alpha is smoothness = 1 - roughness; or grey
  files of their own). The metallic workflow is turned back into ours by its definition
  (:func:`svbrdf_cli.write.derive.specular_to_metallic`): ``specular = lerp(F0, base, m)`` and
  ``diffuse (1 - max(specular)) = base (1 - F0) (1 - m)``; 8-bit rounding aside, a dielectric or a
  metal comes back as it was written.

Anything else is refused with a message naming what is accepted.
"""

from __future__ import annotations

import os
import re

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.errors import MapSetError
from svbrdf_cli.imageio import read_image
from svbrdf_cli.write import ownership
from svbrdf_cli.write.mapset import read_map_set

#: What the commands that read a set accept, for their messages.
ACCEPTED = ("a native set (normal.png, diffuse.png, roughness.png, specular.png) or a set svbrdf wrote with "
            "--preset gltf, unreal, unity-hdrp or blender (with its texture_set.json)")


def is_native(folder):
    """Whether ``folder`` holds the four native maps."""
    return all(os.path.isfile(os.path.join(folder, f"{k}.png")) for k in cv.MAP_NAMES)


def _channels(role):
    """{channel index: what} from a packed map's role ("R = ambient occlusion, G = roughness, ...")."""
    out = {}
    for part in role.split(","):
        m = re.match(r"\s*([RGBA])\s*=\s*(.+)", part)
        if m:
            out["RGBA".index(m.group(1))] = m.group(2).strip().lower()
    return out


def _preset_maps(folder, meta):
    base = normal = rough = metal = None
    for name, info in (meta.get("files") or {}).items():
        raw = str(info.get("role", "")) if isinstance(info, dict) else ""
        role = raw.lower()
        path = os.path.join(folder, name)
        if not role or role == "height" or not os.path.isfile(path):
            continue
        if role == "base colour":
            base = cv.srgb_to_linear(read_image(path)[..., :3])
        elif role.startswith("normal"):
            n = read_image(path)[..., :3] * 2.0 - 1.0
            if "directx" in role:
                n[..., 1] *= -1.0
            normal = cv.normalize(n)
        elif role.startswith("roughness"):
            rough = read_image(path)[..., :1]
        elif role.startswith("metallic"):
            metal = read_image(path)[..., :1]
        elif "=" in role:
            img = read_image(path)
            for c, what in _channels(raw).items():
                if c < img.shape[-1] and what.startswith("roughness"):
                    rough = img[..., c:c + 1]
                elif c < img.shape[-1] and what.startswith("smoothness"):
                    rough = 1.0 - img[..., c:c + 1]
                elif c < img.shape[-1] and what.startswith("metallic"):
                    metal = img[..., c:c + 1]
    missing = [k for k, v in (("base colour", base), ("normal", normal), ("roughness", rough), ("metallic", metal))
               if v is None]
    if missing:
        raise MapSetError(f"'{folder}': its texture_set.json names no {', '.join(missing)} file; 'svbrdf view', "
                          f"'render' and 'export' read {ACCEPTED}.")
    shapes = {v.shape[:2] for v in (base, normal, rough, metal)}
    if len(shapes) != 1:
        raise MapSetError(f"'{folder}': its maps differ in size; resize them to match.")
    f0 = np.float32(cv.DIELECTRIC_F0)
    m = np.clip(metal, 0.0, 1.0)
    specular = f0 * (1.0 - m) + base * m
    diffuse = base * (1.0 - f0) * (1.0 - m) / np.maximum(1.0 - specular.max(-1, keepdims=True), 1e-3)
    return {"normal": normal.astype(np.float32), "diffuse": np.clip(diffuse, 0, 1).astype(np.float32),
            "roughness": np.clip(rough, 0, 1).astype(np.float32), "specular": np.clip(specular, 0, 1).astype(np.float32)}


def read_any_set(folder):
    """Linear maps (as :func:`svbrdf_cli.write.mapset.read_map_set` returns) of a native set or of a
    preset's set svbrdf wrote (see the module docstring)."""
    folder = os.fspath(folder)
    if is_native(folder):
        return read_map_set(folder)
    meta = ownership.read_json(os.path.join(folder, "texture_set.json"))
    if meta is None or meta.get("preset") in (None, "svbrdf"):
        raise MapSetError(f"'{folder}' is not a texture set svbrdf can read: it takes {ACCEPTED}.")
    return _preset_maps(folder, meta)


def material_name(folder):
    """The material's name for a set: the ``--name`` it was captured with, else its photo's name, else the
    folder's."""
    folder = os.fspath(folder)
    rec = ownership.read_json(os.path.join(folder, "material.json"))
    if rec is not None:
        name = (rec.get("options") or {}).get("name") if isinstance(rec.get("options"), dict) else None
        photo = (rec.get("input") or {}).get("file") if isinstance(rec.get("input"), dict) else None
        if name or photo:
            return name or os.path.splitext(os.path.basename(photo))[0]
    return os.path.basename(os.path.abspath(folder))
