"""Texture sets written whole or not at all, and only ever replacing what svbrdf wrote.

:func:`write_set` writes every file into a hidden temporary folder beside the set
(``.svbrdf-<pid>-<token>.partial``, holding a marker naming the pid, host and token: see
:mod:`svbrdf_cli.write.ownership`), adds the set's manifest (every file with its SHA-256) and renames the
folder into place once complete. The rename happens under a lock on the parent folder, after
checking again that nothing appeared there meanwhile, so two runs writing the same set never
silently replace each other: without ``force`` the second fails with "already exists".

``force`` updates a folder only when it is a texture set svbrdf wrote (its manifest, or for older
sets its records, say so; a file name alone never does), and then replaces only the files its
manifest lists and that are still as svbrdf wrote them: files the user added or changed stay where
they are, and a new file whose name one of them holds stops the run before anything changes. It never
touches a folder holding a file the run reads (``protect``: the photo, the source set), nor one
reached through a symbolic link. :func:`clean_partials` removes the temporary folders of runs that
died mid-write on this host, never those of a run still going and never a folder that is not
recognisably ours.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile

from svbrdf_cli.write import ownership
from svbrdf_cli.errors import ImageWriteError
from svbrdf_cli.imageio import umask

#: The records a set svbrdf wrote holds (their content, not their names, makes it ours:
#: :func:`svbrdf_cli.write.ownership.read_manifest`).
SET_MARKERS = (ownership.MANIFEST, ownership.RECORD)


def is_our_set(folder):
    """Whether ``folder`` is a texture set written by svbrdf (by what it holds: see
    :func:`svbrdf_cli.write.ownership.read_manifest`)."""
    return ownership.read_manifest(folder) is not None


def _inside(path, folder):
    path, folder = os.path.realpath(path), os.path.realpath(folder)
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def check_replaceable(folder, force, protect=()):
    """Raise :class:`ImageWriteError` unless a set may be written at ``folder``: it does not exist, or
    ``force`` and it is a real folder, one of our sets, holding none of the ``protect`` paths."""
    if not os.path.lexists(folder):
        return
    if os.path.islink(folder):
        raise ImageWriteError(f"'{folder}' is a symbolic link; svbrdf writes sets only into real folders "
                              "(--force included). Remove the link or choose another folder name.")
    if not os.path.isdir(folder):
        raise ImageWriteError(f"'{folder}' is a file; choose a folder name for the texture set.")
    if not force:
        raise ImageWriteError(f"'{folder}' already exists; choose another folder or replace it with --force.")
    for p in protect:
        if _inside(p, folder):
            raise ImageWriteError(f"'{folder}' holds the input '{p}'; --force will not replace it. "
                                  "Write the set somewhere else (-o).")
    if not is_our_set(folder):
        raise ImageWriteError(f"'{folder}' is not a texture set written by svbrdf (no svbrdf manifest in its "
                              f"{ownership.MANIFEST}); --force replaces only those. Choose a new folder name.")


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


def make_temporary(parent):
    """A new temporary folder in ``parent``, named and marked as ours (:mod:`svbrdf_cli.write.ownership`)."""
    # a plain name (the set's own may not be valid UTF-8, which image libraries cannot open)
    tmp = tempfile.mkdtemp(prefix=f".svbrdf-{os.getpid()}-", suffix=".partial", dir=parent)
    try:
        ownership.mark_temporary(tmp)
    except OSError:  # (a full disk): our folder and its half marker go, not left unrecognisable
        _remove_unmarked(tmp)
        raise
    return tmp


def _remove_unmarked(path):
    """Remove a temporary folder of ours holding at most its (empty or half-written) marker: by ``rmdir``,
    which fails, and leaves it, if anything else is in it."""
    with contextlib.suppress(OSError):
        with contextlib.suppress(FileNotFoundError):
            os.remove(os.path.join(path, ownership.TEMP_MARKER))
        os.rmdir(path)


def write_set(folder, write_files, force, extra=None, protect=()):
    """Run ``write_files(tmp_folder) -> [names]`` and move the result to ``folder``.

    ``extra(tmp_folder) -> [names]``, if given, runs after ``write_files`` and adds files of its own (a
    capture's preview and record) to the same set. With ``force`` an existing set (ours, see
    :func:`check_replaceable`) is updated: the files svbrdf wrote there are replaced by the new ones
    (:func:`_merge`), every other file stays.

    Returns:
        Paths of the written files inside ``folder``.
    """
    folder = os.path.abspath(os.fspath(folder))
    parent = os.path.dirname(folder)
    check_replaceable(folder, force, protect)
    try:
        os.makedirs(parent, exist_ok=True)
        clean_partials(parent)
        tmp = make_temporary(parent)
    except OSError as e:
        raise ImageWriteError(f"Could not create a folder in '{parent}': {e.strerror}. "
                              "Check the path and permissions.") from None
    try:
        names = write_files(tmp)
        if extra is not None:
            names = names + extra(tmp)
        ownership.stamp_manifest(tmp)
        if ownership.MANIFEST not in names:
            names = names + [ownership.MANIFEST]
        os.chmod(tmp, 0o777 & ~umask())  # mkdtemp makes it 0700
        with _locked(parent):
            check_replaceable(folder, force, protect)  # again: another run may have written it meanwhile
            if os.path.lexists(folder):
                _merge(tmp, folder)
            else:
                # renamed with its marker, which goes after: a kill between the two leaves a finished set
                # with a stray marker, never an unmarked temporary the next write cannot tell for ours
                os.rename(tmp, folder)
                with contextlib.suppress(OSError):  # the set is written whatever happens to the marker
                    os.remove(os.path.join(folder, ownership.TEMP_MARKER))
    except OSError as e:
        raise ImageWriteError(f"Could not write the texture set '{folder}': {e.strerror or e}. "
                              "Check the path and free space.") from None
    finally:
        if os.path.isdir(tmp):
            shutil.rmtree(tmp, ignore_errors=True)
    return [os.path.join(folder, n) for n in names]


def _merge(tmp, folder):
    """Replace the set in ``folder`` (ours: checked) by the one in ``tmp``, file by file: svbrdf's
    files there that the new set lacks are removed, the new set's files are moved in, and every file
    the manifest does not list (or that changed since) is left as it is. Refused, before anything
    changes, when a new file's name (or a folder on its path) is held by such a file.

    A run killed midway leaves a manifest listing the old set's files and the new one's, so that the
    next ``--force`` finds every file of ours; ``material.json`` (a complete set) goes in last."""
    old = ownership.read_manifest(folder) or {}
    new = ownership.files_in(tmp)
    ours = {n for n, digest in old.items() if ownership.unchanged(os.path.join(folder, n), digest)}
    for n in new:
        parts = n.split("/")
        for i in range(1, len(parts)):
            d = os.path.join(folder, *parts[:i])
            if os.path.lexists(d) and (os.path.islink(d) or not os.path.isdir(d)):
                raise ImageWriteError(f"'{d}' is not svbrdf's; --force will not replace it. Move it away and "
                                      "run again.")
        p = os.path.join(folder, *parts)
        if os.path.lexists(p) and n not in ours:
            raise ImageWriteError(f"'{p}' was not written by svbrdf (or was changed since); --force will not "
                                  "replace it. Move it away and run again.")
    # 1. the manifest lists every file of ours, old and new, while they are swapped
    transition = ownership.read_json(os.path.join(tmp, ownership.MANIFEST)) or {}
    entry = dict(transition.get(ownership.MANIFEST_KEY, {}))
    entry["files"] = {**{n: None for n in ours}, **{n: None for n in new}}
    ownership.write_manifest(folder, dict(transition, **{ownership.MANIFEST_KEY: entry}))
    # 2. the record first out (the set is incomplete until the end), old files the new set lacks
    for n in sorted(ours - set(new) - {ownership.MANIFEST}, key=lambda n: n != ownership.RECORD):
        os.remove(os.path.join(folder, *n.split("/")))
        _prune(folder, os.path.dirname(n))
    if ownership.RECORD in ours and ownership.RECORD in new:
        os.remove(os.path.join(folder, ownership.RECORD))
    # 3. the new files, the record and then the manifest last
    last = (ownership.RECORD, ownership.MANIFEST)
    for n in [n for n in new if n not in last] + [n for n in last if n in new]:
        dst = os.path.join(folder, *n.split("/"))
        os.makedirs(os.path.dirname(dst), exist_ok=True)
        os.replace(os.path.join(tmp, *n.split("/")), dst)


def _prune(folder, sub):
    """Remove the folders on ``sub`` (relative to ``folder``) that are empty, deepest first."""
    while sub:
        try:
            os.rmdir(os.path.join(folder, *sub.split("/")))
        except OSError:
            return
        sub = os.path.dirname(sub)


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


def clean_partials(out):
    """Remove the temporary folders that runs killed mid-write on this host left in ``out``: only
    folders :func:`svbrdf_cli.write.ownership.orphan_temporary` recognises (named as ours, their process
    dead, and marked as ours or killed before they were marked)."""
    if not os.path.isdir(out):
        return
    for name in os.listdir(out):
        path = os.path.join(out, name)
        if ownership.stale_temporary(path):
            shutil.rmtree(path, ignore_errors=True)
        elif ownership.unmarked_orphan(path):
            _remove_unmarked(path)
