"""Tests of svbrdf_cli.rectify."""
