"""Stage 2 of a capture: the photo cropped to a square of the surface (auto, markers, corners) and
where its flash highlight is."""
