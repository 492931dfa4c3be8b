"""``python -m export.studies.refine_eval --prior NAME=VALUE``: the prior weights it measures."""

import click
import pytest

from export.studies.refine_eval import parse_priors
from svbrdf_cli.infer import refine


def test_no_prior_given_keeps_the_defaults():
    assert parse_priors(()) is None


def test_a_prior_changes_that_weight_only():
    p = parse_priors(("specular=10", "normal=0.2"))
    default = refine.Priors()
    assert p.specular == 10.0 and p.normal == 0.2
    assert p.diffuse == default.diffuse and p.dielectric == default.dielectric


@pytest.mark.parametrize("bad", ["specular", "shine=1", "specular="])
def test_a_bad_prior_is_refused_with_the_names_it_takes(bad):
    with pytest.raises(click.BadParameter, match="smooth_specular"):
        parse_priors((bad,))
