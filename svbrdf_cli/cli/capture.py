"""``svbrdf capture``: photos in, texture sets out (:func:`svbrdf_cli.run.batch.run_local`).

Exit codes: 0 all done, 1 some inputs failed, 2 usage errors (click's).
"""

import click

from svbrdf_cli.run.batch import collect_inputs, run_local
from svbrdf_cli.cli.options import capture_options, finish
from svbrdf_cli.cli.progress import TerminalReport


@click.command("capture")
@click.argument("inputs", nargs=-1, required=True, type=click.Path())
@capture_options
def capture_cmd(inputs, job):
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
    files, ignored = collect_inputs(inputs)
    if not files:
        raise click.UsageError("no photos found in " + ", ".join(f"'{p}'" for p in inputs) + ".")
    if job.opts.name and len(files) > 1:
        raise click.UsageError(f"--name names one material; {len(files)} photos were given.")
    with TerminalReport(job.quiet).lines_above_bars() as report:
        counts = run_local(files, job, report=report)
    finish(counts, ignored, job.quiet)
