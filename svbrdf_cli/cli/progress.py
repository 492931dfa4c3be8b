"""What a run shows on the terminal: error lines, one line per set, the progress bars.

The library reports through :class:`svbrdf_cli.run.batch.Report`; this is the command line's. Lines go
to stderr above the bars, which are drawn only on a terminal (a log file gets the lines alone).
"""

import contextlib
import logging
import sys

from svbrdf_cli.run.batch import Report


class TerminalReport(Report):
    """Error lines always; with ``quiet`` no set lines and no bars."""

    def __init__(self, quiet=False):
        self.quiet = quiet
        self.bar = self.refine_bar = None

    @contextlib.contextmanager
    def lines_above_bars(self):
        """Log lines written above the bars while the run lasts, never inside them."""
        from tqdm.contrib.logging import logging_redirect_tqdm

        with logging_redirect_tqdm():
            yield self

    def _write(self, line):
        from tqdm import tqdm

        tqdm.write(line, file=sys.stderr)

    def start(self, total):
        """Draw the photos' bar (on a terminal, for two photos or more, unless quiet)."""
        from tqdm import tqdm

        self.bar = tqdm(total=total, unit="photo", file=sys.stderr, dynamic_ncols=True,
                        disable=self.quiet or total < 2 or not sys.stderr.isatty())

    def failed(self, message):
        """Write the error line above the bars."""
        self._write(f"error: {message}")

    def converted(self, photo, folder, record, seconds):
        """Write the set's line (unless quiet)."""
        if not self.quiet:
            crop = record["crop"]
            how = crop["mode"] + (f" on the {crop['anchor']}" if crop.get("anchor") else "")
            self._write(f"{photo} -> {folder} ({record['size']}x{record['size']}, crop {how}, {seconds:.1f} s)")

    def warned(self, photo, message):
        """Write the warning line under the photo's own line."""
        self._write(f"warning: {message}")

    def advanced(self):
        """Advance the photos' bar."""
        if self.bar is not None:
            self.bar.update(1)

    def refine_step(self, done, total):
        """Advance the ``--refine`` bar (drawn on a terminal when warnings show)."""
        from tqdm import tqdm

        if self.refine_bar is None:
            self.refine_bar = tqdm(total=total, unit="step", desc="refine", leave=False, file=sys.stderr,
                                   dynamic_ncols=True, disable=not (sys.stderr.isatty()
                                                                    and logging.getLogger().isEnabledFor(logging.WARNING)))
        self.refine_bar.update(1)
        if done >= total:
            self.refine_bar.close()
            self.refine_bar = None

    def finish(self):
        """Close the bars."""
        for bar in (self.refine_bar, self.bar):
            if bar is not None:
                bar.close()
        self.bar = self.refine_bar = None
