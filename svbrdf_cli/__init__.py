"""svbrdf: single-image material capture for 3D artists (runtime; never imports torch).

The library in three calls, what ``svbrdf capture`` and ``svbrdf export`` do::

    import svbrdf_cli

    model = svbrdf_cli.load_model("physical")          # or "auto", or a folder of exported models
    folder, record = svbrdf_cli.capture("photo.jpg", "textures", model=model, preset="gltf")
    maps = svbrdf_cli.read_map_set(folder)
    svbrdf_cli.write_preset("unreal", "textures_ue/photo", maps)

A capture runs the stages in order: :mod:`svbrdf_cli.ingest` (the photo read once: pixels, EXIF,
hash), :mod:`svbrdf_cli.rectify` (the square crop), :mod:`svbrdf_cli.infer` (the model, the fit to
the photo, the output size), :mod:`svbrdf_cli.write` (the preset's files, atomically);
:mod:`svbrdf_cli.run` runs them for one photo, a folder or a cluster, and :mod:`svbrdf_cli.cli` is
the command line over it.
"""

from svbrdf_cli.infer.registry import DEFAULT_MODEL, load_model
from svbrdf_cli.run import pipeline
from svbrdf_cli.version import __version__
from svbrdf_cli.write.mapset import read_map_set
from svbrdf_cli.write.presets import write_preset

__all__ = ["__version__", "capture", "load_model", "read_map_set", "write_preset"]


def capture(photo, out, model=DEFAULT_MODEL, progress=None, **options):
    """One photo to a texture set in ``out/<photo name>/``.

    Args:
        photo: the photo's path (JPEG, PNG, TIFF, EXR or camera RAW).
        out: the folder the set's folder is made in.
        model: a ``--model`` name, or a model :func:`load_model` made (load it once for many photos).
        progress: optional callable ``progress(done, total)``, called after each step of the fit to
            the photo (``--refine``).
        **options: :class:`svbrdf_cli.run.pipeline.Options` fields (``preset``, ``size``, ``crop``,
            ``refine``, ``force``...).

    Returns:
        (the set's folder, its ``material.json`` record as a dict).

    Raises:
        svbrdf_cli.errors.SvbrdfError: with a one-line message naming the file and the fix.
    """
    opts = pipeline.Options(**options)
    chain = load_model(model) if isinstance(model, str) else model
    name = model if isinstance(model, str) else chain.describe().get("tier", "custom")
    return pipeline.capture(pipeline.prepare(photo, opts), chain, out, opts, model_name=name, progress=progress)
