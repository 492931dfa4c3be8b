"""``preview.png``: the photo, the four maps and three relit renders on one sheet."""

from __future__ import annotations

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.imageops import resize
from svbrdf_cli.shading import render_maps
from svbrdf_cli.write.mapset import stored_to_linear

#: Lights of the preview's relit renders (surface units; the surface spans -1..1).
PREVIEW_LIGHTS = {"flash": cv.FLASH_POSITION, "left": (-2.0, 0.5, 1.2), "top right": (1.5, 1.5, 1.5)}


def preview_image(network_input, stored, tile=256):
    """4 x 2 grid: photo, normal, diffuse, roughness / specular and three relit renders."""
    import cv2

    small = {k: resize(v, tile) for k, v in stored.items()}
    lin = stored_to_linear(small)
    tiles = [("photo", resize(network_input, tile)), ("normal", small["normal"]), ("diffuse", small["diffuse"]),
             ("roughness", np.repeat(small["roughness"][..., :1], 3, -1)), ("specular", small["specular"])]
    for name, light in PREVIEW_LIGHTS.items():
        img = render_maps(lin, light=light)  # float32: the preview within 1/255 of float64, in 60% of its time
        tiles.append((f"relit: {name}", cv.image_to_encoded(img).astype(np.float32)))
    grid = np.zeros((2 * tile, 4 * tile, 3), np.float32)
    for i, (name, img) in enumerate(tiles):
        r, c = divmod(i, 4)
        t = np.ascontiguousarray((img.clip(0, 1) * 255 + 0.5).astype(np.uint8))
        t[-20:] = t[-20:] // 3  # a dark band under the label
        cv2.putText(t, name, (5, tile - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        grid[r * tile:(r + 1) * tile, c * tile:(c + 1) * tile] = t / np.float32(255)
    return grid
