"""What every model ``--model`` names offers the capture (:class:`Model`).

The physical estimate (:class:`svbrdf_cli.infer.physical.PhysicalModel`), a network
(:class:`svbrdf_cli.infer.chain.Chain`) and ``auto`` (:class:`svbrdf_cli.infer.auto.AutoModel`) all
have these members, so the capture hands them over without asking what they are.
"""

from __future__ import annotations

from typing import Protocol


class Model(Protocol):
    """A model, ready to run on one encoded photo after another."""

    #: Seconds of each part of the last call (``material.json``'s timings).
    timings: dict

    def __call__(self, image) -> dict:
        """Maps of one photo.

        Args:
            image: (H, W, 3) float32 photo in [0, 1], encoded (sRGB-like gamma), exposed as the
                networks were trained (:func:`svbrdf_cli.infer.exposure.network_input`).

        Returns:
            {name: (H, W, C) float32} with the four maps of :data:`svbrdf_cli.conventions.MAP_NAMES`
            in their stored encoding (roughness one channel), plus what the model shows on the way
            (masks, auxiliary renderings, the fitted flash) for ``--debug``, and optionally
            ``hidden``, an (H, W) bool mask where the highlight hid the albedo without clipping: the
            capture gives the diffuse the photo's own fine detail there at the output size
            (:func:`svbrdf_cli.infer.physical.photo_detail_under_highlight`).
        """

    @property
    def used(self) -> Model:
        """The model that made the last outputs (itself, or the tier ``auto`` chose)."""

    @property
    def found(self) -> dict | None:
        """The physical estimate's findings for the last photo (flash foot and height, roughness,
        F0), when the model computed the estimate; else None."""

    @property
    def any_size(self) -> bool:
        """Whether the model runs at any image size (the capture then runs it again at the output
        size instead of upsampling its maps)."""

    def describe(self) -> dict:
        """What ``material.json`` records of the model."""
