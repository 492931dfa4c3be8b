"""svbrdf: single-image material capture for 3D artists (runtime; never imports torch)."""

__version__ = "0.1.0"
