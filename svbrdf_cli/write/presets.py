"""Texture-set presets: our linear map set re-packed for engines and DCC tools.

Each preset is a function ``write_<name>(folder, maps, *, bits, fmt, force)``
that writes one texture set into ``folder`` and returns the paths it wrote;
:data:`PRESETS` maps CLI names to them. The input is the runtime's linear map
set (see :mod:`svbrdf_cli.write.mapset`): ``normal`` (H, W, 3) unit vectors, +Y up;
``diffuse`` and ``specular`` (H, W, 3) linear albedo / F0; ``roughness``
(H, W, 1) perceptual roughness (alpha = r**2, the same parametrisation glTF,
Unreal, Unity and Blender use, so it is copied, never remapped).

=============  ==================================================================
preset         files (colour space)
=============  ==================================================================
svbrdf         normal.png diffuse.png roughness.png specular.png: the native
               Des18 encoding, exactly these four files (benchmarks read them)
gltf           baseColor.png (sRGB); metallicRoughness.png (linear: R = ambient
               occlusion, G = roughness, B = metallic); normal.png (OpenGL,
               +Y up); height.png; material.gltf (one textured quad)
unreal         T_<Name>_BC.png (sRGB); T_<Name>_N.png (DirectX: green flipped, Y down);
               T_<Name>_ORM.png (linear: R = ambient occlusion, G = roughness, B = metallic);
               T_<Name>_H.png
unity-hdrp     <Name>_BaseMap.png (sRGB); <Name>_MaskMap.png (linear RGBA: R = metallic,
               G = ambient occlusion, B = detail mask = 1, A = smoothness = 1 - roughness);
               <Name>_Normal.png (OpenGL); <Name>_Height.png
blender        <name>_BaseColor.png (sRGB); <name>_Roughness.png,
               <name>_Metallic.png (Non-Color grey); <name>_Normal.png
               (OpenGL); <name>_Height.png
=============  ==================================================================

Every preset but ``svbrdf`` also writes ``texture_set.json``: the preset, the
normal-map convention, each file's role and colour space, and the height map's
scale (a PNG cannot say how deep its [0, 1] range is): a fixed one, 0.5 the mean
surface and the range :data:`svbrdf_cli.write.derive.HEIGHT_SPAN` texture widths.

Blender names follow Node Wrangler's "Principled Texture Setup" (Ctrl+Shift+T),
which splits a file name at ``_ - . #``, at lower-to-upper case changes and
drops digits, then matches the lower-cased pieces against its default tags
(base colour: "diffuse diff albedo base col color basecolor", "roughness rough
rgh", "metallic metalness metal mtl", "normal nor nrm nrml norm",
"displacement displace disp dsp height heightmap"). ``BaseColor`` becomes
"base color", which every version matches (older ones lack the "basecolor"
tag). It matches the material name too, so a name such as "rusty_metal" would
wire every map to Metallic: names holding a tag fall back to "material".

Specular -> metallic uses KHR_materials_pbrSpecularGlossiness' ``solveMetallic``
(see :func:`specular_to_metallic`); the height map is integrated from the
normals with Frankot-Chellappa (:func:`normals_to_height`).

Sets are written atomically: every file goes into a hidden sibling folder that
is renamed into place once complete, so a failure never leaves a half-written
set (or the temporary folder) behind, and an existing set is only replaced
with ``force=True`` when it is a set this tool wrote (:mod:`svbrdf_cli.write.atomic`).
"""

from __future__ import annotations

import json
import logging
import os
import re

import numpy as np

from svbrdf_cli.version import __version__
from svbrdf_cli import conventions as cv
from svbrdf_cli import imageio
from svbrdf_cli.write.atomic import write_set
from svbrdf_cli.errors import MapSetError
from svbrdf_cli.write.derive import (
    AO_NOTE,
    HEIGHT_MIDLEVEL,
    HEIGHT_SPAN,
    ambient_occlusion,
    height_to_map,
    normals_to_directx,
    normals_to_height,
    normals_to_opengl,
    specular_to_metallic,
)
from svbrdf_cli.write.gltf import gltf_document

log = logging.getLogger("svbrdf")

#: Output bit depths of integer (PNG) files; EXR is always 32-bit float.
PNG_BITS = (8, 16)
#: File formats for linear data; colour (sRGB) maps are always PNG.
FORMATS = ("png", "exr")
#: Bit depth of height maps written as PNG (8 bits shows stepping).
HEIGHT_BITS = 16



