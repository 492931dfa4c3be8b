"""Regenerate ``brdf_golden.npz``: fixed directions and parameters -> BRDF values.

    python tests/data/make_brdf_golden.py

The values come from a scalar, pure-``math`` evaluation written directly
from the formulas (not from ``svbrdf_cli/shading.py`` or
``export/render/brdf.py``), so the table checks both array implementations
independently:

* GGX D (Walter et al. 2007, Eq. 33): a^2 / (pi ((n.h)^2 (a^2-1) + 1)^2)
* Smith-Schlick G1 (Karis 2013): n.w / (n.w (1-k) + k), k = a/2 (Des18)
* Schlick F (Schlick 1994): F0 + (1 - F0)(1 - v.h)^5
* f = d (1 - s) / pi + D F G / (4 (n.l)(n.v)), a = max(r, r_min)^2

The only shared inputs are the documented constants of
``svbrdf_cli.conventions`` (denominator floor EPS, MIN_ROUGHNESS), which are
part of the convention being tested. Rows include grazing angles, r = 0 and
r = 1, tilted normals and lights below the horizon.
"""

import math
import os
import random
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", ".."))
from svbrdf_cli import conventions as cv  # noqa: E402


def unit(x, y, z):
    s = math.sqrt(x * x + y * y + z * z)
    return (x / s, y / s, z / s)


def sph(theta_deg, phi_deg):
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return unit(math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t))


def dot(a, b):
    return sum(x * y for x, y in zip(a, b))


def scalar_brdf(n, l, v, d, r, s):
    """Returns (f (3,), D, vis, F (3,)) for one configuration."""
    h = unit(l[0] + v[0], l[1] + v[1], l[2] + v[2])
    a = max(min(r, 1.0), cv.MIN_ROUGHNESS) ** 2
    nh = min(max(dot(n, h), 0.0), 1.0)
    nl = min(max(dot(n, l), 0.0), 1.0)
    nv = min(max(dot(n, v), 0.0), 1.0)
    vh = min(max(dot(v, h), 0.0), 1.0)
    D = a * a / (math.pi * max(nh * nh * (a * a - 1.0) + 1.0, cv.EPS) ** 2)
    k = a / 2.0
    # G / (n.l n.v) = G1(l) G1(v) / (n.l n.v) = 1 / ((nl(1-k)+k)(nv(1-k)+k)), floored like Des18.
    vis = 1.0 / (max(nl * (1.0 - k) + k, cv.EPS) * max(nv * (1.0 - k) + k, cv.EPS))
    F = [sc + (1.0 - sc) * (1.0 - vh) ** 5 for sc in s]
    f = [dc * (1.0 - sc) / math.pi + D * Fc * vis / 4.0 for dc, sc, Fc in zip(d, s, F)]
    return f, D, vis, F


def rows():
    rng = random.Random(20261122)
    flat = (0.0, 0.0, 1.0)
    fixed = [
        # (n, l, v, d, r, s): hand-picked cases
        (flat, flat, flat, (0.5, 0.5, 0.5), 0.5, (0.04, 0.04, 0.04)),
        (flat, flat, flat, (1.0, 1.0, 1.0), 1.0, (0.0, 0.0, 0.0)),
        (flat, flat, flat, (0.2, 0.3, 0.4), 0.0, (0.9, 0.6, 0.3)),     # r = 0: mirror peak, finite
        (flat, sph(30, 0), sph(30, 180), (0.1, 0.2, 0.3), 0.3, (0.5, 0.5, 0.5)),  # mirror configuration
        (flat, sph(89.9, 0), sph(89.9, 180), (0.5, 0.5, 0.5), 0.2, (0.04, 0.04, 0.04)),  # grazing
        (flat, sph(90, 0), sph(90, 90), (0.5, 0.5, 0.5), 0.5, (0.04, 0.04, 0.04)),     # both at horizon
        (flat, sph(120, 0), flat, (0.5, 0.5, 0.5), 0.5, (0.04, 0.04, 0.04)),            # light below horizon
        (sph(40, 45), flat, flat, (0.3, 0.3, 0.3), 0.4, (0.2, 0.2, 0.2)),               # tilted normal
        (sph(85, 10), flat, flat, (0.3, 0.3, 0.3), 0.01, (1.0, 1.0, 1.0)),              # near-edge normal, r tiny
        (flat, sph(60, 0), sph(10, 0), (0.0, 0.0, 0.0), 1.0, (1.0, 0.5, 0.0)),          # pure specular, r = 1
    ]
    out = list(fixed)
    for _ in range(90):
        n = sph(rng.uniform(0, 60), rng.uniform(0, 360))
        l = sph(rng.uniform(0, 89), rng.uniform(0, 360))
        v = sph(rng.uniform(0, 89), rng.uniform(0, 360))
        d = tuple(rng.uniform(0, 1) for _ in range(3))
        s = tuple(rng.uniform(0, 1) for _ in range(3))
        out.append((n, l, v, d, rng.choice([0.0, 1.0, rng.uniform(0, 1)]), s))
    return out


def main():
    cols = {k: [] for k in ("n", "l", "v", "diffuse", "roughness", "specular", "f", "D", "vis", "F")}
    for n, l, v, d, r, s in rows():
        f, D, vis, F = scalar_brdf(n, l, v, d, r, s)
        for k, x in zip(cols, (n, l, v, d, [r], s, f, D, vis, F)):
            cols[k].append(x)
    path = os.path.join(os.path.dirname(__file__), "brdf_golden.npz")
    np.savez_compressed(path, **{k: np.asarray(v, dtype=np.float64) for k, v in cols.items()})
    print(f"wrote {path} ({len(cols['f'])} rows)")


if __name__ == "__main__":
    main()
