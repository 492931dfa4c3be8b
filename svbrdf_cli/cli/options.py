"""What the commands share: options (values parsed by :mod:`svbrdf_cli.cli.values`), verbosity, the
``capture``/``batch`` options (built once into a :class:`svbrdf_cli.run.batch.Job`) and the end-of-run
summary. Every choice and limit is the library's."""

import functools
import logging
import os
import sys

import click

from svbrdf_cli import conventions as cv
from svbrdf_cli.run.batch import Job
from svbrdf_cli.errors import OutputExistsError
from svbrdf_cli.infer.registry import DEFAULT_MODEL
from svbrdf_cli.cli.values import corners, exposure, light, model_help, model_value, numbers
from svbrdf_cli.run.pipeline import MAX_SIZE, MIN_SIZE, Options
from svbrdf_cli.infer.upsample import UPSAMPLE_METHODS
from svbrdf_cli.write.presets import FORMATS, PNG_BITS, PNG_ONLY_PRESETS, PRESETS
from svbrdf_cli.rectify.crops import CROP_MODES
from svbrdf_cli.infer.refine import DEFAULT_ITERATIONS, MAX_ITERATIONS


def set_verbosity(quiet=False, verbose=0):
    """Log level from -q/-v on the group or after the command (louder -v, any -q wins); returns quiet."""
    ctx = click.get_current_context()
    root = ctx.find_root().ensure_object(dict)
    quiet = root["quiet"] = quiet or root.get("quiet", False)
    verbose = root["verbose"] = max(verbose, root.get("verbose", 0))
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    logging.basicConfig(format="%(levelname)s: %(message)s", stream=sys.stderr)
    logging.getLogger().setLevel(level)
    logging.captureWarnings(True)  # Python's warnings as WARNING lines: none under -q
    return quiet


quiet_opt = click.option("-q", "--quiet", is_flag=True, help="Only errors.")
verbose_opt = click.option("-v", "--verbose", count=True, help="More log output (repeat for more).")
light_opt = click.option(
    "--light", callback=light, default=None, metavar="X,Y,Z",
    help="Light position in surface units (the surface spans -1..1; default: the flash, "
         f"{','.join(f'{v:g}' for v in (0, 0, round(cv.CAMERA_HEIGHT, 3)))}).")


def bits_opt(help="PNG bit depth."):
    """The ``--bits`` option (8 or 16-bit PNG)."""
    return click.option("--bits", type=click.Choice([str(b) for b in PNG_BITS]), default=str(PNG_BITS[0]),
                        show_default=True, help=help)


def format_opt(help="File format of data maps (presets other than svbrdf and gltf)."):
    """The ``--format`` option (PNG or EXR data maps)."""
    return click.option("--format", "fmt", type=click.Choice(FORMATS), default=FORMATS[0], show_default=True,
                        help=help)


def force_opt(what):
    """``--force``: replace ``what``; ``--overwrite`` is kept as a hidden alias."""
    def deco(f):
        f = click.option("--overwrite", "force", is_flag=True, hidden=True)(f)
        return click.option("--force", "force", is_flag=True, help=f"Replace {what}.")(f)
    return deco


def refuse_existing(path, force):
    """A file output that exists is replaced only with --force (a file error, exit 1, otherwise)."""
    if os.path.exists(path) and not force:
        raise OutputExistsError(f"'{path}' exists; use --force to replace it.")


def check_format(preset, fmt):
    """Refuse ``--format exr`` for a preset that writes PNG only (a usage error)."""
    if fmt != "png" and preset in PNG_ONLY_PRESETS:
        raise click.UsageError(f"The {preset} preset writes PNG only; drop --format {fmt}.")