# --------------------------------------------------------------------------
# Writing a set atomically
# --------------------------------------------------------------------------

def _check_options(bits, fmt, png_only=None):
    if bits not in PNG_BITS:
        raise ValueError(f"bits must be one of {PNG_BITS}; got {bits!r}.")
    if fmt not in FORMATS:
        raise ValueError(f"fmt must be one of {FORMATS}; got {fmt!r}.")
    if png_only and fmt != "png":
        raise ValueError(f"The {png_only} preset writes PNG only; got fmt={fmt!r}.")


class _Files:
    """Collects the images of one set in a temporary folder, plus their roles."""

    def __init__(self, tmp, bits, fmt, preset, normal_convention, tileable=False, ao=True, images=()):
        self.tmp, self.bits, self.fmt, self.tileable, self.use_ao = tmp, bits, fmt, tileable, ao
        self._height = None
        self._jobs = [(os.path.join(tmp, name), *job) for name, *job in images]  # the caller's, written alongside
        self.names = [name for name, *_ in images]
        self.meta = {"generator": f"svbrdf {__version__}", "conventions_version": cv.CONVENTIONS_VERSION,
                     "preset": preset, "normal_map": normal_convention,
                     "roughness": "perceptual, GGX alpha = roughness^2", "files": {}}

    def colour(self, stem, pixels, role):
        """An sRGB-encoded colour map: always PNG."""
        self._write(stem + ".png", cv.linear_to_srgb(pixels), self.bits, role, "sRGB")

    def data(self, stem, pixels, role, bits=None):
        """A linear (Non-Color) data map: PNG, or 32-bit float EXR."""
        if self.fmt == "exr":
            self._write(stem + ".exr", pixels, 32, role, "linear")
        else:
            self._write(stem + ".png", pixels, bits or self.bits, role, "linear")

    def height_field(self, normals):
        """The height integrated from ``normals`` (once per set)."""
        if self._height is None:
            self._height = normals_to_height(normals, tileable=self.tileable)
        return self._height

    def ao(self, normals):
        """(H, W, 1) ambient occlusion from the height (:func:`ambient_occlusion`), or 1 without ``ao``."""
        h, w = normals.shape[:2]
        if not self.use_ao:
            return np.ones((h, w, 1), np.float32)
        self.meta["ambient_occlusion"] = AO_NOTE
        return ambient_occlusion(self.height_field(normals), 2.0 * cv.SURFACE_HALF_SIZE / w, self.tileable)[..., None]

    def height(self, stem, normals):
        height = self.height_field(normals)
        unit = height_to_map(height, 2.0 * cv.SURFACE_HALF_SIZE)
        self.data(stem, unit[..., None], "height", bits=HEIGHT_BITS)
        relief = float(height.max() - height.min()) / (2.0 * cv.SURFACE_HALF_SIZE)
        self.meta["height"] = {
            "file": self.names[-1], "scale_to_width": HEIGHT_SPAN, "midlevel": HEIGHT_MIDLEVEL,
            "relief_to_width": round(relief, 6),
            "note": f"height in texture widths = (value - {HEIGHT_MIDLEVEL}) * {HEIGHT_SPAN}: a displacement "
                    f"node's midlevel {HEIGHT_MIDLEVEL}, scale {HEIGHT_SPAN} * the texture's real-world width",
            "integration": "Frankot-Chellappa from the normal map"}

    def _write(self, name, pixels, bits, role, space):
        # queued: finish() writes them all at once (imageio.write_images)
        self._jobs.append((os.path.join(self.tmp, name), pixels, bits, space == "sRGB"))
        self.names.append(name)
        self.meta["files"][name] = {"role": role, "colour_space": space, "bits": bits}

    def finish(self, extra=None):
        imageio.write_images(self._jobs)
        self._jobs = []
        meta = dict(self.meta, **(extra or {}))
        with open(os.path.join(self.tmp, "texture_set.json"), "w") as f:
            json.dump(meta, f, indent=2)
            f.write("\n")
        return self.names + ["texture_set.json"]


def _metal_rough(maps):
    base, metallic = specular_to_metallic(maps["diffuse"], maps["specular"])
    rough = np.asarray(maps["roughness"], dtype=np.float32)[..., :1].clip(0.0, 1.0)
    return base, metallic, rough


