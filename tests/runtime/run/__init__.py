"""Tests of svbrdf_cli.run."""