_CAPTURE_OPTIONS = [
    click.option("-o", "--output", required=True, type=click.Path(file_okay=False),
                 help="Folder for the texture sets: one sub-folder per photo, named after it."),
    click.option("--model", default=DEFAULT_MODEL, show_default=True, callback=model_value,
                 help=model_help()),
    click.option("--preset", type=click.Choice(list(PRESETS)), default="svbrdf", show_default=True,
                 help="Texture-set layout (see 'svbrdf export --help')."),
    click.option("--crop", type=click.Choice(CROP_MODES), default=CROP_MODES[0], show_default=True,
                 help="auto: largest square around the flash highlight; markers: rectify the window of the "
                      "sheet from 'svbrdf markers'; none: the photo as it is."),
    click.option("--corners", callback=corners, default=None, metavar="X1,Y1,...,X4,Y4",
                 help="Rectify this quadrilateral (pixels of the oriented photo, any order); overrides --crop."),
    click.option("--size", type=click.IntRange(MIN_SIZE, MAX_SIZE), default=None,
                 help=f"Output map size in pixels ({MIN_SIZE}-{MAX_SIZE}; default: the largest power of two within "
                      "the crop's side, 256-1024; above the crop's side, a warning)."),
    click.option("--exposure", callback=exposure, default="auto", show_default=True, metavar="auto|STOPS",
                 help="auto: expose as the networks were trained; or stops to add to the photo as shot."),
    click.option("--white-balance", "white_balance", callback=numbers(3, "R,G,B multipliers", True),
                 default=None, metavar="R,G,B",
                 help="Multipliers for the linear photo (after the camera's white balance for RAW)."),
    click.option("--upsample", type=click.Choice(UPSAMPLE_METHODS), default=UPSAMPLE_METHODS[0], show_default=True,
                 help="How maps reach --size from the networks' 256 px."),
    bits_opt(), format_opt(),
    click.option("--debug", is_flag=True, help="Also write debug/: network input, masks, auxiliary renderings."),
    click.option("--confidence", is_flag=True, help="Also write confidence/<map>.png: white where a map can be trusted. "
                 "Physical estimate: diffuse where the photo is not clipped, swamped by the highlight, too dark or far "
                 "from the flash; roughness where the highlight shows; none for its assumed normal and specular. "
                 "A network: where its maps of 5 rotated and mirrored copies agree (it runs 5 times)."),
    click.option("--no-preview", is_flag=True, help="Skip preview.png."),
    click.option("--no-ao", is_flag=True, help="Constant ambient occlusion (1) instead of one from the height."),
    click.option("--tileable", is_flag=True, help="Seamless maps: every map cross-faded, one axis at a time, with a "
                                                  "copy of itself shifted in step with its pattern (a regular pattern "
                                                  "first cut to whole repeats), so a tiling shows no seam."),
    click.option("--refine", type=click.IntRange(0, MAX_ITERATIONS), default=DEFAULT_ITERATIONS, show_default=True,
                 is_flag=False, flag_value=DEFAULT_ITERATIONS, metavar="[N]",
                 help="Steps fitting the maps to the photo under its own flash (about 0.6 s; 0: off, the "
                      "model's maps as they are). See docs/capture.md."),
    click.option("--threads", type=click.IntRange(0, 256), default=0, help="onnxruntime threads (0: one per core)."),
    force_opt("existing texture sets (redo them)"),
    click.option("--name", default=None, help="The material's name in Unreal, Unity and Blender file names "
                                              "(T_<NAME>_BC.png ...; default: the photo's name)."),
    quiet_opt, verbose_opt,
]


def capture_options(f):
    """The options ``capture`` and ``batch`` share, handed to the command as one ``job``
    (:class:`svbrdf_cli.run.batch.Job`); verbosity is set before the command runs."""
    @functools.wraps(f)
    def command(*args, output, model, preset, crop, corners, size, exposure, white_balance, upsample, bits, fmt,
                debug, confidence, no_preview, no_ao, tileable, refine, threads, force, name, quiet, verbose, **kwargs):
        check_format(preset, fmt)
        opts = Options(preset=preset, crop=crop, corners=corners, size=size, exposure=exposure,
                       white_balance=white_balance, upsample=upsample, bits=int(bits), fmt=fmt, debug=debug,
                       confidence=confidence, preview=not no_preview, force=force, name=name, tileable=tileable,
                       ao=not no_ao, refine=refine)
        job = Job(output=output, opts=opts, model=model, threads=threads, quiet=set_verbosity(quiet, verbose))
        return f(*args, job=job, **kwargs)

    for o in reversed(_CAPTURE_OPTIONS):
        command = o(command)
    return command


def finish(counts, ignored, quiet):
    """Print the end-of-run summary and exit: 0 when nothing failed, else 1."""
    done, skipped, failed = counts
    if not quiet:
        parts = [f"{done} done"] + ([f"{skipped} already done"] if skipped else []) + \
                ([f"{failed} failed"] if failed else []) + ([f"{ignored} non-photo files ignored"] if ignored else [])
        click.echo(", ".join(parts), err=True)
    sys.exit(1 if failed else 0)
