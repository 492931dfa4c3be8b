"""Where the shared reference data is, atomic file writes, and error reporting, for every export command."""

from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
from pathlib import Path

from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli.imageio import umask


def shared_root() -> Path:
    """``$SVBRDF_SHARED``, else ``../shared`` beside the checkout (the rule of ``tests/conftest.py``)."""
    return Path(os.environ.get("SVBRDF_SHARED", Path(__file__).resolve().parents[1].parent / "shared"))


def shared_data(folder=None) -> str:
    """The shared data folder (holding ``materials/``, ``real/``, ``validation/``):
    ``folder`` when given, else ``<shared_root>/data``."""
    return str(folder or shared_root() / "data")


def atomic_write(path, data: bytes):
    """Write ``data`` to ``path`` through a temporary sibling and a rename: never half-written."""
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(os.fspath(path)) or ".", suffix=".part")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o666 & ~umask())  # mkstemp makes it 0600
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_torch_save(obj, path):
    import torch

    buf = io.BytesIO()
    torch.save(obj, buf)
    atomic_write(path, buf.getvalue())


def read_json(path):
    """The JSON object in ``path``, or {} when there is no such file."""
    if os.path.exists(path):
        with open(path) as f:
            return json.load(f)
    return {}


def write_json(path, data):
    atomic_write(path, json.dumps(data, indent=1).encode())


@contextlib.contextmanager
def command_errors():
    """For a ``python -m export...`` command: the library's :class:`SvbrdfError` as a one-line click error
    (library functions never raise click's exceptions)."""
    import click

    try:
        yield
    except SvbrdfError as e:
        raise click.ClickException(str(e)) from e


#: The real benchmark photos (every n-th of the sorted list, so each collection is represented).
REAL_PHOTOS = 12


def real_photos(real_root, count=REAL_PHOTOS):
    """Up to ``count`` real photos, spread over the sorted list of ``real_root``'s photos."""
    files = sorted(os.path.join(d, f) for d, _, fs in os.walk(real_root) for f in fs
                   if f.lower().endswith((".jpg", ".jpeg", ".png")) and not f.startswith("paper_")
                   and "reference_maps" not in d)
    step = max(1, len(files) // count) if files else 1
    return files[::step][:count]
