"""``svbrdf capture`` and ``svbrdf batch``: photos in, texture sets out.

Both run the same loop (:func:`run_inputs`): each photo is read, cropped and
exposed while the previous one is in the networks, written as one atomic set,
and a bad photo is reported in one line and skipped. Exit codes: 0 all done,
1 some inputs failed, 2 usage errors (click's).
"""

from __future__ import annotations

import concurrent.futures
import logging
import os
import sys
import time

import click

from svbrdf_cli.inference import DEFAULT_MODEL
from svbrdf_cli.presets import PRESETS

log = logging.getLogger("svbrdf")

#: Files a folder input contributes (others are ignored, with a count).
PHOTO_EXTENSIONS = frozenset(".jpg .jpeg .png .tif .tiff .exr .heic .webp".split())


def _photo_extensions():
    from svbrdf_cli.ingest import RAW_EXTENSIONS

    return PHOTO_EXTENSIONS | RAW_EXTENSIONS


def _numbers(ctx, param, value, count, what):
    if value is None:
        return None
    try:
        parts = tuple(float(x) for x in value.split(","))
    except ValueError:
        parts = ()
    if len(parts) != count:
        raise click.BadParameter(f"expected {count} comma-separated numbers ({what}); got '{value}'.")
    return parts


def _corners(ctx, param, value):
    parts = _numbers(ctx, param, value, 8, "x1,y1,...,x4,y4 in pixels")
    return None if parts is None else tuple(zip(parts[0::2], parts[1::2]))


def _wb(ctx, param, value):
    parts = _numbers(ctx, param, value, 3, "R,G,B multipliers")
    if parts is not None and min(parts) <= 0:
        raise click.BadParameter("multipliers must be positive.")
    return parts


def _exposure(ctx, param, value):
    if value is None or value == "auto":
        return None
    try:
        return float(value)
    except ValueError:
        raise click.BadParameter(f"expected 'auto' or a number of stops; got '{value}'.") from None


def capture_options(f):
    """The options ``capture`` and ``batch`` share."""
    opts = [
        click.option("-o", "--output", required=True, type=click.Path(file_okay=False),
                     help="Folder for the texture sets: one sub-folder per photo, named after it."),
        click.option("--model", default=DEFAULT_MODEL, show_default=True,
                     help="'physical' (the maps computed from the flash physics: today's most accurate), a "
                          "network tier (lite, fast, balanced, best), 'auto' (per photo, the cheapest tier "
                          "good enough for it) or a folder of exported models."),
        click.option("--preset", type=click.Choice(list(PRESETS)), default="svbrdf", show_default=True,
                     help="Texture-set layout (see 'svbrdf export --help')."),
        click.option("--crop", type=click.Choice(["auto", "markers", "none"]), default="auto", show_default=True,
                     help="auto: largest square around the flash highlight; markers: rectify the window of "
                          "the sheet from 'svbrdf markers'; none: the photo as it is."),
        click.option("--corners", callback=_corners, default=None, metavar="X1,Y1,...,X4,Y4",
                     help="Rectify this quadrilateral (pixels of the oriented photo, any order); overrides --crop."),
        click.option("--size", type=click.IntRange(256, 4096), default=None,
                     help="Output map size in pixels (256-4096; default: the crop's, at most 1024)."),
        click.option("--exposure", callback=_exposure, default="auto", show_default=True, metavar="auto|STOPS",
                     help="auto: expose as the networks were trained; or stops to add to the photo as shot."),
        click.option("--white-balance", "white_balance", callback=_wb, default=None, metavar="R,G,B",
                     help="Multipliers for the linear photo (after the camera's white balance for RAW)."),
        click.option("--upsample", type=click.Choice(["guided", "bicubic"]), default="guided", show_default=True,
                     help="How maps reach --size from the networks' 256 px."),
        click.option("--bits", type=click.Choice(["8", "16"]), default="8", show_default=True, help="PNG bit depth."),
        click.option("--format", "fmt", type=click.Choice(["png", "exr"]), default="png", show_default=True,
                     help="File format of data maps (presets other than svbrdf and gltf)."),
        click.option("--debug", is_flag=True, help="Also write debug/: network input, masks, auxiliary renderings."),
        click.option("--confidence", is_flag=True,
                     help="Also write confidence/<map>.png: where the maps of rotated and mirrored copies of "
                          "the photo agree (white) or not (dark). Runs the networks 5 times."),
        click.option("--no-preview", is_flag=True, help="Skip preview.png."),
        click.option("--threads", type=click.IntRange(0, 256), default=0,
                     help="onnxruntime threads (0: one per core)."),
        click.option("--force", is_flag=True, help="Redo and replace existing texture sets."),
        click.option("-q", "--quiet", is_flag=True, help="Only errors (same as 'svbrdf -q')."),
        click.option("-v", "--verbose", count=True, help="More log output (same as 'svbrdf -v')."),
    ]
    for o in reversed(opts):
        f = o(f)
    return f


