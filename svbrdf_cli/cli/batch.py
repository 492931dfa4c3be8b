"""``svbrdf batch``: a folder of photos, resumable, here or on a Ray cluster."""


import click

from svbrdf_cli.run.batch import PHOTO_EXTENSIONS, collect_inputs, run_local
from svbrdf_cli.cli.options import capture_options, finish
from svbrdf_cli.cli.progress import TerminalReport
from svbrdf_cli.write.gallery import GALLERY, write_gallery
from svbrdf_cli.run.ray_engine import is_uri

ENGINES = ("local", "ray")


@click.command("batch")
@click.argument("folder", type=click.Path(exists=True, file_okay=False))
@capture_options
@click.option("--engine", type=click.Choice(ENGINES), default=ENGINES[0], show_default=True,
              help="local: this process; ray: a Ray cluster (pip install 'svbrdf[scale]'; see docs/scale.md).")
@click.option("--address", default=None, help="Ray cluster address (default: $RAY_ADDRESS, else a local Ray).")
@click.option("--workers", type=click.IntRange(1, 100000), default=None,
              help="Ray workers, each with its own model (default: one per --threads CPUs of the cluster).")
def batch_cmd(folder, job, engine, address, workers):
    """Convert every photo in FOLDER; rerun to resume.

    Photos whose texture set is already complete in OUTPUT, made with the same
    options, are skipped (so an interrupted batch resumes where it stopped);
    sets made with other options (--preset, --size, ...) are redone, and
    --force redoes them all. Sets are
    written whole or not at all, a bad photo is reported and skipped, and the
    exit code is 1 if any photo failed. OUTPUT/index.html shows every set in
    the folder (photo, maps, preview) and this run's failures.

    \b
    Examples:
      svbrdf batch shoot_2026-11-20/ -o textures
      svbrdf batch shoot/ -o textures_ue --preset unreal --size 2048 -q
      svbrdf batch /mnt/shoot -o s3://studio/textures --engine ray --address ray://head:10001
    """
    if job.opts.name:
        raise click.UsageError("--name names one material; a batch names each set after its photo.")
    job.skip_done = True
    job.reserved = (GALLERY,)
    files, ignored = collect_inputs([folder])
    if not files:
        raise click.UsageError(f"no photos in '{folder}' (looked for {', '.join(sorted(PHOTO_EXTENSIONS))} and RAW files).")
    failures = []
    report = TerminalReport(job.quiet)
    if engine == "ray":
        from svbrdf_cli.run.ray_engine import run_ray

        def err(msg):
            report.failed(msg)
            failures.append(msg)

        counts = run_ray(files, job, address=address, workers=workers, err=err)
    elif is_uri(job.output):
        raise click.UsageError(f"'{job.output}' is a URI: use --engine ray, or a local folder.")
    else:
        with report.lines_above_bars():
            counts = run_local(files, job, failures, report)
    if not is_uri(job.output):
        write_gallery(job.output, failures)  # index.html: every set in the folder, this run's failures
    finish(counts, ignored, job.quiet)
