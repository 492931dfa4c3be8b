"""Texture sets written whole or not at all, and replaced only when they are ours.

:func:`write_set` writes every file into a hidden temporary folder beside the set
(``.svbrdf-<pid>-<random>.partial``) and renames it into place once complete. The rename happens
under a lock on the parent folder, after checking again that nothing appeared there meanwhile, so
two runs writing the same set never silently replace each other: without ``force`` the second
fails with "already exists".

``force`` replaces only a folder that is a texture set this tool wrote (it holds one of
:data:`SET_MARKERS`), never a folder holding anything else, and never one that holds a file the
run reads (``protect``: the photo, the source set). :func:`clean_partials` removes the temporary
folders of runs that died mid-write, never those of a run still going.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile

from svbrdf_cli.errors import ImageWriteError
from svbrdf_cli.imageio import umask

#: A folder holding one of these was written by svbrdf: ``texture_set.json`` by every preset,
#: ``material.json`` by ``svbrdf capture``.
SET_MARKERS = ("texture_set.json", "material.json")
#: Temporary folders: ``.svbrdf-<pid>-<random>.partial`` (being written) and ``.old`` (being replaced).
_TEMPORARY = re.compile(r"^\.svbrdf-(\d+)-[^/]*\.(partial|old)$")
#: Temporary folders of versions before the pid was in the name, ``.<set>.<8 random>.partial``.
_LEGACY = re.compile(r"^\..+\.[a-z0-9_]{8}\.(partial|old)$")


def is_our_set(folder):
    """Whether ``folder`` is a texture set written by svbrdf."""
    return any(os.path.isfile(os.path.join(folder, m)) for m in SET_MARKERS)


def _inside(path, folder):
    path, folder = os.path.realpath(path), os.path.realpath(folder)
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def check_replaceable(folder, force, protect=()):
    """Raise :class:`ImageWriteError` unless a set may be written at ``folder``: it does not exist, or
    ``force`` and it is one of our sets holding none of the ``protect`` paths."""
    if not os.path.lexists(folder):
        return
    if not os.path.isdir(folder):
        raise ImageWriteError(f"'{folder}' is a file; choose a folder name for the texture set.")
    if not force:
        raise ImageWriteError(f"'{folder}' already exists; choose another folder or replace it with --force.")
    for p in protect:
        if _inside(p, folder):
            raise ImageWriteError(f"'{folder}' holds the input '{p}'; --force will not replace it. "
                                  "Write the set somewhere else (-o).")
    if not is_our_set(folder):
        raise ImageWriteError(f"'{folder}' is not a texture set written by svbrdf (it has no "
                              f"{' or '.join(SET_MARKERS)}); --force replaces only those. Choose a new folder name.")


@contextlib.contextmanager
def _locked(parent):
    """An exclusive lock on the folder ``parent`` (POSIX ``flock``; no lock where there is none)."""
    try:
        import fcntl
    except ImportError:  # Windows: the checks still run, without mutual exclusion
        yield
        return
    fd = os.open(parent, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


def write_set(folder, write_files, force, extra=None, protect=()):
    """Run ``write_files(tmp_folder) -> [names]`` and move the result to ``folder``.

    ``extra(tmp_folder) -> [names]``, if given, runs after ``write_files`` and adds files of its own (a
    capture's preview and record) to the same set. With ``force`` an existing set (ours, see
    :func:`check_replaceable`) is renamed away first and deleted once the new one is in.

    Returns:
        Paths of the written files inside ``folder``.
    """
    folder = os.path.abspath(os.fspath(folder))
    parent = os.path.dirname(folder)
    check_replaceable(folder, force, protect)
    try:
        os.makedirs(parent, exist_ok=True)
        # a plain name (the set's own may not be valid UTF-8, which image libraries cannot open)
        tmp = tempfile.mkdtemp(prefix=f".svbrdf-{os.getpid()}-", suffix=".partial", dir=parent)
    except OSError as e:
        raise ImageWriteError(f"Could not create a folder in '{parent}': {e.strerror}. "
                              "Check the path and permissions.") from None
    old = None
    try:
        names = write_files(tmp)
        if extra is not None:
            names = names + extra(tmp)
        os.chmod(tmp, 0o777 & ~umask())  # mkdtemp makes it 0700
        with _locked(parent):
            check_replaceable(folder, force, protect)  # again: another run may have written it meanwhile
            if os.path.lexists(folder):
                old = tmp[: -len(".partial")] + ".old"
                os.rename(folder, old)
            try:
                os.rename(tmp, folder)
            except OSError:
                if old is not None:
                    os.rename(old, folder)
                    old = None
                raise
    except OSError as e:
        raise ImageWriteError(f"Could not write the texture set '{folder}': {e.strerror or e}. "
                              "Check the path and free space.") from None
    finally:
        if os.path.isdir(tmp):
            shutil.rmtree(tmp, ignore_errors=True)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    return [os.path.join(folder, n) for n in names]


def write_text(path, text):
    """Write a text file atomically (a temporary file beside it, renamed over it), mode as ``open`` gives."""
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=".svbrdf-", suffix=os.path.splitext(path)[1], dir=folder)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.chmod(tmp, 0o666 & ~umask())  # mkstemp makes it 0600
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def clean_partials(out):
    """Remove the temporary folders that runs killed mid-write left in ``out`` (never those of a run
    still going: their pid is in the name)."""
    if not os.path.isdir(out):
        return
    for name in os.listdir(out):
        m = _TEMPORARY.match(name)
        stale = (m is not None and not _alive(int(m.group(1)))) or (m is None and _LEGACY.match(name) is not None)
        if stale and os.path.isdir(os.path.join(out, name)):
            shutil.rmtree(os.path.join(out, name), ignore_errors=True)
