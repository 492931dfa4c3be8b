"""The three-stage inference chain on onnxruntime (no torch).

A model folder holds ``masks.onnx``, ``aux.onnx`` and ``maps.onnx`` (a chain)
or ``maps.onnx`` alone (an end-to-end network such as ``lite``), as written by
``python -m export.onnx_export``; each declares its inputs,
outputs, size multiple and conventions version in its metadata, and
:class:`Chain` checks them when it loads.

Images are HWC float32 in [0, 1] (encoded, as the networks were trained);
the maps come back in their stored encoding (``svbrdf_cli.conventions``),
HWC, roughness with one channel.
"""

from __future__ import annotations

import os
import time

import numpy as np

from svbrdf_cli import conventions as cv
from svbrdf_cli.errors import SvbrdfError

STAGES = ("masks", "aux", "maps")
#: Pixels of reflected photo around the networks' input, cropped off their output (see :meth:`Chain.__call__`).
BORDER_MARGIN = 32

#: Installed model sets live here, one folder per tier, beside ``--model auto``'s rule (``auto.json``).
MODELS_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "models")
#: Names an installed tier may have, cheapest first: ``lite`` is one end-to-end UNet (maps.onnx only),
#: ``swift`` the training engine's chain in one graph (:data:`SWIFT_FILE`, ``export.engine``), the others
#: ``export.nets.chain``'s three-stage chain.
TIERS = ("lite", "fast", "swift", "balanced", "best")
#: The one file of a swift chain's folder (:mod:`svbrdf_cli.infer.swift`).
SWIFT_FILE = "chain.onnx"
#: The extra network input of models that refine the physical estimate: its four stored maps
#: stacked as 10 channels (normal 3, diffuse 3, roughness 1, specular 3).
PHYSICAL_INPUT = "physical"


def padding(h, w, multiple, margin=BORDER_MARGIN):
    """(margin, np.pad widths, np.pad mode) around an (h, w) network input: a reflected margin of
    ``margin`` pixels, then up to ``multiple``. The networks' zero padding then shapes the margin,
    which is cropped off, instead of the maps' own border."""
    m = min(margin, h - 1, w - 1)
    ph, pw = -(h + 2 * m) % multiple, -(w + 2 * m) % multiple
    pad = ((m, m + ph), (m, m + pw), (0, 0))
    return m, pad, ("reflect" if (m + ph < h and m + pw < w) else "edge")


class ModelError(SvbrdfError):
    """A model folder is missing, incomplete or made for other conventions."""


def session(path, threads):
    """An onnxruntime session of ``path`` on ``threads`` threads (0: onnxruntime's choice); a
    :class:`ModelError` naming the file when it cannot load.

    onnxruntime 1.32, when imported, writes a ``.ses`` file into ``$TMPDIR`` and tries to send usage
    events; ``ORT_DISABLE_TELEMETRY`` (unless the user set it) stops both."""
    os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
    import onnxruntime as ort

    opts = ort.SessionOptions()
    if threads:
        opts.intra_op_num_threads = threads
    providers = [p for p in ("CUDAExecutionProvider", "CPUExecutionProvider") if p in ort.get_available_providers()]
    try:
        return ort.InferenceSession(path, sess_options=opts, providers=providers)
    except Exception as e:  # noqa: BLE001 - onnxruntime raises its own unexported types
        why = (str(e).strip().splitlines() or [type(e).__name__])[0]
        why = why.split(" : ")[-1] if " : " in why else why
        raise ModelError(f"Could not load the model '{path}': {why}. Re-export it (python -m export.onnx_export) "
                         "or use --model physical.") from None


def model_stages(folder):
    """The stages exported in ``folder``: all of :data:`STAGES` (the chain), ``("maps",)`` (an
    end-to-end network), or None when the set is incomplete."""
    present = tuple(s for s in STAGES if os.path.isfile(os.path.join(folder, f"{s}.onnx")))
    return present if present in (STAGES, ("maps",)) else None


def installed_tiers():
    """Tiers whose models are in :data:`MODELS_DIR`, cheapest first."""
    def installed(folder):
        return os.path.isfile(os.path.join(folder, SWIFT_FILE)) or model_stages(folder)

    return [t for t in TIERS if installed(os.path.join(MODELS_DIR, t))]


