"""What ``--model`` names, ready to run.

``--model`` is ``physical`` (the maps computed from the flash physics, :mod:`svbrdf_cli.infer.physical`), an
installed network tier (a folder of :data:`svbrdf_cli.infer.chain.MODELS_DIR` named for one of
:data:`svbrdf_cli.infer.chain.TIERS`), ``auto`` (per photo, the cheapest installed model good enough
for it, :mod:`svbrdf_cli.infer.auto`) or a folder of exported models. Everything that runs
maps (the local batch, the Ray workers, the speed benchmark) loads them here, so that neither
:mod:`svbrdf_cli.infer.chain` nor :mod:`svbrdf_cli.infer.auto` has to know the other.
"""

from __future__ import annotations

import os

from svbrdf_cli.infer import swift
from svbrdf_cli.infer.chain import MODELS_DIR, TIERS, Chain, ModelError, installed_tiers
from svbrdf_cli.infer.physical import NAME as PHYSICAL
#: What ``svbrdf capture`` runs without ``--model``: the trained chain ``swift`` when it is installed
#: (it beats the physical estimate on Des19, every map and relief, and on the real 9-light card:
#: docs/benchmarks.md), else the physical estimate.
DEFAULT_MODEL = "swift" if "swift" in installed_tiers() else PHYSICAL
#: ``--model auto``: per photo, the cheapest installed model good enough for it (:mod:`svbrdf_cli.infer.auto`).
AUTO = "auto"


def model_folder(model):
    """``--model`` value (a tier name or a folder) -> the folder holding its ONNX files."""
    if model in TIERS:
        if model not in installed_tiers():
            raise ModelError(f"the '{model}' model is not installed (installed: {', '.join(model_names())}); "
                             f"leave --model out for the default ({DEFAULT_MODEL}).")
        return os.path.join(MODELS_DIR, model)
    if os.path.isdir(model):
        return model
    raise ModelError(f"'{model}' is neither an installed model ({', '.join(model_names())}) nor a folder of "
                     f"exported models; leave --model out for the default ({DEFAULT_MODEL}).")


def model_names():
    """What ``--model`` accepts by name here: the physical estimate, the installed tiers and, when its
    rule is installed, ``auto``."""
    from svbrdf_cli.infer.auto import RULE_FILE

    return [PHYSICAL, *installed_tiers(), *([AUTO] if os.path.isfile(RULE_FILE) else [])]


def load_model(model, threads=0):
    """What ``--model`` names, ready to run: a :class:`svbrdf_cli.infer.chain.Chain`, or for ``auto`` an
    :class:`svbrdf_cli.infer.auto.AutoModel`, for ``physical`` a
    :class:`svbrdf_cli.infer.physical.PhysicalModel`, for a folder holding ``chain.onnx`` a
    :class:`svbrdf_cli.infer.swift.SwiftModel` (same call interface)."""
    if model == AUTO:
        from svbrdf_cli.infer.auto import AutoModel

        return AutoModel(load_model, threads=threads)
    if model == PHYSICAL:
        from svbrdf_cli.infer.physical import PhysicalModel

        return PhysicalModel()
    folder = model_folder(model)
    if swift.is_swift(folder):
        return swift.SwiftModel(folder, threads=threads)
    return Chain(folder, threads=threads)


def check_model(model):
    """Raise :class:`svbrdf_cli.infer.chain.ModelError` now if ``model`` cannot be loaded (cheap: no
    session is made)."""
    if model == AUTO:
        from svbrdf_cli.infer.auto import load_rule

        load_rule()
    elif model != PHYSICAL:
        model_folder(model)
