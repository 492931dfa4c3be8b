"""Shared fixtures. Tests that read ``../shared`` skip cleanly when it is absent.

The package installs no network (``--model physical`` is the default and ``auto`` has only it to
choose): tests that need one run a folder of exported models (``--model FOLDER``) that
:func:`swift_model` or :func:`chain_model` exports once per session, skipping cleanly without torch.
"""

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SHARED = Path(os.environ.get("SVBRDF_SHARED", ROOT.parent / "shared"))
DATA = Path(__file__).resolve().parent / "data"


@pytest.fixture
def shared_data():
    """``../shared/data``, or skip."""
    path = SHARED / "data"
    if not path.is_dir():
        pytest.skip("../shared/data is not present (a user's fresh clone)")
    return path


@pytest.fixture
def golden():
    import numpy as np

    return dict(np.load(DATA / "brdf_golden.npz"))


#: The random weights of the fixture networks' heads: large enough that their zero padding would show
#: as a seam at the maps' border without the runtime's reflected margin (test_registry's seam test
#: fails with ``BORDER_MARGIN = 0``), small enough that their maps stay maps.
HEAD_STD = 0.1


def _export_or_skip():
    """torch and onnx (the ``train`` extra), or skip: the fixture models are exported here, not shipped."""
    torch = pytest.importorskip("torch", reason="a network model for the tests is exported with torch (the 'train' extra)")
    pytest.importorskip("onnx", reason="a network model for the tests is exported with onnx (the 'train' extra)")
    return torch


@pytest.fixture(scope="session")
def swift_model(tmp_path_factory):
    """A folder for ``--model FOLDER`` holding a swift chain (``chain.onnx``, run by
    :class:`svbrdf_cli.infer.swift.SwiftModel`): the training engine's network, untrained, its zero
    heads given random weights (:data:`HEAD_STD`) so that its maps are its own, not the physical
    estimate's. Exported once per session; skips without torch."""
    torch = _export_or_skip()
    from export.engine import nets
    from export.engine import onnx as engine_onnx

    folder = tmp_path_factory.mktemp("models") / "swift"
    with torch.random.fork_rng():  # the session's other tests keep their random stream
        torch.manual_seed(0)
        net = nets.build().eval()
        for m in (net.aux, net.maps):
            torch.nn.init.normal_(m.head.weight, std=HEAD_STD)
        engine_onnx.export(net, str(folder / "chain.onnx"), provenance={"samples": 0, "made_by": "tests/conftest.py"})
    return folder


@pytest.fixture(scope="session")
def chain_model(tmp_path_factory):
    """A folder for ``--model FOLDER`` holding a three-stage chain (``masks.onnx``, ``aux.onnx``,
    ``maps.onnx``, run by :class:`svbrdf_cli.infer.chain.Chain`), as ``python -m export.onnx_export``
    writes a trained run: a tiny refining chain of ``export.nets.chain``, untrained, its correction heads
    given random weights (:data:`HEAD_STD`). Exported once per session; skips without torch."""
    torch = _export_or_skip()
    from export.nets.chain import SVBRDFNet, Tier
    from export.onnx_export import IO, export_stage

    folder = tmp_path_factory.mktemp("models") / "chain"
    folder.mkdir()
    with torch.random.fork_rng():  # the session's other tests keep their random stream
        torch.manual_seed(0)
        net = SVBRDFNet(Tier(mask_width=0.25, aux_base=8, map_base=8, depth=3), pretrained=False, refine=True).eval()
        for m in net.maps.values():
            torch.nn.init.normal_(m.decoder.head.weight, std=HEAD_STD)
        for stage in IO:
            export_stage(net, stage, str(folder / f"{stage}.onnx"), size=64)
    return folder