def _check_maps(maps):
    missing = [k for k in cv.MAP_NAMES if k not in maps]
    if missing:
        raise MapSetError(f"The map set lacks {', '.join(missing)}; it needs {', '.join(cv.MAP_NAMES)}.")


# --------------------------------------------------------------------------
# Presets
# --------------------------------------------------------------------------

def write_svbrdf(folder, maps, *, bits=8, fmt="png", force=False, extra=None, protect=(), name=None,
                 tileable=False, ao=True, images=(), stored=None):
    """Native set: ``normal.png diffuse.png roughness.png specular.png`` and
    ``texture_set.json`` (their roles and encodings).

    Written by :func:`svbrdf_cli.write.mapset.write_map_set` in the Des18 encoding
    (benchmarks and ``svbrdf render`` read it back). PNG only, no height.

    Args:
        folder: the set's folder (must not exist unless ``force``).
        maps: linear map set (see the module docstring), or None with ``stored``.
        bits: 8 or 16.
        fmt: "png" only.
        force: replace an existing folder.
        extra: optional function of the temporary folder writing more files into it; returns their names.
        protect: paths that must survive (the photo itself when it lies in the folder).
        name: the material's name (unused by the native layout).
        tileable: the maps tile (the height integration wraps).
        ao: write ambient occlusion (unused by the native layout).
        images: more images for the set, (name, pixels or a function making them, bits, colour) each,
            encoded with the maps.
        stored: the maps already in the stored encoding (a capture's): written as they are, without
            the round trip through linear units.

    Returns:
        List of the written paths.
    """
    from svbrdf_cli.write import mapset

    _check_options(bits, fmt, png_only="svbrdf")
    _check_maps(maps if stored is None else stored)

    def files(tmp):
        more = [(os.path.join(tmp, name), *job) for name, *job in images]
        if stored is None:
            mapset.write_map_set(tmp, maps, bits=bits, images=more)
        else:
            mapset.write_stored_set(tmp, stored, bits=bits, images=more)
        names = [name for name, *_ in images]
        f = _Files(tmp, bits, fmt, "svbrdf", "OpenGL (+Y up)", tileable, ao)
        f.names.extend(names)
        for name, role in zip(cv.MAP_NAMES, ("normal", "diffuse albedo (stored^2.2 = linear)", "roughness",
                                              "specular F0 (stored^2.2 = linear)")):
            space = "sRGB" if name in ("diffuse", "specular") else "linear"
            f.names.append(name + ".png")
            f.meta["files"][name + ".png"] = {"role": role, "colour_space": space, "bits": bits}
        return f.finish()

    return write_set(folder, files, force, extra, protect)


def write_gltf(folder, maps, *, bits=8, fmt="png", force=False, extra=None, protect=(), name=None,
                 tileable=False, ao=True, images=()):
    """GlTF 2.0 metallic-roughness set plus ``material.gltf`` (one textured quad).

    ``baseColor.png`` (sRGB), ``metallicRoughness.png`` (linear; R = ambient
    occlusion from the height, referenced as ``occlusionTexture`` too; 1 with ``ao=False``),
    G = roughness, B = metallic), ``normal.png`` (+Y up, linear), ``height.png`` (16-bit,
    not referenced: glTF has no displacement slot) and ``material.gltf``. glTF
    core textures are PNG/JPEG, so ``fmt`` must be "png".

    Returns:
        Written paths.
    """
    _check_options(bits, fmt, png_only="gltf")
    _check_maps(maps)
    base, metallic, rough = _metal_rough(maps)

    def files(tmp):
        f = _Files(tmp, bits, fmt, "gltf", "OpenGL (+Y up)", tileable, ao, images)
        f.colour("baseColor", base, "base colour")
        f.data("metallicRoughness", np.concatenate([f.ao(maps["normal"]), rough, metallic], -1),
               "R = ambient occlusion (glTF occlusionTexture), G = roughness, B = metallic")
        f.data("normal", normals_to_opengl(maps["normal"]), "normal (OpenGL, +Y up)")
        f.height("height", maps["normal"])
        doc = gltf_document("baseColor.png", "metallicRoughness.png", "normal.png",
                            name=os.path.basename(os.path.abspath(folder)), extras={"height": f.meta["height"]})
        with open(os.path.join(tmp, "material.gltf"), "w") as out:
            json.dump(doc, out, indent=2)
            out.write("\n")
        return f.finish() + ["material.gltf"]

    return write_set(folder, files, force, extra, protect)


