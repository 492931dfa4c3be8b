"""The tool's version (``svbrdf --version``, ``material.json``, the glTF generator)."""

__version__ = "0.1.0"
