"""CC0 material seeds (ambientCG, metalness workflow) -> our linear map set.

Read from ``../shared/data/materials/ambientcg/<ID>/`` at training time, never
shipped. Conversions:

* metalness -> diffuse/specular (KHR_materials_pbrSpecularGlossiness forward
  model, in linear colour): ``diffuse = colour * (1 - m)``,
  ``specular = lerp(0.04, colour, m)``.
* missing normal map -> normals from the displacement map's gradient.
* a normal map's +Y convention (OpenGL or DirectX) is decided from the sign
  of its correlation with the displacement-derived normals.
"""

from __future__ import annotations

import os

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageio import read_image

#: Default displacement depth, in surface units per full [0, 1] swing of the
#: map, for a 2-unit-wide surface (see :func:`normals_from_height`).
DEFAULT_DEPTH = 0.04


def metalness_to_specular(colour, metalness):
    """Metalness workflow -> (diffuse, specular) linear albedos.

    Args:
        colour: (..., 3) linear base colour in [0, 1].
        metalness: (..., 1) metalness in [0, 1].

    Returns:
        (diffuse, specular), each (..., 3) linear.
    """
    diffuse = colour * (1.0 - metalness)
    specular = cv.DIELECTRIC_F0 + (colour - cv.DIELECTRIC_F0) * metalness
    return diffuse, specular


def normals_from_height(height, depth=DEFAULT_DEPTH, span=2.0 * cv.SURFACE_HALF_SIZE):
    """Unit normals (+Y up) from a tileable height map.

    Args:
        height: (H, W) or (H, W, 1) heights in [0, 1].
        depth: surface-unit height of a full [0, 1] swing.
        span: surface width the map covers, in surface units.

    Returns:
        (H, W, 3) float32 unit normals.
    """
    h = np.asarray(height, dtype=np.float64).reshape(height.shape[0], height.shape[1]) * depth
    px = span / h.shape[1]
    dx = (np.roll(h, -1, 1) - np.roll(h, 1, 1)) / (2 * px)
    # Row index grows downward, world +Y is up: dh/dy = -dh/drow.
    dy = -(np.roll(h, -1, 0) - np.roll(h, 1, 0)) / (2 * px)
    n = np.stack([-dx, -dy, np.ones_like(h)], -1)
    return cv.normalize(n).astype(np.float32)


#: ambientCG's normal.jpg files, measured with :func:`normal_map_y_sign` on
#: every seed whose displacement has relief, are all DirectX (Y down): used
#: where the displacement is flat and the sign cannot be measured.
AMBIENTCG_Y_SIGN = -1


def normal_map_y_sign(normals, height, min_corr=0.1):
    """+1 if a decoded normal map is +Y up (OpenGL), -1 if Y down (DirectX), 0 if unknown.

    Correlates its y component with that of the normals derived from the
    displacement map (any depth: only the sign matters). Returns 0 when the
    correlation is weaker than ``min_corr`` (flat displacement, unrelated maps).
    """
    ref = normals_from_height(height, depth=1.0)[..., 1].ravel()
    ny = normals[..., 1].ravel()
    if ref.std() < 1e-6 or ny.std() < 1e-6:
        return 0
    c = np.corrcoef(ny, ref)[0, 1]
    return 0 if not abs(c) >= min_corr else (1 if c > 0 else -1)


def _oriented_normals(nmap, height, default_sign, vendor):
    """Decode a normal map and make it +Y up: the convention measured against
    ``height`` when it can be, else the vendor's ``default_sign``."""
    normal = cv.decode_normals(nmap)
    sign = normal_map_y_sign(normal, height) if height is not None else 0
    source = "map" if sign else f"map, assumed {vendor} convention"
    if (sign or default_sign) < 0:
        normal = normal * np.array([1.0, -1.0, 1.0], dtype=np.float32)
        source += " (flipped y)"
    return normal, source


def _resize(img, size):
    import cv2

    if img.shape[0] == size and img.shape[1] == size:
        return img
    out = cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)
    return out[..., None] if out.ndim == 2 else out


