"""The batch engine: photos in, texture sets out, one bad photo never stopping the rest.

``svbrdf capture`` and ``svbrdf batch`` (local engine) run :func:`run_local`; the Ray engine
(:mod:`svbrdf_cli.run.ray_engine`) plans its work with the same :func:`plan_inputs` and reports
failures with the same :func:`describe_failure`. Each photo is read, cropped and exposed while the
previous one is in the model, and written as one atomic set (:func:`svbrdf_cli.run.pipeline.infer_set`)
on a thread of its own while the next one is in the model; a bad photo is reported in one line
and skipped. The warnings a photo raises, on whichever thread, are collected (:func:`collect_warnings`)
and reported with that photo's own line (:meth:`Report.warned`), naming it.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import logging
import os
import threading
import time
from typing import NamedTuple

from svbrdf_cli.run import pipeline
from svbrdf_cli.write import ownership
from svbrdf_cli.write.atomic import clean_partials
from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli.infer.registry import DEFAULT_MODEL

log = logging.getLogger("svbrdf")

#: Files a folder input contributes (others are ignored, with a count).
PHOTO_EXTENSIONS = frozenset(".jpg .jpeg .png .tif .tiff .exr .webp".split())


@dataclasses.dataclass
class Job:
    """One run of ``capture`` or ``batch``: where the sets go, which model makes them, and how each
    photo is processed (:class:`svbrdf_cli.run.pipeline.Options`)."""

    output: str
    opts: pipeline.Options = dataclasses.field(default_factory=pipeline.Options)
    model: str = DEFAULT_MODEL
    threads: int = 0        # onnxruntime threads (0: one per core)
    skip_done: bool = False  # skip photos whose set is complete (batch: resume); else they fail without --force
    redo: set = dataclasses.field(default_factory=set)  # photos whose complete set has other options: replaced
    quiet: bool = False
    reserved: tuple = ()     # names in ``output`` the run writes itself (batch: the gallery): no set takes one


class _Collector(logging.Filter):
    """On the ``svbrdf`` logger: a warning raised on a thread that collects them goes to its list
    instead of the log."""

    local = threading.local()

    def filter(self, record):
        sink = getattr(self.local, "sink", None)
        if sink is None or record.levelno < logging.WARNING:
            return True
        sink.append(record.getMessage())
        return False


_COLLECTOR = _Collector()
log.addFilter(_COLLECTOR)


@contextlib.contextmanager
def collect_warnings(sink):
    """While the block runs, the ``svbrdf`` logger's warnings raised on this thread are appended to
    the list ``sink`` (their messages) instead of being logged."""
    before = getattr(_COLLECTOR.local, "sink", None)
    _COLLECTOR.local.sink = sink
    try:
        yield sink
    finally:
        _COLLECTOR.local.sink = before


def _collecting(sink, fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` with its warnings collected into ``sink``."""
    with collect_warnings(sink):
        return fn(*args, **kwargs)


def naming(photo, message):
    """A warning's message, naming ``photo`` unless it already does."""
    return message if f"'{photo}'" in message else f"'{photo}': {message}"


class Report:
    """What a run tells as it goes; this one tells nothing (:mod:`svbrdf_cli.cli` draws a terminal's)."""

    def start(self, total):
        """``total`` photos are to be converted."""

    def failed(self, message):
        """A photo failed: its one-line ``message`` (naming the file and the fix)."""

    def converted(self, photo, folder, record, seconds):
        """``photo`` became the set ``folder`` (``record``: its ``material.json``) in ``seconds``."""

    def warned(self, photo, message):
        """A warning about ``photo``, told right after its own line (converted or failed); ``message``
        names it."""

    def advanced(self):
        """One more photo is finished (converted or failed)."""

    def refine_step(self, done, total):
        """Step ``done`` of ``total`` of the current photo's ``--refine``."""

    def finish(self):
        """The run is over."""


class Counts(NamedTuple):
    """What a run did: photos converted, skipped as already complete, failed."""

    done: int
    skipped: int
    failed: int


def photo_extensions():
    """Extensions a folder input contributes: :data:`PHOTO_EXTENSIONS` and camera RAW."""
    from svbrdf_cli.ingest.photo import RAW_EXTENSIONS

    return PHOTO_EXTENSIONS | RAW_EXTENSIONS


def collect_inputs(paths):
    """Files given, and the photos directly inside folders given (sorted); (inputs, ignored count)."""
    exts = photo_extensions()
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


