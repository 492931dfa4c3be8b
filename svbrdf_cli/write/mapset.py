"""The native map set on disk: ``normal.png diffuse.png roughness.png specular.png``.

Stored in the Des18 encoding (:mod:`svbrdf_cli.conventions`); in memory as a
dict of HWC float32 arrays in linear units: ``normal`` (H, W, 3) unit vectors,
``diffuse`` and ``specular`` (H, W, 3) linear albedo, ``roughness`` (H, W, 1).
"""

from __future__ import annotations

import os

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.conventions import MAP_CHANNELS
from svbrdf_cli.errors import MapSetError
from svbrdf_cli.imageio import read_image, write_images


def stored_to_linear(stored, linear_albedo=False):
    """Dict of stored-encoding HWC maps as read from disk -> linear maps.

    ``linear_albedo``: the files hold diffuse and specular as linear albedo (the Des19
    validation ground truth and the paper's outputs do), not our gamma-2.2 encoding.
    """
    maps = cv.decode_maps({k: v[..., :MAP_CHANNELS[k]] for k, v in stored.items()})
    if linear_albedo:
        for k in ("diffuse", "specular"):
            maps[k] = stored[k][..., :MAP_CHANNELS[k]].clip(0.0, 1.0)
    return maps


def linear_to_stored(maps):
    """Linear maps -> stored-encoding maps in [0, 1], roughness as grey RGB (Des18 files)."""
    out = cv.encode_maps(maps)
    out["roughness"] = np.repeat(out["roughness"][..., :1].clip(0.0, 1.0), 3, axis=-1)
    return out


def read_stored_maps(folder, names=None):
    """Read a map set's four images as stored (encoded), without decoding them.

    Args:
        folder: directory holding the four PNGs (other image extensions
            OpenImageIO reads are accepted: ``.tif``, ``.exr``).
        names: optional {map: file stem} for sets named otherwise (e.g.
            ``paper_normal``); default: the map names.

    Returns:
        dict of stored-encoding HWC float32 maps (grey diffuse/specular as RGB).

    Raises:
        MapSetError: a map is missing, or their sizes differ.
    """
    folder = os.fspath(folder)
    names = names or {n: n for n in cv.MAP_NAMES}
    stored = {}
    for name in cv.MAP_NAMES:
        stem = names[name]
        path = next((os.path.join(folder, stem + ext) for ext in (".png", ".tif", ".tiff", ".exr")
                     if os.path.isfile(os.path.join(folder, stem + ext))), None)
        if path is None:
            raise MapSetError(f"'{folder}' has no {stem}.png; a map set needs "
                              f"{', '.join(names[n] + '.png' for n in cv.MAP_NAMES)}.")
        img = read_image(path)
        if img.shape[-1] == 1 and name != "roughness":
            img = np.repeat(img, 3, axis=-1)
        stored[name] = img
    shapes = {k: v.shape[:2] for k, v in stored.items()}
    if len(set(shapes.values())) != 1:
        raise MapSetError(f"Maps in '{folder}' differ in size: "
                          + ", ".join(f"{k} {w}x{h}" for k, (h, w) in shapes.items()) + ". Resize them to match.")
    return stored


def read_map_set(folder, names=None, linear_albedo=False):
    """Read a native map set (see :func:`read_stored_maps`) as linear HWC float32 maps
    (``linear_albedo``: see :func:`stored_to_linear`)."""
    return stored_to_linear(read_stored_maps(folder, names), linear_albedo=linear_albedo)


def write_map_set(folder, maps, bits=8, images=()):
    """Write linear maps as a native map set (PNG, Des18 encoding); ``images``: more
    :func:`svbrdf_cli.imageio.write_image` jobs encoded alongside."""
    write_stored_set(folder, linear_to_stored(maps), bits, images)


def write_stored_set(folder, stored, bits=8, images=()):
    """Write stored-encoding maps (what a model returns) as a native map set, as they are: clipped to
    [0, 1], roughness as grey RGB. ``images``: more :func:`svbrdf_cli.imageio.write_image` jobs
    (path, pixels, bits, colour), encoded with the maps on the same threads."""
    os.makedirs(folder, exist_ok=True)
    jobs = []
    for name in cv.MAP_NAMES:
        img = stored[name]
        if name == "roughness":
            img = np.repeat(img[..., :1], 3, axis=-1)
        jobs.append((os.path.join(folder, name + ".png"), img, bits, name in ("diffuse", "specular")))
    write_images(list(images) + jobs)  # the caller's first: a preview made while the maps are encoded
