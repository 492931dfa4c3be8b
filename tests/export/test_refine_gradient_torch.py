"""The runtime's analytic rendering gradient (numpy, svbrdf_cli.shading) against torch's autograd of
the training renderer (export/render/brdf.py): two implementations of one model must agree."""

import numpy as np
import pytest
import torch

from export.render.brdf import render
from svbrdf_cli import shading


@pytest.mark.parametrize("camera", [None, (0.2, -0.1, 2.6)])
def test_analytic_gradient_matches_torch_autograd(camera):
    rng = np.random.default_rng(5)
    size = 16
    tilt = rng.normal(0, 0.4, (size, size, 2))
    diffuse = rng.uniform(0.05, 0.9, (size, size, 3))
    rough = rng.uniform(0.1, 0.9, (size, size, 1))
    spec = rng.uniform(0.02, 0.7, (size, size, 3))
    light_pos = (-0.3, 0.4, 2.1)
    radiance, backward = shading.render_with_gradient(tilt, diffuse, rough, spec,
                                                      shading.Lighting(size, size, light_pos, camera))
    weights = rng.normal(size=radiance.shape)
    ours = backward(weights)

    def t(x):
        return torch.tensor(np.moveaxis(x, -1, 0)[None], dtype=torch.float64, requires_grad=True)

    tt, dt, rt, st = t(tilt), t(diffuse), t(rough), t(spec)
    m = torch.cat([tt, torch.ones_like(tt[:, :1])], 1)
    normal = m / m.norm(dim=1, keepdim=True)
    out = render(normal, dt, rt, st, light=light_pos, camera=camera)
    assert np.allclose(np.moveaxis(out.detach().numpy()[0], 0, -1), radiance, rtol=1e-4, atol=1e-6)
    (out * torch.tensor(np.moveaxis(weights, -1, 0)[None])).sum().backward()
    for name, x in (("tilt", tt), ("diffuse", dt), ("roughness", rt), ("specular", st)):
        theirs = np.moveaxis(x.grad.numpy()[0], 0, -1)
        assert np.allclose(ours[name], theirs, rtol=1e-3, atol=1e-5 * np.abs(theirs).max()), name
