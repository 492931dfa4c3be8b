"""preview.png: the photo, the maps and three relit renders."""

import numpy as np

from svbrdf_cli.write import preview


def test_preview_layout():
    stored = {"normal": np.broadcast_to(np.float32([0.5, 0.5, 1.0]), (64, 64, 3)).copy(),
              "diffuse": np.full((64, 64, 3), 0.5, np.float32), "roughness": np.full((64, 64, 1), 0.5, np.float32),
              "specular": np.full((64, 64, 3), 0.2, np.float32)}
    grid = preview.preview_image(np.full((64, 64, 3), 0.3, np.float32), stored, tile=128)
    assert grid.shape == (256, 512, 3) and np.isfinite(grid).all()
    # The flash render of a flat surface is brightest at its centre.
    flash = grid[128:, 128:256].mean(-1)
    assert flash[64, 64] > flash[5, 5]