def load_ambientcg(folder, size=None, depth=DEFAULT_DEPTH):
    """Load one ambientCG material as linear maps.

    Args:
        folder: ``.../ambientcg/<ID>`` holding ``color.jpg`` (sRGB),
            ``roughness.jpg``, optional ``metalness.jpg``, ``normal.jpg``,
            ``displacement.jpg``.
        size: resize to size x size (area filter) when given.
        depth: displacement depth when normals come from displacement.

    Returns:
        dict of HWC float32 linear maps (keys of ``MAP_NAMES``) plus
        ``"normal_source"`` ("map", "map-flipped-y" or "displacement").

    Raises:
        FileNotFoundError: colour or roughness is missing (7 of the 25 seeds
            lack colour; they cannot be used as full materials).
    """
    def get(name, grey=False):
        p = os.path.join(folder, name + ".jpg")
        if not os.path.isfile(p):
            return None
        img = read_image(p)
        img = img[..., :1] if grey else img[..., :3]
        return _resize(img, size) if size else img

    colour = get("color")
    if colour is not None and colour.shape[-1] == 1:  # greyscale JPEG
        colour = np.repeat(colour, 3, -1)
    rough = get("roughness", grey=True)
    if colour is None or rough is None:
        raise FileNotFoundError(f"{folder}: needs color.jpg and roughness.jpg")
    metal = get("metalness", grey=True)
    metal = np.zeros_like(rough) if metal is None else metal
    diffuse, specular = metalness_to_specular(cv.srgb_to_linear(colour), metal)
    disp = get("displacement", grey=True)
    nmap = get("normal")
    if nmap is not None:
        normal, source = _oriented_normals(nmap, disp, AMBIENTCG_Y_SIGN, "ambientCG")
    elif disp is not None:
        normal = normals_from_height(disp, depth=depth)
        source = "displacement"
    else:
        normal = np.broadcast_to(np.array(cv.FLAT_NORMAL, np.float32), colour.shape).copy()
        source = "flat"
    return {"normal": normal.astype(np.float32), "diffuse": diffuse.astype(np.float32),
            "roughness": rough.astype(np.float32), "specular": specular.astype(np.float32),
            "normal_source": source}


#: The +Y convention assumed for PlayCanvas normal maps without a height map:
#: the one with a height map (seaside-rocks01) measures as DirectX (Y down).
PLAYCANVAS_Y_SIGN = -1


def load_playcanvas(folder, size=None, depth=DEFAULT_DEPTH):
    """Load one PlayCanvas material (``<name>-color``, ``-normal``, ``-roughness``,
    optional ``-height``; .png or .jpg; dielectric) as linear maps, like
    :func:`load_ambientcg`."""
    name = os.path.basename(os.path.normpath(folder))

    def get(kind, grey=False):
        for ext in (".png", ".jpg"):
            p = os.path.join(folder, f"{name}-{kind}{ext}")
            if os.path.isfile(p):
                img = read_image(p)
                img = img[..., :1] if grey else img[..., :3]
                return _resize(img, size) if size else img
        return None

    colour, rough, nmap, height = get("color"), get("roughness", True), get("normal"), get("height", True)
    if colour is None or rough is None or nmap is None:
        raise FileNotFoundError(f"{folder}: needs {name}-color, -roughness and -normal")
    normal, source = _oriented_normals(nmap, height, PLAYCANVAS_Y_SIGN, "PlayCanvas")
    diffuse, specular = metalness_to_specular(cv.srgb_to_linear(colour), np.zeros_like(rough))
    return {"normal": normal.astype(np.float32), "diffuse": diffuse.astype(np.float32),
            "roughness": rough.astype(np.float32), "specular": specular.astype(np.float32),
            "normal_source": source}


def seed_folders(root):
    """(loader, folder) for every seed material under ``<root>/materials``
    (ambientCG and PlayCanvas), sorted; empty when the folder is absent."""
    out = []
    for sub, loader in (("ambientcg", load_ambientcg), ("playcanvas", load_playcanvas)):
        base = os.path.join(root, "materials", sub)
        if os.path.isdir(base):
            out += [(loader, os.path.join(base, d)) for d in sorted(os.listdir(base))
                    if os.path.isdir(os.path.join(base, d))]
    return out


