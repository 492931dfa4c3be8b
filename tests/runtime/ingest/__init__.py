"""Tests of svbrdf_cli.ingest."""
