"""``index.html`` in a batch's output folder: one card per texture set, the failures with their reasons.

:func:`write_gallery` is called by ``svbrdf batch`` at the end of every run, so the page follows the
folder as a batch resumes: it lists every complete set found there (its photo, its maps under plain
names, its relit preview, a link to its folder and to its interactive viewer, which it writes beside
any set that has none: :mod:`svbrdf_cli.write.viewer`) and the inputs that failed in the latest run.
Each card's pictures wrap to the window's width, so nothing is cut off. The page is self-contained
HTML and CSS referring to the sets' own files by relative paths: nothing is fetched from the network.

The page carries :data:`svbrdf_cli.write.ownership.GENERATOR_META`: an ``index.html`` without it (the
user's own page, or a folder of that name) is never replaced; the gallery is then not written, with
a warning.
"""

from __future__ import annotations

import html
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
h1 { font-size: 1.3em; } h2 { font-size: 1.05em; margin: 0 0 6px 0; } a { color: #8cf; }
.set { border-bottom: 1px solid #333; padding: 10px 0; }
.set .info { font-size: 0.85em; color: #999; margin-left: 1em; }
.maps { display: flex; flex-wrap: wrap; gap: 8px; } figure { margin: 0; }
img { width: 128px; height: 128px; object-fit: cover; display: block; }
img.preview { width: auto; max-width: 100%; height: 128px; } .err { color: #f88; font-family: monospace; }
figcaption { font-size: 0.75em; color: #999; max-width: 128px; }
"""

#: Plain names of the maps, by what their role in ``texture_set.json`` starts with (the first that matches).
_LABELS = (("r = ambient occlusion", "packed: AO (R), roughness (G), metallic (B)"),
           ("r = metallic", "mask map: metallic, AO, smoothness"),
           ("base colour", "base colour"), ("diffuse", "diffuse colour"), ("specular", "specular (reflectance)"),
           ("normal", "normal"), ("roughness", "roughness"), ("metallic", "metallic"), ("height", "height"),
           ("ambient occlusion", "ambient occlusion"))


def label(role, file):
    """A map's plain name for the page, from its ``texture_set.json`` role (else the file's name)."""
    r = role.strip().lower()
    return next((name for start, name in _LABELS if r.startswith(start)), role or file)


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
                meta[marker] = ownership.read_json(path) or {}
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


def render(out, failures=(), sets=None):
    """The gallery page of ``out`` as a string (``failures``: one-line reasons of the latest run;
    ``sets``: what :func:`_sets` finds there, when the caller has it)."""
    cards = []
    for name, record, texture_set in _sets(out) if sets is None else sets:
        folder = os.path.join(out, name)
        cells = []
        photo = (record.get("input") or {}).get("file")
        if photo and photo.lower().endswith(_VIEWABLE) and os.path.isfile(photo):
            cells.append(_figure(os.path.relpath(photo, out), "photo"))
        elif photo:
            cells.append(f"<figure><figcaption>photo: {html.escape(os.path.basename(photo))}</figcaption></figure>")
        for file, role in _map_files(texture_set, folder):
            cells.append(_figure(f"{name}/{file}", label(role, file)))
        if os.path.isfile(os.path.join(folder, "preview.png")):
            cells.append(_figure(f"{name}/preview.png", "preview: the maps, and relit", "preview"))
        model = (record.get("model") or {}).get("tier", "")
        size = record.get("size", "")
        viewer = (f' &middot; <a href="{html.escape(name)}/viewer.html">open the viewer</a>'
                  if os.path.isfile(os.path.join(folder, "viewer.html")) else "")
        info = " ".join(str(x) for x in (model, f"{size} px" if size else "") if x)
        cards.append(f'<div class="set"><h2><a href="{html.escape(name)}/">{html.escape(name)}</a>{viewer}'
                     f'<span class="info">{html.escape(info)}</span></h2><div class="maps">' + "".join(cells)
                     + "</div></div>")
    fails = "".join(f'<li class="err">{html.escape(f)}</li>' for f in failures)
    return ("<!doctype html>\n<html><head><meta charset=\"utf-8\">" + ownership.GENERATOR_META
            + '<meta name="viewport" content="width=device-width, initial-scale=1"><title>svbrdf: '
            f"{html.escape(os.path.basename(os.path.abspath(out)))}</title><style>{_STYLE}</style></head><body>\n"
            f"<h1>{len(cards)} texture set{'s' if len(cards) != 1 else ''} in "
            f"{html.escape(os.path.abspath(out))}</h1>\n"
            + (f"<h2>Failed in the latest run</h2><ul>{fails}</ul>\n" if failures else "")
            + "\n".join(cards) + "\n</body></html>\n")


def _viewers(out, sets):
    """Write ``viewer.html`` beside every set of ``out`` (``sets``, as :func:`_sets` finds them) that has
    none (one that cannot be read gets none)."""
    from svbrdf_cli.errors import SvbrdfError
    from svbrdf_cli.write.viewer import VIEWER, write_viewer

    for name, _, _ in sets:
        folder = os.path.join(out, name)
        if not os.path.lexists(os.path.join(folder, VIEWER)):
            try:
                write_viewer(folder)
            except (SvbrdfError, OSError) as e:
                log.info("no viewer for '%s': %s", folder, e)


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
    sets = _sets(out)
    _viewers(out, sets)
    try:
        return write_text(path, render(out, failures, sets))
    except OSError as e:
        log.warning("Could not write the gallery '%s': %s.", path, e.strerror or e)
        return None
