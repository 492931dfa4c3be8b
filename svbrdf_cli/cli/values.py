"""Parsing option values: numbers, corners, exposure stops (a usage error, exit 2, when malformed)."""

import math

import click

from svbrdf_cli.pipeline import MAX_EXPOSURE_STOPS


def numbers(count, what, positive=False):
    """A callback parsing ``count`` comma-separated finite numbers (``what`` says what they are)."""
    def parse(ctx, param, value):
        if value is None:
            return None
        try:
            parts = tuple(float(x) for x in value.split(","))
        except ValueError:
            parts = ()
        if len(parts) != count or not all(map(math.isfinite, parts)):
            raise click.BadParameter(f"expected {count} comma-separated finite numbers ({what}); got '{value}'.")
        if positive and min(parts) <= 0:
            raise click.BadParameter(f"{what} must be positive.")
        return parts
    return parse


def corners(ctx, param, value):
    parts = numbers(8, "x1,y1,...,x4,y4 in pixels")(ctx, param, value)
    return None if parts is None else tuple(zip(parts[0::2], parts[1::2]))


def exposure(ctx, param, value):
    if value is None or value == "auto":
        return None
    try:
        stops = float(value)
    except ValueError:
        stops = math.nan
    if not abs(stops) <= MAX_EXPOSURE_STOPS:  # NaN and infinities too
        raise click.BadParameter(f"expected 'auto' or stops within ±{MAX_EXPOSURE_STOPS:g}; got '{value}'.")
    return stops
