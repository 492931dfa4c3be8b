"""The ``svbrdf`` command line: a thin layer over the library (the library never imports click)."""
