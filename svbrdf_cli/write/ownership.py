"""What svbrdf wrote, recognised by content it wrote, never by a name alone.

* A texture set's **manifest** is the ``svbrdf_set`` entry of its ``texture_set.json``: the tool's
  name and version and every file of the set with its SHA-256 (:func:`stamp_manifest`, called on
  the temporary folder before it becomes the set). :func:`read_manifest` returns those files, or
  None for a folder svbrdf did not write; a set written before the manifest existed is recognised by
  its records (``texture_set.json``'s ``generator`` and ``files``, ``material.json``'s ``tool`` and
  ``files``), each file of it then counted as ours whatever its content.
* A **temporary folder** (``.svbrdf-<pid>-<token>.partial``) holds :data:`TEMP_MARKER`, a record of
  the tool, the pid, the host and the token (:func:`mark_temporary`); :func:`orphan_temporary` says
  whether a folder is one of ours whose process has died on this host: marked (:func:`stale_temporary`)
  or killed before it was marked (:func:`unmarked_orphan`).
* A **page** (the batch gallery, the viewer) carries :data:`GENERATOR_META` in its head
  (:func:`is_our_page`).

Paths in a manifest are relative, ``/``-separated and never leave the folder (:func:`safe_name`).
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import socket

from svbrdf_cli.version import __version__

TOOL = "svbrdf"
#: The file holding the manifest (every preset writes it) and the manifest's key in it.
MANIFEST, MANIFEST_KEY = "texture_set.json", "svbrdf_set"
#: A capture's record (it lists the set's files too).
RECORD = "material.json"
#: The record inside each temporary folder (never part of the set).
TEMP_MARKER = ".svbrdf-temporary.json"
#: ``.svbrdf-<pid>-<token>.partial``: the names :func:`tempfile.mkdtemp` gives our temporary folders.
TEMP_NAME = re.compile(r"^\.svbrdf-(\d+)-([a-z0-9_]{8})\.partial$")
#: What our HTML pages carry in their head.
GENERATOR_META = f'<meta name="generator" content="{TOOL}">'
#: The start of the pages (gallery, viewer) written before :data:`GENERATOR_META` (exactly as they began).
_LEGACY_PAGES = ('<!doctype html>\n<html><head><meta charset="utf-8"><title>svbrdf: ',
                 '<!doctype html>\n<html><head><meta charset="utf-8"><title>svbrdf viewer: ')


def sha256(path):
    """The SHA-256 of the file ``path``, read in blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def safe_name(name):
    """``name`` as a relative ``/``-separated path inside a folder, or None when it is not one (absolute,
    empty, holding ``..`` or a NUL)."""
    if not isinstance(name, str) or not name or "\0" in name or name.startswith(("/", "\\")):
        return None
    parts = name.replace("\\", "/").split("/")
    if any(p in ("", ".", "..") for p in parts):
        return None
    return "/".join(parts)


def files_in(folder, skip=(TEMP_MARKER,)):
    """Relative ``/``-separated paths of the regular files below ``folder`` (not following links)."""
    found = []
    for d, dirs, names in os.walk(folder):
        for n in names:
            rel = os.path.relpath(os.path.join(d, n), folder).replace(os.sep, "/")
            if rel not in skip:
                found.append(rel)
    return sorted(found)


