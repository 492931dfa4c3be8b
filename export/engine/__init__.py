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
