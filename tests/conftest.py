"""Shared fixtures. Tests that read ``../shared`` skip cleanly when it is absent."""

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SHARED = Path(os.environ.get("SVBRDF_SHARED", ROOT.parent / "shared"))
DATA = Path(__file__).resolve().parent / "data"


@pytest.fixture
def shared_data():
    """``../shared/data``, or skip."""
    path = SHARED / "data"
    if not path.is_dir():
        pytest.skip("../shared/data is not present (a user's fresh clone)")
    return path


@pytest.fixture
def golden():
    import numpy as np

    return dict(np.load(DATA / "brdf_golden.npz"))
