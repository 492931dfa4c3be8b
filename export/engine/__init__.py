"""The fast training engine: a material bank on disk, photos rendered on the fly in torch, small
space-to-depth networks under bf16, and runs that checkpoint, stop on a signal and resume exactly.

* :mod:`export.engine.bank`: materials made once (procedural families, every CC0 set, mixes),
  stored as uint8/int16 shards with a manifest, loaded into memory for training.
* :mod:`export.engine.batches`: one training batch: crops of bank materials, augmented, photographed
  under a sampled camera and flash (:mod:`export.data.simulate`), with the targets and the flash
  geometry context of the stage being trained.
* :mod:`export.engine.flash`: the flash geometry context and the base estimate the networks correct.
* :mod:`export.engine.nets`: the space-to-depth UNets of the ``swift`` chain.
* :mod:`export.engine.run`: training runs (``python -m export.engine``).
"""


def keep_memory():
    """Keep freed memory in this process instead of handing it back to the system: glibc gives large
    blocks back at every ``free`` and faults them in again at the next step (10% of a training step
    in system time, measured). Blocks up to 32 MB (glibc's largest threshold: every activation of a
    step at 128², batch 16) stay in the heap, which is never trimmed; larger ones are still mapped
    and unmapped. No-op without glibc."""
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    try:
        mallopt = ctypes.CDLL(name).mallopt if name else None
    except (OSError, AttributeError):
        return False
    if mallopt is None:
        return False
    m_trim_threshold, m_top_pad, m_mmap_threshold = -1, -2, -3
    return bool(mallopt(m_mmap_threshold, 32 << 20) and mallopt(m_trim_threshold, 1 << 40)
                and mallopt(m_top_pad, 1 << 28))