def plan_inputs(files, job, err, store=None):
    """Which inputs to run: (todo, skipped count, failed count), errors reported through ``err``.

    Two inputs with the same stem (photo.jpg, photo.dng) would write the same folder: the second
    fails. An existing set is skipped when complete and ``job.skip_done`` (batch) and its
    ``material.json`` records the same output options (:func:`svbrdf_cli.run.pipeline.options_differ`);
    made with other ones, it is redone (added to ``job.redo``: replaced as ``--force`` would, which
    keeps files svbrdf did not write). Otherwise it fails unless ``job.opts.force``. ``store``
    answers ``exists(stem)``, ``complete(stem)`` and ``record(stem)`` (default: local folders).
    """
    seen, todo, failed, skipped = {}, [], 0, 0
    changed = {}
    for f in files:
        folder = pipeline.output_folder(job.output, f)
        stem = os.path.basename(folder)
        if folder in seen:
            err(f"'{f}' would write to '{folder}' like '{seen[folder]}'; rename one of them.")
            failed += 1
            continue
        seen[folder] = f
        if stem in job.reserved:
            err(f"'{f}' would write its set to '{folder}', a name the run keeps for its own file; "
                "rename the photo.")
            failed += 1
            continue
        exists = store.exists(stem) if store else os.path.exists(folder)
        if exists and not job.opts.force:
            if job.skip_done and (store.complete(stem) if store else pipeline.is_complete(folder)):
                record = store.record(stem) if store else read_record(folder)
                differ = pipeline.options_differ(record, job.opts, job.model)
                if not differ:
                    log.info("skip %s: %s is complete", f, folder)
                    skipped += 1
                    continue
                log.info("redo %s: %s was made with other %s", f, folder, ", ".join(differ))
                changed[f] = differ
                job.redo.add(f)
                todo.append(f)
                continue
            err(f"'{folder}' already exists (from '{f}'); use --force to replace it.")
            failed += 1
            continue
        todo.append(f)
    if changed:
        cli = {"fmt": "format", "ao": "no-ao", "preview": "no-preview"}
        names = sorted({"--" + cli.get(k, k).replace("_", "-") for v in changed.values() for k in v})
        log.warning("%d complete set%s in '%s' made with other options (%s): redoing %s", len(changed),
                    "" if len(changed) == 1 else "s", job.output, ", ".join(names),
                    "it" if len(changed) == 1 else "them")
    return todo, skipped, failed


def read_record(folder):
    """A set's ``material.json`` as a dict, or None when it cannot be read."""
    return ownership.read_json(os.path.join(folder, pipeline.RECORD))


def options_for(opts, redo, f):
    """The options photo ``f`` runs with: ``opts``, replacing its set when it is one of ``redo``."""
    return dataclasses.replace(opts, force=True) if f in redo else opts


def describe_failure(f, e):
    """One line for an exception raised while converting ``f``."""
    if isinstance(e, SvbrdfError):
        return str(e)
    if isinstance(e, MemoryError):
        return f"'{f}': out of memory; use a smaller --size or downscale the photo."
    first = (str(e).strip().splitlines() or [""])[0]
    return f"'{f}': unexpected {type(e).__name__}: {first} (rerun with -vv for details; please report it)."


def run_local(files, job, failures=None, report=None):
    """Convert ``files`` in this process; returns :class:`Counts`. ``report`` (a :class:`Report`) is
    told of each failure and converted photo as the run goes; ``failures``, a list, also receives each
    failure's line."""
    from svbrdf_cli.infer.registry import load_model

    report = report or Report()
    notes = {}  # photo -> its warnings, reported with its own line

    def err(msg):
        report.failed(msg)
        if failures is not None:
            failures.append(msg)

    def tell_warnings(f):
        for message in notes.pop(f, []):
            report.warned(f, naming(f, message))

    todo, skipped, failed = plan_inputs(files, job, err)
    if not todo:
        return Counts(0, skipped, failed)

    chain = load_model(job.model, threads=job.threads)
    clean_partials(job.output)
    done = 0
    report.start(len(todo))

    def report_failure(f, e):
        log.debug("details", exc_info=e)
        err(describe_failure(f, e))
        tell_warnings(f)

    def finish(writing):
        """Wait for a set being written on the writer thread; report it (or its failure)."""
        nonlocal done
        f, t0, future = writing
        try:
            folder, record = future.result()
        except Exception as e:  # noqa: BLE001 - one bad photo never stops a batch
            report_failure(f, e)
        else:
            done += 1
            report.converted(f, folder, record, time.perf_counter() - t0)
            tell_warnings(f)
        report.advanced()

    # Read and crop the next photo while the current one is in the networks, and write the previous
    # set on another thread meanwhile: at most one set waits to be written (memory stays bounded).
    reader = concurrent.futures.ThreadPoolExecutor(max_workers=1)
    writer = concurrent.futures.ThreadPoolExecutor(max_workers=1)
    writing = None

    def prepare(f):
        return _collecting(notes.setdefault(f, []), pipeline.prepare, f, options_for(job.opts, job.redo, f))

    with reader, writer:
        pending = reader.submit(prepare, todo[0])
        for i, f in enumerate(todo):
            t0 = time.perf_counter()
            try:
                prepared = pending.result()
            except Exception as e:  # noqa: BLE001 - one bad photo never stops a batch
                prepared = None
                report_failure(f, e)
            if i + 1 < len(todo):
                pending = reader.submit(prepare, todo[i + 1])
            write = None
            if prepared is not None:
                try:
                    write = _collecting(notes.setdefault(f, []), pipeline.infer_set, prepared, chain, job.output,
                                        options_for(job.opts, job.redo, f), model_name=job.model, progress=report.refine_step)
                except Exception as e:  # noqa: BLE001
                    report_failure(f, e)
                del prepared
            if writing is not None:
                finish(writing)
                writing = None
            if write is not None:
                writing = (f, t0, writer.submit(_collecting, notes.setdefault(f, []), write))
            else:
                report.advanced()
        if writing is not None:
            finish(writing)
    report.finish()
    return Counts(done, skipped, len(todo) - done + failed)