def load_seeds(root, size=512):
    """Every usable seed material under ``<root>/materials`` at ``size``².

    Returns:
        (names, maps): names of the loaded folders and a dict of
        (N, C, size, size) float32 numpy arrays in NCHW (materials without
        colour or roughness are skipped).
    """
    names, stacks = [], {k: [] for k in cv.MAP_NAMES}
    for loader, folder in seed_folders(root):
        try:
            m = loader(folder, size=size)
        except FileNotFoundError:
            continue
        names.append(os.path.basename(folder))
        for k in cv.MAP_NAMES:
            stacks[k].append(np.moveaxis(m[k], -1, 0))
    if not names:
        return [], {}
    return names, {k: np.stack(v) for k, v in stacks.items()}


def _manifest_signs(base):
    """Material name -> +1 (OpenGL) / -1 (DirectX) from ``cc0_more/MANIFEST.md``'s per-material table
    (the measured convention where it gives one, else the stated one); absent names: unknown."""
    signs = {}
    path = os.path.join(base, "MANIFEST.md")
    if not os.path.isfile(path):
        return signs
    with open(path, encoding="utf-8") as f:
        for line in f:
            cells = [c.strip() for c in line.split("|")]
            if len(cells) < 8 or "/" not in cells[1] or not cells[1].startswith("`"):
                continue
            name = cells[1].strip("`").split("/")[-1]
            text = cells[6] or cells[5]
            if "OpenGL" in text:
                signs[name] = 1
            elif "DirectX" in text:
                signs[name] = -1
    return signs


def load_cc0_more(folder, size=None, depth=DEFAULT_DEPTH, default_sign=-1):
    """Load one ``materials/cc0_more/<source>/<Material>/`` set (``color``, ``roughness``, optional
    ``normal``, ``height``, ``metalness``; .jpg or .png) as linear maps, like :func:`load_ambientcg`.

    The normal map's +Y convention is measured against the height map where there is one, else
    ``default_sign`` (the manifest's); sets without a normal map get normals from their height.
    """
    def get(name, grey=False):
        for ext in (".jpg", ".png"):
            p = os.path.join(folder, name + ext)
            if os.path.isfile(p):
                img = read_image(p)
                if img.shape[0] != img.shape[1]:  # 1024x512 sets: the square of the shorter side
                    s = min(img.shape[:2])
                    img = img[:s, :s]
                img = img[..., :1] if grey else img[..., :3]
                if not grey and img.shape[-1] == 1:
                    img = np.repeat(img, 3, -1)
                return _resize(img, size) if size else img
        return None

    colour, rough = get("color"), get("roughness", grey=True)
    if colour is None or rough is None:
        raise FileNotFoundError(f"{folder}: needs color and roughness")
    metal = get("metalness", grey=True)
    metal = np.zeros_like(rough) if metal is None else metal
    diffuse, specular = metalness_to_specular(cv.srgb_to_linear(colour), metal)
    height, nmap = get("height", grey=True), get("normal")
    if nmap is not None:
        normal, source = _oriented_normals(nmap, height, default_sign, "manifest")
    elif height is not None:
        normal, source = normals_from_height(height, depth=depth), "height"
    else:
        raise FileNotFoundError(f"{folder}: needs normal or height")
    return {"normal": normal.astype(np.float32), "diffuse": diffuse.astype(np.float32),
            "roughness": rough.astype(np.float32), "specular": specular.astype(np.float32),
            "normal_source": source}


#: ``cc0_more`` sets that are not a flat material under a flash: glowing cracks, a building front.
NOT_MATERIALS = ("Lava002", "Facade005")


def all_folders(shared=None):
    """(loader, folder) for every CC0/MIT set with full maps under ``<shared>/materials``: ambientCG,
    PlayCanvas and ``cc0_more`` (but :data:`NOT_MATERIALS`); empty when absent."""
    import functools

    from export.files import shared_data

    root = shared_data(shared)
    out = seed_folders(root)
    base = os.path.join(root, "materials", "cc0_more")
    if os.path.isdir(base):
        signs = _manifest_signs(base)
        for src in sorted(os.listdir(base)):
            d = os.path.join(base, src)
            if not os.path.isdir(d):
                continue
            for name in sorted(os.listdir(d)):
                if os.path.isdir(os.path.join(d, name)) and name not in NOT_MATERIALS:
                    loader = functools.partial(load_cc0_more, default_sign=signs.get(name, -1))
                    out.append((loader, os.path.join(d, name)))
    return out
