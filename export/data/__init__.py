"""Training data: procedural materials, CC0 material seeds, augmentation, the camera model and the
simulated flash photos of a batch (``dataset.make_batch``)."""
