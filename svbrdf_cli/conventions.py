"""Rendering and map conventions: the one source of truth.

Everything that decides what a number in a map or an image *means* lives here:
map names and channel order, how each map is encoded on disk, the colour
transforms, roughness to GGX alpha, the flash geometry, the light layout used
for the highlight-removed auxiliary renderings, and the thresholds of the
bumpiness/highlight masks. ``svbrdf_cli/shading.py`` (numpy), the writers, and
``export/render/`` (torch) import these; none of them restates a constant.

The conventions match the Des18 data family (Deschaintre et al. 2018), which
the paper and our validation set (Des19 test set) use. ``docs/conventions.md``
explains them for people; keep the two in step and bump
:data:`CONVENTIONS_VERSION` when a meaning changes (it is written into every
exported model and checked on load).

The small functions below use only arithmetic, ``.clip`` and ``.sum`` so they
work unchanged on numpy arrays and torch tensors (the runtime never imports
torch; ``export/`` passes tensors in). Functions that take a channel axis use
``axis=-1`` (HWC, the runtime's layout) by default; torch code passes
``axis=1`` (NCHW).
"""

from __future__ import annotations

import math

import numpy as np

#: Bumped whenever the meaning of a map, an image or the geometry changes.
CONVENTIONS_VERSION = "1"

# --------------------------------------------------------------------------
# Maps
# --------------------------------------------------------------------------

#: The native SVBRDF map set, in the order networks and files use.
MAP_NAMES = ("normal", "diffuse", "roughness", "specular")

#: Channels of each map in memory (roughness is one channel; on disk it is
#: written as grey RGB, the way Des18 stores it).
MAP_CHANNELS = {"normal": 3, "diffuse": 3, "roughness": 1, "specular": 3}

#: Tangent-space normal maps: +X right, +Y up (OpenGL / glTF / Blender), +Z out
#: of the surface. Unreal and other DirectX-style tools flip the green channel.
NORMAL_Y_UP = True

#: Uniform normal map N_u of the paper (Eq. 4), in its stored encoding.
FLAT_NORMAL_ENCODED = (0.5, 0.5, 1.0)
#: The same normal as a unit vector.
FLAT_NORMAL = (0.0, 0.0, 1.0)

#: Albedo maps (diffuse and specular) are stored gamma-encoded with this
#: exponent and are linear in the maths (Des18 uses a pure 2.2 power, not the
#: piecewise sRGB curve; ``score_maps.py`` compares in the stored space).
ALBEDO_GAMMA = 2.2

#: Rendered images (inputs I and every auxiliary rendering) are clipped to
#: [0, 1] in linear radiance, then encoded with the same 2.2 power.
IMAGE_GAMMA = 2.2

#: Reflectance at normal incidence of a dielectric (used when converting
#: specular to metallic workflows).
DIELECTRIC_F0 = 0.04

#: What a trained chain's F0 is (``specular_level`` in an export's metadata): ``absolute``, the
#: material's; or ``photo``, read at the photo's flash level as the diffuse, so that the capture scales
#: it with the diffuse (``docs/training.md``, "F0 at the photo's level").
SPECULAR_LEVELS = ("absolute", "photo")

#: F0 (brightness) up to this is a dielectric's, whatever its tint: water 0.02, plastics, lacquer,
#: glass and stone 0.04-0.05, gemstones up to about 0.08. Metals reflect 0.5 and more (iron 0.56,
#: gold, copper, aluminium 0.9). From DIELECTRIC_MAX_F0 to METAL_MIN_F0 a material is read as
#: more and more metal (a smoothstep, :func:`metal_weight`): ``--refine`` lets F0 take a colour there (a
#: metal's is its own); the metallic conversion calls metal from :data:`METAL_CALL_F0`.
DIELECTRIC_MAX_F0 = 0.08
METAL_MIN_F0 = 0.16


