"""The ``svbrdf`` command group: verbosity, version, error reporting, sub-commands."""

import contextlib
import logging
import signal
import threading

import click

from svbrdf_cli.version import __version__
from svbrdf_cli.cli.options import quiet_opt, set_verbosity, verbose_opt
from svbrdf_cli.ingest.decoder_output import guard_python_stderr
from svbrdf_cli.errors import SvbrdfError


@contextlib.contextmanager
def _signals_end_the_run():
    """SIGTERM and SIGHUP end the run as Ctrl-C does, through every clean-up on the way out (a set
    being written is finished or its temporary folder removed): exit 128 + the signal's number."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        raise SystemExit(128 + signum)

    previous = {s: signal.signal(s, stop) for s in (signal.SIGTERM, getattr(signal, "SIGHUP", None)) if s}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


class SvbrdfGroup(click.Group):
    """Turns library errors into one-line messages and exit code 1."""

    def main(self, *args, **kwargs):
        """Run the group with SIGTERM and SIGHUP ending the run cleanly and the decoders' stderr caught."""
        with _signals_end_the_run(), guard_python_stderr():  # (the decoders' fd 2 is caught: decoder_output)
            return super().main(*args, **kwargs)

    def invoke(self, ctx):
        """Run the command; a library error becomes one line and exit code 1."""
        try:
            return super().invoke(ctx)
        except SvbrdfError as e:
            logging.getLogger("svbrdf").debug("details", exc_info=True)
            raise click.ClickException(str(e)) from e


@click.group(cls=SvbrdfGroup, context_settings={"help_option_names": ["-h", "--help"]}, epilog="""\b
Examples:
  svbrdf capture photo.dng -o textures             one photo -> textures/photo/
  svbrdf batch shoot/ -o textures --preset unreal  a folder, resumable
  svbrdf export textures/photo -o photo_gltf --preset gltf
  svbrdf markers sheet.png                         a sheet for --crop markers
""")
@verbose_opt
@quiet_opt
@click.version_option(__version__, prog_name="svbrdf")
def cli(verbose, quiet):
    """Single-image material capture: flash photo in, PBR texture set out."""
    set_verbosity(quiet, verbose)


def _register():
    from svbrdf_cli.cli.batch import batch_cmd
    from svbrdf_cli.cli.capture import capture_cmd
    from svbrdf_cli.cli.export_set import export_cmd
    from svbrdf_cli.cli.markers import markers_cmd
    from svbrdf_cli.cli.render import render_cmd
    from svbrdf_cli.cli.view import view_cmd

    for cmd in (capture_cmd, batch_cmd, export_cmd, render_cmd, view_cmd, markers_cmd):
        cli.add_command(cmd)


_register()


if __name__ == "__main__":
    cli()
