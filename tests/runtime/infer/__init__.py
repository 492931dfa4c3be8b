"""Tests of svbrdf_cli.infer."""
