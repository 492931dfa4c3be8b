"""What the CLI tests share: the bundled sample, a small flash-like photo, and running a command."""

import os

import numpy as np
from click.testing import CliRunner

from svbrdf_cli.cli.main import cli
from svbrdf_cli.imageio import write_image

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
SAMPLE = os.path.join(ROOT, "examples", "glazed_tiles.jpg")


def run(*args):
    r = CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)
    return r.exit_code, r.output


def make_photo(path, h=300, w=400, seed=0, **kw):
    """A small flash-like photo (sRGB file)."""
    y, x = np.mgrid[0:h, 0:w]
    rng = np.random.default_rng(seed)
    base = rng.uniform(0.2, 0.5, 3) * (0.8 + 0.2 * np.sin(x / 7.0)[..., None])
    hl = np.exp(-((x - w / 2) ** 2 + (y - h / 2) ** 2) / (2 * 30.0 ** 2))[..., None]
    write_image(path, np.clip(base + 0.6 * hl, 0, 1).astype(np.float32), **kw)
    return path