def write_unreal(folder, maps, *, bits=8, fmt="png", force=False, extra=None, protect=(), name=None,
                 tileable=False, ao=True, images=()):
    """Unreal Engine set, named as Unreal projects name textures: ``T_<Name>_BC`` (base colour, sRGB),
    ``T_<Name>_N`` (normal, DirectX), ``T_<Name>_ORM``, ``T_<Name>_H`` (height); ``<Name>`` is ``name``
    or the folder's (:func:`asset_name`), so sets imported into one folder never collide.

    ORM is linear (import with sRGB off): R = ambient occlusion from the height
    (1 with ``ao=False``), G = roughness, B = metallic. The normal map's green channel is
    flipped (Y down), as Unreal expects.

    Returns:
        Written paths.
    """
    _check_options(bits, fmt)
    _check_maps(maps)
    base, metallic, rough = _metal_rough(maps)

    def files(tmp):
        f = _Files(tmp, bits, fmt, "unreal", "DirectX (green flipped, Y down)", tileable, ao, images)
        t = f"T_{asset_name(folder, name)}_"
        f.colour(t + "BC", base, "base colour")
        f.data(t + "N", normals_to_directx(maps["normal"]), "normal (DirectX, Y down)")
        f.data(t + "ORM", np.concatenate([f.ao(maps["normal"]), rough, metallic], -1),
               "R = ambient occlusion, G = roughness, B = metallic")
        f.height(t + "H", maps["normal"])
        return f.finish()

    return write_set(folder, files, force, extra, protect)


def write_unity_hdrp(folder, maps, *, bits=8, fmt="png", force=False, extra=None, protect=(), name=None,
                 tileable=False, ao=True, images=()):
    """Unity HDRP Lit set: ``<Name>_BaseMap`` (sRGB), ``<Name>_MaskMap`` (RGBA), ``<Name>_Normal``,
    ``<Name>_Height``; ``<Name>`` is ``name`` or the folder's (:func:`asset_name`).

    MaskMap is linear (import with sRGB off): R = metallic, G = ambient occlusion,
    B = detail mask (1: a detail map, if one is added, applies everywhere),
    A = smoothness = 1 - roughness. Unity normal maps are OpenGL (+Y up).

    Returns:
        Written paths.
    """
    _check_options(bits, fmt)
    _check_maps(maps)
    base, metallic, rough = _metal_rough(maps)
    one = np.ones_like(rough)

    def files(tmp):
        f = _Files(tmp, bits, fmt, "unity-hdrp", "OpenGL (+Y up)", tileable, ao, images)
        t = f"{asset_name(folder, name)}_"
        f.colour(t + "BaseMap", base, "base colour")
        f.data(t + "MaskMap", np.concatenate([metallic, f.ao(maps["normal"]), one, 1.0 - rough], -1),
               "R = metallic, G = ambient occlusion, B = detail mask (1), A = smoothness = 1 - roughness")
        f.data(t + "Normal", normals_to_opengl(maps["normal"]), "normal (OpenGL, +Y up)")
        f.height(t + "Height", maps["normal"])
        return f.finish()

    return write_set(folder, files, force, extra, protect)


#: Node Wrangler's default Principled Texture Setup tags (see the module docstring).
_NODE_WRANGLER_TAGS = frozenset(
    "diffuse diff albedo base col color basecolor sss subsurface metallic metalness metal mtl "
    "specularity specular spec spc normal nor nrm nrml norm bump bmp roughness rough rgh gloss glossy "
    "glossiness displacement displace disp dsp height heightmap transmission transparency emission "
    "emissive emit alpha opacity ao ambient occlusion".split())


def name_components(name):
    """A file name split the way Node Wrangler splits it (lower-cased pieces)."""
    name = "".join(ch for ch in name if not ch.isdigit())
    name = re.sub(r"([a-z])([A-Z])", r"\1 \2", name)
    return [p.lower() for p in re.split(r"[\s_.\-#]+", name) if p]


def asset_name(folder, name=None):
    """The material's name in engine file names: ``name``, else the set folder's, as letters, digits and
    underscores (what Unreal and Unity asset names allow); "Material" when nothing is left."""
    raw = name or os.path.basename(os.path.abspath(os.fspath(folder)))
    return re.sub(r"[^A-Za-z0-9_]+", "_", raw).strip("_") or "Material"


