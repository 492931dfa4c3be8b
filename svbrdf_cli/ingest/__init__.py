"""Stage 1 of a capture: the photo file read into linear pixels (RAW, JPEG, PNG, TIFF, EXR)."""
