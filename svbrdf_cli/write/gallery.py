"""``index.html`` in a batch's output folder: one row per texture set, the failures with their reasons.

:func:`write_gallery` is called by ``svbrdf batch`` at the end of every run, so the page follows the
folder as a batch resumes: it lists every complete set found there (its photo, its maps, its relit
preview, its folder) and the inputs that failed in the latest run. The page is self-contained HTML
and CSS referring to the sets' own files by relative paths: nothing is fetched from the network.

The page carries :data:`svbrdf_cli.write.ownership.GENERATOR_META`: an ``index.html`` without it (the
user's own page, or a folder of that name) is never replaced; the gallery is then not written, with
a warning.
"""

from __future__ import annotations

import html
import json
import logging
import os

from svbrdf_cli.write import ownership
from svbrdf_cli.write.atomic import SET_MARKERS, is_our_set, write_text

log = logging.getLogger("svbrdf")

#: The gallery's file name in the output folder.
GALLERY = "index.html"
#: Image files a browser shows (a RAW or EXR input is listed by name only).
_VIEWABLE = (".png", ".jpg", ".jpeg", ".gif", ".webp")

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 1.5em; background: #1e1e1e; color: #ddd; }
h1 { font-size: 1.3em; } a { color: #8cf; }
table { border-collapse: collapse; } td, th { padding: 6px; vertical-align: top; text-align: left; }
tr { border-bottom: 1px solid #333; } img { width: 128px; height: 128px; object-fit: cover; display: block; }
img.preview { width: auto; height: 128px; } .err { color: #f88; font-family: monospace; }
figcaption { font-size: 0.75em; color: #999; }
"""


def _sets(out):
    """[(name, record, texture_set)] of the complete sets in ``out``, sorted by name."""
    found = []
    for name in sorted(os.listdir(out)):
        folder = os.path.join(out, name)
        if name.startswith(".") or not os.path.isdir(folder) or not is_our_set(folder):
            continue
        meta = {}
        for marker in SET_MARKERS:
            path = os.path.join(folder, marker)
            if os.path.isfile(path):
                try:
                    with open(path) as f:
                        meta[marker] = json.load(f)
                except (OSError, ValueError):
                    meta[marker] = {}
        if meta:
            found.append((name, meta.get("material.json", {}), meta.get("texture_set.json", {})))
    return found


def _map_files(texture_set, folder):
    """(file, role) of a set's PNG maps, in the order texture_set.json lists them."""
    files = texture_set.get("files") or {}
    if not files:  # a set without texture_set.json: the native names
        files = {f"{k}.png": {"role": k} for k in ("normal", "diffuse", "roughness", "specular")}
    return [(n, str(info.get("role", ""))) for n, info in files.items()
            if n.lower().endswith(".png") and os.path.isfile(os.path.join(folder, n))]


def _figure(src, caption, cls=""):
    c = f' class="{cls}"' if cls else ""
    return (f'<figure><a href="{html.escape(src)}"><img{c} src="{html.escape(src)}" loading="lazy" '
            f'alt="{html.escape(caption)}"></a><figcaption>{html.escape(caption)}</figcaption></figure>')


def render(out, failures=()):
    """The gallery page of ``out`` as a string (``failures``: one-line reasons of the latest run)."""
    rows = []
    for name, record, texture_set in _sets(out):
        folder = os.path.join(out, name)
        cells = []
        photo = (record.get("input") or {}).get("file")
        if photo and photo.lower().endswith(_VIEWABLE) and os.path.isfile(photo):
            cells.append(_figure(os.path.relpath(photo, out), "photo"))
        elif photo:
            cells.append(f"<figcaption>{html.escape(os.path.basename(photo))}</figcaption>")
        else:
            cells.append("")
        for file, role in _map_files(texture_set, folder):
            cells.append(_figure(f"{name}/{file}", role or file))
        if os.path.isfile(os.path.join(folder, "preview.png")):
            cells.append(_figure(f"{name}/preview.png", "preview: maps and relit", "preview"))
        model = (record.get("model") or {}).get("tier", "")
        viewer = (f'<br><a href="{html.escape(name)}/viewer.html">viewer</a>'
                  if os.path.isfile(os.path.join(folder, "viewer.html")) else "")  # (svbrdf view SET)
        head = (f'<a href="{html.escape(name)}/">{html.escape(name)}</a>{viewer}<br>'
                f'<figcaption>{html.escape(str(model))} {html.escape(str(record.get("size", "")))}</figcaption>')
        rows.append("<tr><th>" + head + "</th>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    fails = "".join(f'<li class="err">{html.escape(f)}</li>' for f in failures)
    return ("<!doctype html>\n<html><head><meta charset=\"utf-8\">" + ownership.GENERATOR_META + "<title>svbrdf: "
            f"{html.escape(os.path.basename(os.path.abspath(out)))}</title><style>{_STYLE}</style></head><body>\n"
            f"<h1>{len(rows)} texture set{'s' if len(rows) != 1 else ''} in "
            f"{html.escape(os.path.abspath(out))}</h1>\n"
            + (f"<h2>Failed in the latest run</h2><ul>{fails}</ul>\n" if failures else "")
            + "<table>\n" + "\n".join(rows) + "\n</table>\n</body></html>\n")


def write_gallery(out, failures=()):
    """Write (atomically) ``out/index.html``; returns its path, or None when ``out`` is not a folder or
    its ``index.html`` is not a gallery svbrdf wrote (a warning says so; it is left as it is)."""
    if not os.path.isdir(out):
        return None
    path = os.path.join(out, GALLERY)
    if os.path.lexists(path) and not ownership.is_our_page(path):
        log.warning("'%s' was not written by svbrdf: it is left as it is, and the gallery is not written. "
                    "Move it away to get one.", path)
        return None
    try:
        return write_text(path, render(out, failures))
    except OSError as e:
        log.warning("Could not write the gallery '%s': %s.", path, e.strerror or e)
        return None