def collect_inputs(paths):
    """Files given, and the photos directly inside folders given (sorted); (inputs, ignored count)."""
    exts = _photo_extensions()
    files, ignored = [], 0
    for p in paths:
        if os.path.isdir(p):
            for name in sorted(os.listdir(p)):
                full = os.path.join(p, name)
                if name.startswith(".") or not os.path.isfile(full):
                    continue
                if os.path.splitext(name)[1].lower() in exts:
                    files.append(full)
                else:
                    ignored += 1
        else:
            files.append(p)  # named explicitly: tried whatever its extension, errors reported per file
    return files, ignored


def _clean_partials(out):
    """Remove temporary folders an interrupted run (killed mid-write) left in ``out``."""
    import shutil

    if not os.path.isdir(out):
        return
    for name in os.listdir(out):
        if name.startswith(".") and (name.endswith(".partial") or name.endswith(".old")):
            shutil.rmtree(os.path.join(out, name), ignore_errors=True)


def plan_inputs(files, output, opts, skip_done, err, store=None):
    """Which inputs to run: (todo, skipped count, failed count), errors reported through ``err``.

    Two inputs with the same stem (photo.jpg, photo.dng) would write the same
    folder: the second fails. An existing set is skipped when complete and
    ``skip_done`` (batch), else it fails unless ``opts.force``. ``store``
    answers ``exists(stem)`` and ``complete(stem)`` (default: local folders).
    """
    from svbrdf_cli import capture as C

    seen, todo, failed, skipped = {}, [], 0, 0
    for f in files:
        folder = C.output_folder(output, f)
        stem = os.path.basename(folder)
        if folder in seen:
            err(f"'{f}' would write to '{folder}' like '{seen[folder]}'; rename one of them.")
            failed += 1
            continue
        seen[folder] = f
        exists = store.exists(stem) if store else os.path.exists(folder)
        if exists and not opts.force:
            if skip_done and (store.complete(stem) if store else C.is_complete(folder)):
                log.info("skip %s: %s is complete", f, folder)
                skipped += 1
                continue
            err(f"'{folder}' already exists (from '{f}'); use --force to replace it.")
            failed += 1
            continue
        todo.append(f)
    return todo, skipped, failed


def describe_failure(f, e):
    """One line for an exception raised while converting ``f``."""
    from svbrdf_cli.errors import SvbrdfError

    if isinstance(e, SvbrdfError):
        return str(e)
    if isinstance(e, MemoryError):
        return f"'{f}': out of memory; use a smaller --size or downscale the photo."
    first = (str(e).strip().splitlines() or [""])[0]
    return f"'{f}': unexpected {type(e).__name__}: {first} (rerun with -vv for details; please report it)."


