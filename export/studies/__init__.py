"""Studies and benchmarks, each run as ``python -m export.studies.NAME``: they score the runtime
and the trained networks and write the tables and figures of ``docs/``."""