def smoothstep(x, lo, hi, dtype=np.float64):
    """0 for ``x`` up to ``lo``, 1 from ``hi``, the cubic 3t^2 - 2t^3 between (no edge at either end),
    computed in ``dtype`` (None: ``x``'s own)."""
    t = np.clip((np.asarray(x, dtype) - lo) / (hi - lo), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def metal_weight(f0_level):
    """0 for an F0 level (brightness) up to :data:`DIELECTRIC_MAX_F0`, 1 from :data:`METAL_MIN_F0`, a
    smoothstep between (no edge where the level crosses a line)."""
    return smoothstep(f0_level, DIELECTRIC_MAX_F0, METAL_MIN_F0, dtype=None)


#: Where the metallic conversion calls an F0 level (brightness) metal: from none at the first to fully
#: at the second, a smoothstep. One photo does not tell a dark dielectric (F0 0.04) from a dark grey
#: metal (0.5 and more: iron 0.56), and a trained chain's F0 between the two is a hedge over them, the
#: share of metal ``(F0 - 0.04) / (0.56 - 0.04)``. It says metal more likely than not past the halfway
#: mark, 0.30; the band is that share from 0.35 to 0.65. Measured with the default chain on the 27 real
#: dielectric photos of ``export.studies.artist_check``: a black phone case with a metallic-flake look
#: (``paper_real`` IMG_7202, its F0 0.17 at the median, 0.32 at the 90th percentile) came out 72 % metal
#: with the band :data:`DIELECTRIC_MAX_F0`-:data:`METAL_MIN_F0`; no photo with metal in it had an F0
#: level above 0.08.
METAL_CALL_F0 = (0.22, 0.38)


def metal_call(f0_level):
    """How much the metallic conversion reads an F0 level (brightness) as a metal's: 0 up to
    ``METAL_CALL_F0[0]``, 1 from ``METAL_CALL_F0[1]``, a smoothstep between."""
    return smoothstep(f0_level, METAL_CALL_F0[0], METAL_CALL_F0[1], dtype=None)

#: Smallest roughness the renderer evaluates. alpha = r^2 would reach 0 and
#: make GGX a Dirac delta; this keeps r = 0 finite (alpha = 1e-4).
MIN_ROUGHNESS = 0.01

#: Denominator floor used by D and G (Des18 uses the same 1e-3).
EPS = 1e-3


def roughness_to_alpha(r):
    """GGX alpha from perceptual roughness: alpha = r**2 (Burley 2012).

    Args:
        r: roughness in [0, 1], any shape; numpy array or torch tensor.

    Returns:
        alpha, same shape, with r clipped below at :data:`MIN_ROUGHNESS`.
    """
    r = r.clip(MIN_ROUGHNESS, 1.0) if hasattr(r, "clip") else min(max(r, MIN_ROUGHNESS), 1.0)
    return r * r


def encode_normals(n):
    """Unit normal vectors in [-1, 1] -> stored encoding xyz*0.5+0.5 in [0, 1]."""
    return n * 0.5 + 0.5


def decode_normals(x, axis=-1):
    """Stored normal encoding in [0, 1] -> unit vectors (renormalised).

    Args:
        x: encoded normals, channels x, y, z along ``axis``.
        axis: channel axis (-1 for HWC numpy, 1 for NCHW torch).
    """
    return normalize(x * 2.0 - 1.0, axis=axis)


def normalize(v, axis=-1, eps=1e-20):
    """Vectors scaled to unit length along ``axis``.

    ``eps`` only keeps zero vectors finite; it must stay tiny, since near-grazing
    half vectors have squared lengths around 1e-5 and GGX at low alpha is
    sensitive to 1e-8 changes of n.h.
    """
    if isinstance(v, np.ndarray) and axis in (-1, v.ndim - 1) and v.shape[-1] == 3:  # the three squares
        # added directly: the same sum (same order), 5-14x faster than numpy's reduction over a 3-long axis
        sq = v[..., 0:1] * v[..., 0:1] + v[..., 1:2] * v[..., 1:2] + v[..., 2:3] * v[..., 2:3]
        return v / (sq + eps) ** 0.5
    return v / ((v * v).sum(axis, keepdims=True) + eps) ** 0.5


def decode_maps(stored, axis=-1):
    """Stored-encoding maps in [0, 1] -> linear maps (the rule for each map, once).

    Args:
        stored: dict with ``normal`` (xyz*0.5+0.5), ``diffuse`` and
            ``specular`` (gamma-encoded), ``roughness`` (linear), channels
            along ``axis`` (roughness one channel).
        axis: channel axis (-1 for HWC numpy, 1 for NCHW torch).
    """
    return {"normal": decode_normals(stored["normal"], axis=axis),
            "diffuse": albedo_to_linear(stored["diffuse"]),
            "roughness": stored["roughness"],
            "specular": albedo_to_linear(stored["specular"])}


def encode_maps(maps):
    """Inverse of :func:`decode_maps`."""
    return {"normal": encode_normals(maps["normal"]),
            "diffuse": albedo_to_stored(maps["diffuse"]),
            "roughness": maps["roughness"],
            "specular": albedo_to_stored(maps["specular"])}


def albedo_to_linear(x):
    """Stored (gamma 2.2) diffuse/specular albedo in [0, 1] -> linear."""
    return x.clip(0.0, 1.0) ** ALBEDO_GAMMA


def albedo_to_stored(x):
    """Linear albedo -> stored gamma 2.2 encoding in [0, 1]."""
    return x.clip(0.0, 1.0) ** (1.0 / ALBEDO_GAMMA)


def image_to_linear(x):
    """Encoded rendered image in [0, 1] -> linear radiance in [0, 1]."""
    return x.clip(0.0, 1.0) ** IMAGE_GAMMA


def image_to_encoded(x):
    """Linear radiance -> the clipped, gamma-2.2 image networks see.

    A tiny floor keeps the gradient of ``x ** (1/2.2)`` finite at 0.
    """
    return x.clip(1e-10, 1.0) ** (1.0 / IMAGE_GAMMA)


def srgb_to_linear(x):
    """IEC 61966-2-1 sRGB decoding (for photos and engine texture sets)."""
    x = x.clip(0.0, 1.0)
    lo = x / 12.92
    hi = ((x + 0.055) / 1.055) ** 2.4
    m = x > 0.04045
    return hi * m + lo * ~m


def linear_to_srgb(x):
    """IEC 61966-2-1 sRGB encoding (for photos and engine texture sets)."""
    x = x.clip(0.0, 1.0)
    lo = x * 12.92
    hi = 1.055 * x.clip(0.0031308, 1.0) ** (1.0 / 2.4) - 0.055
    m = x > 0.0031308
    return hi * m + lo * ~m


# --------------------------------------------------------------------------
# Flash geometry
# --------------------------------------------------------------------------

#: The imaged surface is the square [-SURFACE_HALF_SIZE, +SURFACE_HALF_SIZE]^2
#: in the plane z = 0. Row 0 of an image is y = +1 (the top), column 0 is
#: x = -1: +Y up in world space and in the normal map agree.
SURFACE_HALF_SIZE = 1.0


def camera_height(tan_half_fov):
    """Height above the surface at which a square image sees exactly the
    [-1, 1]^2 surface, for a field of view with ``tan(fov / 2) = tan_half_fov``
    (array-agnostic)."""
    return SURFACE_HALF_SIZE / tan_half_fov


#: Camera (and, for a flash photo, the co-located light) height above the
#: surface centre. 1 / tan(22.5 deg) = 2.414: a 45 degree field of view sees
#: exactly the [-1, 1]^2 square.
CAMERA_HEIGHT = camera_height(math.tan(math.radians(22.5)))

#: Default camera / flash position.
FLASH_POSITION = (0.0, 0.0, CAMERA_HEIGHT)

#: Default point-light intensity (radiant intensity in units where the
#: rendered radiance is ``intensity * pi * f * cos / d^2``). With it a white
#: Lambertian surface (d = 1, s = 0) at the centre renders to 0.5 in linear
#: radiance: bright enough to show albedo, headroom for highlights.
LIGHT_INTENSITY = 0.5 * CAMERA_HEIGHT ** 2

#: Flash power of the validation inputs (and of a photo exposed as the tool exposes
#: it): the point-light intensity at :data:`FLASH_POSITION` that reproduces the Des19
#: inputs from their maps read as linear albedo. Fitted per sample on the pixels where
#: the diffuse term dominates (specular under 10 % of it, none clipped): median 10.35
#: over the 18 samples with enough such pixels, p10-p90 6.3-14.0
#: (``python -m export.studies.physical_eval --fit-flash``). The physical estimate
#: (:mod:`svbrdf_cli.infer.physical`) divides by it to put albedo on an absolute scale.
FLASH_INTENSITY = 10.35

#: Luminance weights (Rec. 709) of linear RGB.
LUMA = (0.2126, 0.7152, 0.0722)

#: Mean encoded brightness of a flash image after auto exposure: the median
#: over the 29 Des19 validation inputs (their means span 0.11-0.60). Fitting
#: the intensity that reproduces each input's brightness from its ground-truth
#: maps at the default geometry gives 14 to 829 (median 187): those inputs
#: were exposed per image, not rendered with one flash power.
AUTO_EXPOSURE_MEAN = 0.32


#: An encoded photo's pixels at or above this fraction of its clip level are clipped.
CLIPPED = 0.98
#: A photo whose brightest value is held by at least this share of its pixels (to within
#: CLIP_PLATEAU_TOLERANCE of it, relative: the same value) was clipped there: the camera's
#: ceiling, moved down by an exposure gain. (Measured at 256²: the exposed real photos whose
#: highlight clipped hold 0.45-1.3 % of their pixels there, the unclipped ones at most 0.04 %.)
CLIP_PLATEAU_SHARE = 0.003
CLIP_PLATEAU_TOLERANCE = 1e-4


def clip_level(image):
    """The encoded value at which an encoded (H, W, 3) photo was clipped.

    A camera clips at its white (1.0); a photo darkened afterwards (``svbrdf capture``'s auto
    exposure, a validation input rendered that way) holds its clipped highlight as a flat plateau
    at a lower value, whose pixels say only "at least this bright". Such a plateau (many pixels at
    exactly the photo's brightest value, which an unclipped photo's smooth peak never has) gives
    its level; otherwise 1.0.
    """
    x = np.asarray(image, np.float32)
    top_channel = np.maximum(np.maximum(x[..., 0], x[..., 1]), x[..., 2])
    top = float(top_channel.max()) if top_channel.size else 1.0
    if top >= CLIPPED or top <= 0.0:
        return 1.0
    if float((top_channel >= top * (1.0 - CLIP_PLATEAU_TOLERANCE)).mean()) >= CLIP_PLATEAU_SHARE:
        return top
    return 1.0


def surface_positions(height, width):
    """World positions of pixel centres on the surface.

    Args:
        height: rows of the image.
        width: columns of the image.

    Returns:
        (height, width, 3) float64 array of (x, y, 0); row 0 is y = +1.
    """
    s = SURFACE_HALF_SIZE
    xs = ((np.arange(width) + 0.5) / width * 2.0 - 1.0) * s
    ys = -((np.arange(height) + 0.5) / height * 2.0 - 1.0) * s
    x, y = np.meshgrid(xs, ys)
    return np.stack([x, y, np.zeros_like(x)], axis=-1)


# --------------------------------------------------------------------------
# Auxiliary renderings and masks (paper Eqs. 4-11)
# --------------------------------------------------------------------------

#: Number of lights averaged into I_hr and I_hr^2 (paper Eqs. 5 and 8).
AUX_LIGHT_COUNT = 100

#: Radius of the disc of light positions, at camera height, for I_hr. A light
#: at (lx, ly, h) with the camera at (0, 0, h) puts the mirror highlight of a
#: flat surface at (lx/2, ly/2): a radius of 4 sweeps it over [-2, 2]^2, past
#: the corners of the surface, so every pixel sees a highlight from only a
#: few of the lights and the mean washes it out.
AUX_LIGHT_RADIUS = 4.0

#: Roughness R_1 used everywhere for I_hr^2 (Eq. 7).
AUX_HIGH_ROUGHNESS = 1.0

#: Highlight threshold delta_h on the GGX NDF value (Eq. 10).
HIGHLIGHT_NDF_THRESHOLD = 0.9
#: Lowlight threshold delta_s on the GGX NDF value (Eq. 11).
LOWLIGHT_NDF_THRESHOLD = 0.15


def aux_light_positions(count=AUX_LIGHT_COUNT, radius=AUX_LIGHT_RADIUS, height=CAMERA_HEIGHT):
    """Light positions for the highlight-removed renderings (Eqs. 5-8).

    The paper's scheme is in its supplement, which we do not have. Ours: a
    Fibonacci (sunflower) disc of ``count`` lights at the camera's height, so
    they cover the disc evenly and deterministically; see
    ``docs/conventions.md`` for why this removes highlights.

    Returns:
        (count, 3) float64 positions.
    """
    k = np.arange(count) + 0.5
    rho = radius * np.sqrt(k / count)
    theta = k * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([rho * np.cos(theta), rho * np.sin(theta), np.full(count, float(height))], -1)


def aux_light_intensities(positions, intensity=LIGHT_INTENSITY, height=CAMERA_HEIGHT):
    """Per-light intensity so each light gives the surface centre the flash's irradiance.

    Irradiance at the centre from a light at distance d and height z is
    I * z / d^3; scaling by (d / height)^3 keeps the average image about as
    bright as the flash photo instead of darkening with far lights.

    Array-agnostic (numpy or torch): ``positions`` (..., K, 3) relative to
    the point below the camera, ``height`` broadcastable to (..., K).

    Args:
        positions: (..., K, 3) light positions.
        intensity: the flash's intensity (:data:`LIGHT_INTENSITY`).
        height: the camera's height, broadcastable to (..., K).

    Returns:
        (..., K) intensities.
    """
    d = ((positions * positions).sum(-1)) ** 0.5
    return intensity * (d / height) ** 3 * (height / positions[..., 2])