def run_inputs(files, output, opts, model, threads, skip_done, quiet):
    """The shared local loop; returns (done, skipped, failed) counts."""
    from tqdm import tqdm

    from svbrdf_cli import capture as C
    from svbrdf_cli.inference import load_model

    def err(msg):
        tqdm.write(f"error: {msg}", file=sys.stderr)  # above the progress bar, never inside it

    todo, skipped, failed = plan_inputs(files, output, opts, skip_done, err)
    if not todo:
        return 0, skipped, failed

    chain = load_model(model, threads=threads)
    _clean_partials(output)
    done = 0
    bar = tqdm(total=len(todo), unit="photo", disable=quiet or len(todo) < 2, file=sys.stderr, dynamic_ncols=True)

    def report_failure(f, e):
        log.debug("details", exc_info=e)
        err(describe_failure(f, e))

    # Read and crop the next photo while the current one is in the networks.
    with concurrent.futures.ThreadPoolExecutor(max_workers=1) as pool:
        pending = pool.submit(C.prepare, todo[0], opts)
        for i, f in enumerate(todo):
            t0 = time.perf_counter()
            try:
                prepared = pending.result()
            except Exception as e:  # noqa: BLE001 - one bad photo never stops a batch
                prepared = None
                report_failure(f, e)
            if i + 1 < len(todo):
                pending = pool.submit(C.prepare, todo[i + 1], opts)
            if prepared is not None:
                try:
                    folder, record = C.capture(prepared, chain, output, opts, model_name=model)
                    done += 1
                    crop = record["crop"]
                    how = crop["mode"] + (f" on the {crop['anchor']}" if crop.get("anchor") else "")
                    msg = (f"{f} -> {folder} ({record['size']}x{record['size']}, crop {how}, "
                           f"{time.perf_counter() - t0:.1f} s)")
                    if not quiet:
                        tqdm.write(msg, file=sys.stderr)
                except Exception as e:  # noqa: BLE001
                    report_failure(f, e)
            bar.update(1)
    bar.close()
    return done, skipped, len(todo) - done + failed


def _finish(done, skipped, failed, ignored, quiet):
    if not quiet:
        parts = [f"{done} done"] + ([f"{skipped} already done"] if skipped else []) + \
                ([f"{failed} failed"] if failed else []) + ([f"{ignored} non-photo files ignored"] if ignored else [])
        click.echo(", ".join(parts), err=True)
    sys.exit(1 if failed else 0)


def _quiet(ctx, quiet, verbose):
    """-q/-v given after the sub-command work like the group's."""
    quiet = quiet or ctx.obj.get("quiet", False)
    verbose = max(verbose, ctx.obj.get("verbose", 0))
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    logging.getLogger().setLevel(level)
    return quiet


def _options(preset, crop, corners, size, exposure, white_balance, upsample, bits, fmt, debug, confidence, no_preview,
             force):
    from svbrdf_cli.capture import Options
    from svbrdf_cli.presets import PNG_ONLY_PRESETS

    if fmt != "png" and preset in PNG_ONLY_PRESETS:
        raise click.UsageError(f"The {preset} preset writes PNG only; drop --format {fmt}.")
    return Options(preset=preset, crop=crop, corners=corners, size=size, exposure=exposure,
                   white_balance=white_balance, upsample=upsample, bits=int(bits), fmt=fmt, debug=debug,
                   confidence=confidence, preview=not no_preview, force=force)


@click.command("capture")
@click.argument("inputs", nargs=-1, required=True, type=click.Path())
@capture_options
@click.pass_context
def capture_cmd(ctx, inputs, output, model, preset, crop, corners, size, exposure, white_balance, upsample,
                bits, fmt, debug, confidence, no_preview, threads, force, quiet, verbose):
    """Turn flash photos into PBR texture sets.

    INPUTS are photos (JPEG, PNG, TIFF, EXR, camera RAW such as DNG, NEF, CR2,
    ARW) or folders of them. Each photo becomes OUTPUT/<photo name>/ with the
    preset's maps, material.json (crop, exposure, model, timings) and
    preview.png (the maps and three relit renders). Take the photo with the
    flash on, square to the surface, from 20-50 cm.

    \b
    Examples:
      svbrdf capture wood.dng -o textures
      svbrdf capture shots/ -o textures --preset unreal --size 2048
      svbrdf capture tiles.jpg -o textures --crop markers --preset gltf
      svbrdf capture leather.jpg -o textures --corners 410,220,1630,250,1600,1480,380,1450
    """
    opts = _options(preset, crop, corners, size, exposure, white_balance, upsample, bits, fmt, debug, confidence,
                    no_preview, force)
    files, ignored = collect_inputs(inputs)
    if not files:
        raise click.UsageError("no photos found in " + ", ".join(f"'{p}'" for p in inputs) + ".")
    quiet = _quiet(ctx, quiet, verbose)
    _finish(*run_inputs(files, output, opts, model, threads, skip_done=False, quiet=quiet), ignored, quiet)


