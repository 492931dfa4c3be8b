"""Errors the library raises; the CLI turns them into one-line messages (no click here).

Each message names the object, says what was observed and what to try.
"""


class SvbrdfError(Exception):
    """Base class of every expected failure."""


class ImageReadError(SvbrdfError):
    """An input image is missing or cannot be decoded."""


class ImageWriteError(SvbrdfError):
    """An output image cannot be written."""


class MapSetError(SvbrdfError):
    """A folder does not hold a complete, consistent SVBRDF map set."""


class OutputExistsError(SvbrdfError):
    """The output already exists and replacing it was not asked for (``--force``)."""
