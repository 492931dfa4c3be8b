"""Stage 3 of a capture: the maps from the cropped photo.

The models ``--model`` names (:mod:`.registry`): the physical estimate (:mod:`.physical`), the
onnxruntime networks (:mod:`.chain`) and ``auto`` (:mod:`.auto`); then the fit of the maps to the
photo (:mod:`.geometry`, :mod:`.refine`) and the rotated passes for confidence (:mod:`.tta`).
"""
