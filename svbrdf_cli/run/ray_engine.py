"""``svbrdf batch --engine ray``: the same batch on a Ray cluster (``pip install svbrdf[scale]``).

The input files become a ``ray.data`` dataset of paths; an actor pool of
:class:`CaptureWorker` (one model chain per worker, loaded once) reads, crops,
infers and writes each photo where it is, so pixels never travel through
Ray's object store: only paths go in and one small result row per photo comes
out. The driver plans the work exactly as the local engine does (same
naming, skipping of complete sets, ``--force``, duplicate stems) and prints
the same summary; a bad photo is a failed row, never a failed job.

Outputs go to a local folder (which every worker must see: on a cluster, a
shared mount) or to any URI ``pyarrow.fs`` opens (``s3://``, ``gs://``,
``abfs://``, ``hdfs://``, ``file://``), or else ``fsspec`` (any installed
implementation, wrapped for pyarrow). Remote sets are written locally on the
worker first (atomically) and uploaded file by file with ``material.json``
last: a set whose ``material.json`` exists is complete, which is what resuming
checks.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import sys
import tempfile

from svbrdf_cli.run import pipeline
from svbrdf_cli.write import ownership
from svbrdf_cli.write.atomic import clean_partials
from svbrdf_cli.run.batch import (Counts, collect_warnings, describe_failure, naming, options_for, plan_inputs,
                                  read_record)
from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli.infer.registry import check_model, load_model

log = logging.getLogger("svbrdf")


class ScaleError(SvbrdfError):
    """Ray or the output store is missing or unreachable."""


def is_uri(output):
    """Whether ``output`` is a URI (``s3://...``) rather than a local folder."""
    return "://" in os.fspath(output)


def open_store(output):
    """(pyarrow FileSystem, root path inside it) for a URI."""
    try:
        import pyarrow.fs as pafs
    except ImportError:
        raise ScaleError("Writing to a URI needs pyarrow: pip install 'svbrdf[scale]'.") from None
    try:
        return pafs.FileSystem.from_uri(output)
    except (ValueError, NotImplementedError, OSError):  # ArrowInvalid / ArrowNotImplementedError: not pyarrow's
        pass
    try:
        import fsspec
        from pyarrow.fs import FSSpecHandler, PyFileSystem
    except ImportError:
        raise ScaleError(f"No filesystem for '{output}': pyarrow does not know the scheme and fsspec is not installed.") from None
    try:
        fs, path = fsspec.core.url_to_fs(output)
    except (ImportError, ValueError) as e:
        raise ScaleError(f"No filesystem for '{output}': {e}. Install the fsspec implementation for it.") from None
    return PyFileSystem(FSSpecHandler(fs)), path


class Store:
    """Where sets go: a local folder or a URI (see the module docstring)."""

    def __init__(self, output):
        self.output = os.fspath(output)
        self.remote = is_uri(self.output)
        if self.remote:
            self.fs, self.root = open_store(self.output)
            self.root = self.root.rstrip("/")

    def _info(self, rel):
        import pyarrow.fs as pafs

        return self.fs.get_file_info(f"{self.root}/{rel}").type != pafs.FileType.NotFound

    def exists(self, stem):
        """Whether the set ``stem`` exists in the store."""
        return self._info(stem) if self.remote else os.path.exists(os.path.join(self.output, stem))

    def complete(self, stem):
        """Whether the set ``stem`` is complete in the store."""
        return self._info(f"{stem}/{pipeline.RECORD}") if self.remote else pipeline.is_complete(os.path.join(self.output, stem))

    def record(self, stem):
        """The set ``stem``'s ``material.json`` as a dict, or None when it cannot be read."""
        if not self.remote:
            return read_record(os.path.join(self.output, stem))
        return self._json(f"{self.root}/{stem}/{pipeline.RECORD}")

    def upload(self, local_folder, stem):
        """Copy a finished local set to ``<root>/<stem>/``, its manifest first and ``material.json``
        last. A set already there loses only the files svbrdf wrote and nobody changed since (its
        manifest); a file of the new set that would replace anything else is refused."""
        import pyarrow.fs as pafs

        dest = f"{self.root}/{stem}"
        files = sorted(os.path.relpath(os.path.join(d, n), local_folder)
                       for d, _, names in os.walk(local_folder) for n in names)
        if self._info(stem):  # (a set the plan redoes: --force, other options, or an interrupted upload)
            kept = self._remove_ours(dest)
            clash = sorted(set(kept) & {rel.replace(os.sep, "/") for rel in files})
            if clash:
                raise SvbrdfError(f"'{self.output.rstrip('/')}/{stem}' holds {', '.join(clash[:3])}, which svbrdf did "
                                  "not write (or which changed since); move them away, or write elsewhere with -o.")
        self.fs.create_dir(dest, recursive=True)
        # the manifest first (an interrupted upload is still known as ours), the completion marker last
        files.sort(key=lambda rel: (rel != ownership.MANIFEST, rel == pipeline.RECORD))
        local = pafs.LocalFileSystem()
        for rel in files:
            target = f"{dest}/{rel.replace(os.sep, '/')}"
            if os.sep in rel:
                self.fs.create_dir(target.rsplit("/", 1)[0], recursive=True)
            pafs.copy_files(os.path.join(local_folder, rel), target, source_filesystem=local,
                            destination_filesystem=self.fs)
        return f"{self.output.rstrip('/')}/{stem}"

    def _files(self, dest):
        """Relative ``/``-separated paths of the files below ``dest`` in the store."""
        import pyarrow.fs as pafs

        infos = self.fs.get_file_info(pafs.FileSelector(dest, recursive=True))
        return [i.path[len(dest) + 1:] for i in infos if i.type == pafs.FileType.File]

    def _read(self, path, limit=None):
        with self.fs.open_input_stream(path) as fh:
            return fh.read(limit) if limit else fh.read()

    def _json(self, path):
        import json

        try:
            data = json.loads(self._read(path, 16 << 20).decode("utf-8"))
        except (OSError, ValueError):
            return None
        return data if isinstance(data, dict) else None

    def _remove_ours(self, dest):
        """Delete the files of the set at ``dest`` that svbrdf wrote and that are as it wrote them (its
        manifest, :mod:`svbrdf_cli.write.ownership`); returns the files left, which are not ours."""
        import hashlib

        ours = ownership.manifest_of(self._json(f"{dest}/{ownership.MANIFEST}"),
                                     self._json(f"{dest}/{ownership.RECORD}")) or {}
        left = []
        for rel in self._files(dest):
            digest = ours.get(rel, False)
            if digest is not False and (digest is None or hashlib.sha256(self._read(f"{dest}/{rel}")).hexdigest() == digest):
                self.fs.delete_file(f"{dest}/{rel}")
            else:
                left.append(rel)
        return left


class CaptureWorker:
    """One Ray actor: a model chain loaded once, then photos one by one (``map_batches``)."""

    def __init__(self, model, opts, output, threads=1, redo=()):
        self.chain = load_model(model, threads=threads)
        self.model, self.opts, self.store, self.redo = model, opts, Store(output), frozenset(redo)

    def _one(self, path):
        notes = []
        with collect_warnings(notes):
            row = self._convert(path)
        return dict(row, warnings="\n".join(naming(path, m) for m in notes))

    def _convert(self, path):
        opts = options_for(self.opts, self.redo, path)
        try:
            prepared = pipeline.prepare(path, opts)
            if not self.store.remote:
                folder, rec = pipeline.capture(prepared, self.chain, self.store.output, opts, model_name=self.model)
                return {"path": path, "folder": folder, "error": "", "seconds": sum(rec["timings_s"].values())}
            tmp = tempfile.mkdtemp(prefix="svbrdf-ray-")
            try:
                local, rec = pipeline.capture(prepared, self.chain, tmp, opts, model_name=self.model)
                folder = self.store.upload(local, os.path.basename(local))
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
            return {"path": path, "folder": folder, "error": "", "seconds": sum(rec["timings_s"].values())}
        except Exception as e:  # noqa: BLE001 - a bad photo is a failed row, never a failed job
            return {"path": path, "folder": "", "error": describe_failure(path, e), "seconds": 0.0}

    def __call__(self, batch):
        """Convert one batch of photos on this worker; a row per photo (its set or its failure)."""
        rows = [self._one(str(p)) for p in batch["path"]]
        return {k: [r[k] for r in rows] for k in ("path", "folder", "error", "seconds", "warnings")}


@contextlib.contextmanager
def _silenced_fd2(active):
    if not active:
        yield
        return
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def run_ray(files, job, address=None, workers=None, err=print):
    """Run ``job`` (:class:`svbrdf_cli.run.batch.Job`) on Ray; returns :class:`svbrdf_cli.run.batch.Counts` like the
    local engine. Each worker runs ``job.threads`` onnxruntime threads (0: one)."""
    output, opts, model, quiet = job.output, job.opts, job.model, job.quiet
    threads_per_worker = job.threads or 1
    quiet_ray = log.getEffectiveLevel() > logging.DEBUG  # Ray's own INFO lines would bury the summary
    if quiet_ray:
        # The driver's core worker logs an "E" line for every actor pool (ray-project/ray#53727) that is
        # no error of ours; real failures still reach the user as failed rows or exceptions.
        os.environ.setdefault("RAY_BACKEND_LOG_LEVEL", "fatal")
    try:
        import ray
        import ray.data
    except ImportError:
        raise ScaleError("--engine ray needs Ray: pip install 'svbrdf[scale]'.") from None
    if quiet_ray:
        for name in ("ray", "ray.data"):
            logging.getLogger(name).setLevel(logging.ERROR if quiet else logging.WARNING)
    store = Store(output)
    check_model(model)  # fail early, on the driver, for a model that is not installed
    todo, skipped, failed = plan_inputs(files, job, err, store=store)
    if not todo:
        return Counts(0, skipped, failed)
    if not store.remote:
        os.makedirs(output, exist_ok=True)
        clean_partials(output)
    started_here = not ray.is_initialized()
    if started_here:
        try:
            with _silenced_fd2(quiet_ray):  # the core worker announces its log level on fd 2
                ray.init(address=address, logging_level=logging.ERROR, log_to_driver=False,
                         include_dashboard=False, ignore_reinit_error=True)
        except (ConnectionError, RuntimeError, ValueError) as e:
            raise ScaleError(f"Could not reach the Ray cluster at '{address}': {e}. "
                             "Check --address (ray://HOST:10001 or HOST:6379) or start one with 'ray start --head'.") from None
    try:
        ctx = ray.data.DataContext.get_current()
        ctx.enable_progress_bars = not quiet
        if workers is None:
            workers = max(1, int(ray.cluster_resources().get("CPU", 1) // max(1, threads_per_worker)))
        # Absolute paths: workers may start in another directory.
        paths = [os.path.abspath(p) for p in todo]
        ds = ray.data.from_items([{"path": p} for p in paths], override_num_blocks=min(len(paths), 200))
        pool = ray.data.ActorPoolStrategy(min_size=1, max_size=workers, initial_size=min(workers, len(paths)))
        redo = [os.path.abspath(p) for p in todo if p in job.redo]
        ds = ds.map_batches(CaptureWorker, fn_constructor_args=(model, opts, output, threads_per_worker, redo),
                            batch_size=1, compute=pool, num_cpus=threads_per_worker)
        rows = ds.take_all()
    finally:
        if started_here:
            ray.shutdown()
    done = 0
    by_path = {r["path"]: r for r in rows}
    for p, original in zip(paths, todo):
        r = by_path.get(p)
        if r is None:
            err(f"'{original}': no result came back from the cluster; rerun the batch to retry it.")
            failed += 1
        elif r["error"]:
            err(r["error"])
            failed += 1
        else:
            done += 1
            if not quiet:
                log.info("%s -> %s (%.1f s)", original, r["folder"], r["seconds"])
        for line in (r or {}).get("warnings", "").splitlines():  # (a worker's warnings, naming the photo)
            log.warning("%s", line.replace(p, original))
    return Counts(done, skipped, failed)
