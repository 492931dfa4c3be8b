"""Parsing option values: numbers, corners, exposure stops, models (a usage error, exit 2, when malformed)."""

import math

import click

from svbrdf_cli.infer.chain import ModelError, installed_tiers
from svbrdf_cli.infer.exposure import MAX_EXPOSURE_STOPS
from svbrdf_cli.infer.registry import AUTO, check_model, model_names


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
    """``--corners X1,Y1,...,X4,Y4`` -> four (x, y) pixel corners."""
    parts = numbers(8, "x1,y1,...,x4,y4 in pixels")(ctx, param, value)
    return None if parts is None else tuple(zip(parts[0::2], parts[1::2]))


def exposure(ctx, param, value):
    """``--exposure auto|STOPS`` -> None (auto) or the stops, within the limits."""
    if value is None or value == "auto":
        return None
    try:
        return stops(ctx, param, float(value))
    except (ValueError, click.BadParameter):  # (BadParameter: NaN, infinite, out of range)
        raise click.BadParameter(f"expected 'auto' or stops within ±{MAX_EXPOSURE_STOPS:g}; got '{value}'.") from None


def stops(ctx, param, value):
    """An exposure change in stops, finite and within ±MAX_EXPOSURE_STOPS."""
    if value is None or not abs(value) <= MAX_EXPOSURE_STOPS:
        raise click.BadParameter(f"expected stops within ±{MAX_EXPOSURE_STOPS:g}; got '{value}'.")
    return value


def positive(ctx, param, value):
    """A finite number above 0 (or nothing)."""
    if value is not None and not (math.isfinite(value) and value > 0):
        raise click.BadParameter(f"expected a finite number above 0; got '{value}'.")
    return value


def light(ctx, param, value):
    """X,Y,Z of a light above the surface (Z > 0)."""
    xyz = numbers(3, "X,Y,Z")(ctx, param, value)
    if xyz is not None and xyz[2] <= 0:
        raise click.BadParameter(f"the light must be above the surface (Z > 0); got '{value}'.")
    return xyz


def model_value(ctx, param, value):
    """``--model``: a name that is not installed, or a folder that does not exist, is a usage error."""
    try:
        check_model(value)
    except ModelError as e:
        raise click.BadParameter(str(e)) from None
    return value


def model_help():
    """``--model``'s help: what it accepts, naming the networks installed here (only those)."""
    tiers = installed_tiers()
    auto = ""
    if AUTO in model_names():
        auto = (f", '{AUTO}' (per photo, the cheapest of physical and the installed networks that is good enough for it)"
                if tiers else f", '{AUTO}' (per photo, the cheapest installed model good enough for it: with no network "
                              "installed, physical)")
    described = {"swift": "swift: the trained masks -> auxiliary renderings -> maps chain"}
    return ("'physical' (the maps computed from the flash physics alone)"
            + (f", an installed network ({', '.join(described.get(t, t) for t in tiers)})" if tiers else "")
            + auto + " or a folder of exported models.")
