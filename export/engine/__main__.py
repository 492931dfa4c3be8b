"""``python -m export.engine COMMAND``: see :mod:`export.engine.cli`."""

from export.engine.cli import main

main()