def read_json(path):
    """The JSON object in the regular file ``path`` (not a link), or None when absent or unreadable."""
    if os.path.islink(path) or not os.path.isfile(path):
        return None
    try:
        with open(path, "rb") as f:
            data = json.loads(f.read(16 << 20).decode("utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def stamp_manifest(folder):
    """Add the manifest (every file below ``folder`` with its SHA-256) to ``folder``'s
    :data:`MANIFEST`, creating it when there is none. Run on a set's temporary folder once every
    file is written; the manifest itself is listed without a hash."""
    path = os.path.join(folder, MANIFEST)
    meta = read_json(path) or {}
    files = {n: sha256(os.path.join(folder, n)) for n in files_in(folder) if n != MANIFEST}
    files[MANIFEST] = None
    meta[MANIFEST_KEY] = {"tool": TOOL, "version": __version__, "files": dict(sorted(files.items()))}
    write_manifest(folder, meta)


def write_manifest(folder, meta):
    """Write ``meta`` as ``folder``'s :data:`MANIFEST` (a temporary file renamed over it)."""
    path = os.path.join(folder, MANIFEST)
    tmp = os.path.join(folder, f".svbrdf-{os.getpid()}-manifest.tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(meta, f, indent=2)
        f.write("\n")
    os.replace(tmp, path)


def read_manifest(folder):
    """{relative path: SHA-256 or None (ours whatever its content)} of the files svbrdf wrote in
    ``folder``, or None when ``folder`` is not a texture set svbrdf wrote (or is a link)."""
    if os.path.islink(folder) or not os.path.isdir(folder):
        return None
    return manifest_of(read_json(os.path.join(folder, MANIFEST)), read_json(os.path.join(folder, RECORD)))


def manifest_of(meta, record):
    """:func:`read_manifest` from a set's :data:`MANIFEST` and :data:`RECORD` contents (dicts or None),
    wherever they were read from (a folder, an object store)."""
    entry = meta.get(MANIFEST_KEY) if meta else None
    if isinstance(entry, dict) and entry.get("tool") == TOOL and isinstance(entry.get("files"), dict):
        files = {safe_name(n): h if isinstance(h, str) else None for n, h in entry["files"].items()}
        files.pop(None, None)
        return files or None
    # sets written before the manifest: their records name their files
    files = set()
    if meta and str(meta.get("generator", "")).startswith(TOOL + " ") and isinstance(meta.get("files"), dict):
        files |= set(meta["files"]) | {MANIFEST}
    if record and str(record.get("tool", "")).startswith(TOOL + " ") and isinstance(record.get("files"), list):
        files |= {n for n in record["files"] if isinstance(n, str)} | {RECORD}
    found = {safe_name(n): None for n in files}
    found.pop(None, None)
    return found or None


def unchanged(path, digest):
    """Whether the file at ``path`` is still what svbrdf wrote (``digest`` None: any regular file)."""
    if os.path.islink(path) or not os.path.isfile(path):
        return False
    return digest is None or sha256(path) == digest


# --------------------------------------------------------------------------
# Temporary folders
# --------------------------------------------------------------------------

def mark_temporary(folder):
    """Write :data:`TEMP_MARKER` into a new temporary folder named by :data:`TEMP_NAME`, in one
    ``os.write`` to a file it creates: a run killed meanwhile leaves no marker or an empty one."""
    m = TEMP_NAME.match(os.path.basename(folder))
    record = {"tool": TOOL, "version": __version__, "pid": int(m.group(1)), "token": m.group(2),
              "host": socket.gethostname()}
    data = json.dumps(record).encode("utf-8")
    fd = os.open(os.path.join(folder, TEMP_MARKER), os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        if os.write(fd, data) != len(data):
            raise OSError(errno.ENOSPC, "the temporary folder's marker was cut short")
    finally:
        os.close(fd)


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):  # someone else's process (or no such pid at all)
        return True
    return True


def stale_temporary(path):
    """Whether ``path`` is a temporary folder svbrdf made whose process has died: its name matches
    :data:`TEMP_NAME`, it is a real folder, and its :data:`TEMP_MARKER` names the same pid and token,
    this host, and a pid no longer running. (A folder of ours on another host is never judged.)"""
    m = TEMP_NAME.match(os.path.basename(path))
    if m is None or os.path.islink(path) or not os.path.isdir(path):
        return False
    pid = int(m.group(1))
    record = read_json(os.path.join(path, TEMP_MARKER))
    if record is None:
        return False
    return (record.get("tool") == TOOL and record.get("pid") == pid and record.get("token") == m.group(2)
            and record.get("host") == socket.gethostname() and not _alive(pid))


def unmarked_orphan(path):
    """Whether ``path`` is a temporary folder named as ours whose run was killed before it was marked:
    a real folder, empty or holding only an empty :data:`TEMP_MARKER`, its process dead."""
    m = TEMP_NAME.match(os.path.basename(path))
    if m is None or os.path.islink(path) or not os.path.isdir(path):
        return False
    marker = os.path.join(path, TEMP_MARKER)
    try:
        names = os.listdir(path)
        if names and (names != [TEMP_MARKER] or os.path.islink(marker) or not os.path.isfile(marker)
                      or os.path.getsize(marker)):
            return False
    except OSError:
        return False
    return not _alive(int(m.group(1)))


def orphan_temporary(path):
    """Whether ``path`` is a temporary folder of ours left by a run that died on this host, marked
    (:func:`stale_temporary`) or not (:func:`unmarked_orphan`)."""
    return stale_temporary(path) or unmarked_orphan(path)


# --------------------------------------------------------------------------
# Pages
# --------------------------------------------------------------------------

def is_our_page(path):
    """Whether ``path`` is an HTML page svbrdf wrote (a regular file carrying :data:`GENERATOR_META`, or
    a gallery of the versions before it)."""
    if os.path.islink(path) or not os.path.isfile(path):
        return False
    try:
        with open(path, "rb") as f:
            head = f.read(4096).decode("utf-8", "replace")
    except OSError:
        return False
    return GENERATOR_META in head or head.startswith(_LEGACY_PAGES)
