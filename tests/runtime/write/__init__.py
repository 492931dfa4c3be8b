"""Tests of svbrdf_cli.write."""
