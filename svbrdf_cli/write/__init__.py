"""Stage 4 of a capture: texture sets written, atomically, in each preset's layout (and read back).

:mod:`.presets` (the engines' layouts), :mod:`.atomic` (the all-or-nothing folder), :mod:`.mapset`
(the stored encoding), :mod:`.tiling`, :mod:`.viewer` and :mod:`.gallery`.
"""