@click.command("batch")
@click.argument("folder", type=click.Path(exists=True, file_okay=False))
@capture_options
@click.option("--engine", type=click.Choice(["local", "ray"]), default="local", show_default=True,
              help="local: this process; ray: a Ray cluster (pip install 'svbrdf[scale]'; see docs/scale.md).")
@click.option("--address", default=None, help="Ray cluster address (default: $RAY_ADDRESS, else a local Ray).")
@click.option("--workers", type=click.IntRange(1, 100000), default=None,
              help="Ray workers, each with its own model (default: one per --threads CPUs of the cluster).")
@click.pass_context
def batch_cmd(ctx, folder, output, model, preset, crop, corners, size, exposure, white_balance, upsample,
              bits, fmt, debug, confidence, no_preview, threads, force, quiet, verbose, engine, address, workers):
    """Convert every photo in FOLDER; rerun to resume.

    Photos whose texture set is already complete in OUTPUT are skipped (so an
    interrupted batch resumes where it stopped; --force redoes them). Sets are
    written whole or not at all, a bad photo is reported and skipped, and the
    exit code is 1 if any photo failed.

    \b
    Examples:
      svbrdf batch shoot_2026-11-20/ -o textures
      svbrdf batch shoot/ -o textures_ue --preset unreal --size 2048 -q
      svbrdf batch /mnt/shoot -o s3://studio/textures --engine ray --address ray://head:10001
    """
    opts = _options(preset, crop, corners, size, exposure, white_balance, upsample, bits, fmt, debug, confidence,
                    no_preview, force)
    files, ignored = collect_inputs([folder])
    quiet = _quiet(ctx, quiet, verbose)
    if not files:
        raise click.UsageError(f"no photos in '{folder}' (looked for {', '.join(sorted(PHOTO_EXTENSIONS))} and RAW files).")
    if engine == "ray":
        from tqdm import tqdm

        from svbrdf_cli.scale import run_ray

        counts = run_ray(files, output, opts, model, address=address, workers=workers,
                         threads_per_worker=threads or 1, quiet=quiet,
                         err=lambda m: tqdm.write(f"error: {m}", file=sys.stderr))
        _finish(*counts, ignored, quiet)
    if "://" in output:
        raise click.UsageError(f"'{output}' is a URI: use --engine ray, or a local folder.")
    _finish(*run_inputs(files, output, opts, model, threads, skip_done=True, quiet=quiet), ignored, quiet)


@click.command("markers")
@click.argument("output", type=click.Path(dir_okay=False))
@click.option("--cell", type=click.IntRange(24, 1000), default=96, show_default=True,
              help="Pixels per grid cell (the sheet is 11 cells wide).")
@click.option("--overwrite", is_flag=True, help="Replace an existing file.")
def markers_cmd(output, cell, overwrite):
    """Write the marker sheet for --crop markers (print it, cut out the window).

    A ring of 16 AprilTag 36h11 tags around a square window. Lay the sheet on
    the material, photograph it whole with the flash on, and run
    'svbrdf capture photo.jpg --crop markers': the window is found and
    rectified to a square, however the phone was tilted.

    \b
    Example:
      svbrdf markers sheet.png && svbrdf capture shot.jpg -o out --crop markers
    """
    import numpy as np

    from svbrdf_cli.imageio import write_image
    from svbrdf_cli.rectify import marker_sheet

    if os.path.exists(output) and not overwrite:
        raise click.UsageError(f"'{output}' exists; use --overwrite to replace it.")
    sheet = marker_sheet(cell)
    write_image(output, sheet.astype(np.float32) / 255.0)
    click.echo(f"wrote {output} ({sheet.shape[1]}x{sheet.shape[0]}; print at any size, keep it flat)", err=True)