class Chain:
    """masks -> aux -> maps, as trained (see ``export/nets/chain.py``); a :class:`svbrdf_cli.infer.model.Model`."""

    #: Runs at its export's resolution: the capture upsamples its maps.
    any_size = False

    def __init__(self, folder, threads=0):
        self.folder = os.fspath(folder)
        self.sessions, self.meta = {}, {}
        self.stages = model_stages(self.folder)
        if self.stages is None:
            missing = [f"{s}.onnx" for s in STAGES if not os.path.isfile(os.path.join(self.folder, f"{s}.onnx"))]
            raise ModelError(f"'{self.folder}' has no {', '.join(missing)}; export a trained run with "
                             "python -m export.onnx_export.")
        for stage in self.stages:
            path = os.path.join(self.folder, f"{stage}.onnx")
            sess = session(path, threads)
            meta = sess.get_modelmeta().custom_metadata_map
            if meta.get("conventions") != cv.CONVENTIONS_VERSION:
                raise ModelError(f"'{path}' was made for conventions version {meta.get('conventions')!r}, "
                                 f"this tool uses {cv.CONVENTIONS_VERSION!r}; re-export it.")
            if PHYSICAL_INPUT in meta.get("inputs", "").split(","):
                from svbrdf_cli.infer.physical import PHYSICAL_VERSION

                if meta.get("physical_version") != PHYSICAL_VERSION:
                    raise ModelError(f"'{path}' refines version {meta.get('physical_version')!r} of the physical "
                                     f"estimate, this tool computes version {PHYSICAL_VERSION!r}; retrain it.")
            self.sessions[stage], self.meta[stage] = sess, meta
        given = {"photo", PHYSICAL_INPUT}
        for stage in self.stages:
            need = set(self.meta[stage]["inputs"].split(",")) - given
            if need:
                raise ModelError(f"'{self.folder}': {stage}.onnx needs {', '.join(sorted(need))}, which no "
                                 "earlier stage makes; re-export the run.")
            given |= set(self.meta[stage]["outputs"].split(","))
        self.multiple = max(int(m.get("size_multiple", "32")) for m in self.meta.values())
        self.tier = self.meta["maps"].get("tier", "custom")
        # Which exported set this is: the SHA-256 of each file, from the export's provenance.json.
        self.files = {}
        prov = os.path.join(self.folder, "provenance.json")
        if os.path.isfile(prov):
            import json

            with open(prov) as f:
                files = json.load(f).get("export", {}).get("files", {})
            self.files = {k: v.get("sha256", "")[:16] for k, v in files.items()}
        self.timings = {}  # seconds of each stage in the last call
        self.found = None  # the physical estimate's findings, for a network that refines it

    @property
    def used(self):
        """The model that made the last outputs (for a chain, itself; see :class:`svbrdf_cli.infer.auto.AutoModel`)."""
        return self

    def describe(self):
        """What ``material.json`` records of the model."""
        return {"tier": self.tier, "folder": os.path.abspath(self.folder), "sha256_16": self.files}

    def _run(self, stage, feeds):
        meta = self.meta[stage]
        outs = meta["outputs"].split(",")
        res = self.sessions[stage].run(outs, {k: feeds[k] for k in meta["inputs"].split(",")})
        return dict(zip(outs, res))

    def __call__(self, image):
        """(H, W, 3) encoded image -> dict of HWC outputs (maps stored, plus masks and aux renderings
        when the model has those stages).

        The image is padded by reflection (:data:`BORDER_MARGIN` on each side,
        then up to the models' size multiple) and the outputs cropped back: the
        networks' zero padding would otherwise leave a border of its own on
        every map.
        """
        img = np.asarray(image, dtype=np.float32)
        if img.ndim != 3 or img.shape[-1] != 3:
            raise ValueError(f"expected an (H, W, 3) image, got shape {img.shape}")
        h, w = img.shape[:2]
        m, pad, mode = padding(h, w, self.multiple)
        x = np.ascontiguousarray(np.pad(img, pad, mode=mode).transpose(2, 0, 1)[None])
        feeds = {"photo": x}
        if any(PHYSICAL_INPUT in self.meta[s]["inputs"].split(",") for s in self.stages):
            from svbrdf_cli.infer import physical

            t0 = time.perf_counter()  # the estimate of the photo as it is (its geometry), padded like it
            est, self.found = physical.network_input(img)
            est = np.pad(est, pad, mode=mode)
            feeds[PHYSICAL_INPUT] = np.ascontiguousarray(est.transpose(2, 0, 1)[None])
            self.timings["physical"] = time.perf_counter() - t0
        for stage in self.stages:
            t0 = time.perf_counter()
            feeds.update(self._run(stage, feeds))
            self.timings[stage] = time.perf_counter() - t0
        names = [k for k in ("M_b", "M_h", "I_bf", "I_hr", "I_hr2") if k in feeds] + list(cv.MAP_NAMES)
        return {k: np.ascontiguousarray(feeds[k][0].transpose(1, 2, 0)[m:m + h, m:m + w]) for k in names}