def blender_prefix(folder, name=None):
    """File-name prefix for the Blender preset: ``name`` or the folder's, unless Node Wrangler would
    misread it."""
    raw = name or os.path.basename(os.path.abspath(os.fspath(folder)))
    prefix = re.sub(r"[^A-Za-z0-9_-]+", "-", raw).strip("-_")  # (Node Wrangler splits at _ and - alike)
    if not prefix or set(name_components(prefix)) & _NODE_WRANGLER_TAGS:
        if prefix:
            log.warning("Blender preset: '%s' holds a texture tag Node Wrangler matches; "
                        "naming the files material_*.", raw)
        return "material"
    return prefix


def write_blender(folder, maps, *, bits=8, fmt="png", force=False, extra=None, protect=(), name=None,
                 tileable=False, ao=True, images=()):
    """Blender set, named for Node Wrangler's Principled Texture Setup (Ctrl+Shift+T).

    ``<name>_BaseColor.png`` (sRGB), ``<name>_Roughness`` and
    ``<name>_Metallic`` (grey, set the Image nodes to Non-Color),
    ``<name>_Normal`` (OpenGL, Blender's Normal Map node default, Non-Color),
    ``<name>_Height`` (Non-Color, for a Displacement node) and, with ``ao``,
    ``<name>_AO`` (Non-Color; Node Wrangler multiplies it into the base colour).
    ``<name>`` is :func:`blender_prefix` of the folder.

    Returns:
        Written paths.
    """
    _check_options(bits, fmt)
    _check_maps(maps)
    base, metallic, rough = _metal_rough(maps)
    prefix = blender_prefix(folder, name)

    def files(tmp):
        f = _Files(tmp, bits, fmt, "blender", "OpenGL (+Y up)", tileable, ao, images)
        f.colour(f"{prefix}_BaseColor", base, "base colour")
        f.data(f"{prefix}_Roughness", rough, "roughness (Non-Color)")
        f.data(f"{prefix}_Metallic", metallic, "metallic (Non-Color)")
        f.data(f"{prefix}_Normal", normals_to_opengl(maps["normal"]), "normal (OpenGL, Non-Color)")
        f.height(f"{prefix}_Height", maps["normal"])
        if ao:
            f.data(f"{prefix}_AO", f.ao(maps["normal"]), "ambient occlusion (Non-Color)")
        return f.finish()

    return write_set(folder, files, force, extra, protect)


#: Preset name -> writer.
PRESETS = {"svbrdf": write_svbrdf, "gltf": write_gltf, "unreal": write_unreal,
           "unity-hdrp": write_unity_hdrp, "blender": write_blender}
#: Presets whose files must be PNG (the native contract; glTF core images).
PNG_ONLY_PRESETS = ("svbrdf", "gltf")


def write_preset(preset, folder, maps, stored=None, **kwargs):
    """Write ``maps`` as the texture set ``preset`` (a key of :data:`PRESETS`).

    Keyword arguments: ``bits``, ``fmt``, ``force``, ``extra`` (a function
    of the temporary folder that writes more files into the same atomic set),
    ``protect`` (paths the run reads: a folder holding one is never
    replaced; see :func:`svbrdf_cli.write.atomic.write_set`), ``name`` (the
    material's name in engine file names, :func:`asset_name`),
    ``tileable`` (the maps wrap: the height map is integrated periodically)
    and ``ao`` (ambient occlusion from the height in ORM, MaskMap and glTF's
    occlusion channel; False: a constant 1), ``images`` (more images for the set, each
    ``(name, pixels, bits, colour)``, encoded together with the preset's own; ``pixels`` may be a function
    making them, called on an encoding thread).

    ``stored``: the maps in the stored encoding, instead of ``maps`` (None): the native preset writes
    them as they are, the others decode them first.
    """
    try:
        writer = PRESETS[preset]
    except KeyError:
        raise ValueError(f"Unknown preset {preset!r}; choose one of {', '.join(PRESETS)}.") from None
    if stored is not None and maps is None:
        if writer is write_svbrdf:
            return writer(folder, None, stored=stored, **kwargs)
        from svbrdf_cli.write.mapset import stored_to_linear

        maps = stored_to_linear(stored)
    return writer(folder, maps, **kwargs)
