"""Training losses: zero for a perfect prediction, larger for a worse one, and the paper's weights."""

import pytest
import torch
import torch.nn.functional as F

from export import losses
from svbrdf_cli import conventions as cv

SIZE = 16


def _stored(batch=2, diffuse=0.5, roughness=0.5, specular=0.2, tilt=0.0):
    """Stored-encoding (B, C, H, W) maps, constant; ``tilt`` turns the normal towards +x."""
    n = cv.normalize(torch.tensor([tilt, 0.0, 1.0]))
    return {"normal": cv.encode_normals(n).reshape(1, 3, 1, 1).expand(batch, 3, SIZE, SIZE).clone(),
            "diffuse": torch.full((batch, 3, SIZE, SIZE), diffuse),
            "roughness": torch.full((batch, 1, SIZE, SIZE), roughness),
            "specular": torch.full((batch, 3, SIZE, SIZE), specular)}


def _views(batch=2, seed=0):
    return losses.random_light_views(batch, generator=torch.Generator().manual_seed(seed))


class _Linear(torch.nn.Module):
    """A critic D(x) = <w, x> per sample, whose gradient is w everywhere."""

    def __init__(self, w):
        super().__init__()
        self.w = w

    def forward(self, x):
        return (x * self.w).sum((1, 2, 3))


def test_mask_loss_is_the_mean_squared_error():
    a, b = torch.zeros(2, 1, 4, 4), torch.full((2, 1, 4, 4), 0.5)
    assert float(losses.mask_loss(a, a)) == 0.0
    assert float(losses.mask_loss(a, b)) == pytest.approx(0.25)


def test_random_light_views_lie_on_the_upper_hemisphere_at_two_to_five():
    lights, cams = _views(batch=3)
    assert lights.shape == cams.shape == (losses.RENDER_LIGHTS, 3, 3)
    for p in (lights, cams):
        d = p.norm(dim=-1)
        assert bool((d >= 2 - 1e-5).all() and (d <= 5 + 1e-5).all()) and bool((p[..., 2] > 0).all())
    assert not torch.equal(lights, cams)
    again, _ = _views(batch=3)
    assert torch.equal(lights, again)  # the generator decides them


def test_map_losses_are_zero_for_the_truth_and_grow_with_the_error():
    lights, cams = _views()
    gt = _stored()
    total, parts = losses.map_losses(gt, gt, lights, cams)
    assert set(parts) == {n + s for n in cv.MAP_NAMES for s in ("", "_render")}
    assert float(total) == pytest.approx(0.0, abs=1e-6)
    near, _ = losses.map_losses(_stored(diffuse=0.55), gt, lights, cams)
    far, far_parts = losses.map_losses(_stored(diffuse=0.8), gt, lights, cams)
    assert 0 < float(near) < float(far)
    # Only the wrong map is penalised: the others are rendered with the ground truth.
    assert float(far_parts["diffuse"]) == pytest.approx(0.3, abs=1e-6) and float(far_parts["diffuse_render"]) > 0
    assert all(float(far_parts[n]) == 0 and float(far_parts[n + "_render"]) == pytest.approx(0, abs=1e-6)
               for n in ("normal", "roughness", "specular"))
    weighted = sum(losses.MAP_WEIGHTS["rec"] * far_parts[n] + losses.MAP_WEIGHTS["render"] * far_parts[n + "_render"]
                   for n in cv.MAP_NAMES)
    assert float(far) == pytest.approx(float(weighted))


def test_a_wrong_normal_is_seen_only_through_the_rendering():
    lights, cams = _views()
    gt = _stored()
    _, small = losses.map_losses(_stored(tilt=0.1), gt, lights, cams, names=("normal",))
    _, large = losses.map_losses(_stored(tilt=0.6), gt, lights, cams, names=("normal",))
    assert set(small) == {"normal", "normal_render"}
    assert 0 < float(small["normal_render"]) < float(large["normal_render"])


def test_map_losses_give_gradients_to_the_prediction():
    lights, cams = _views()
    pred = {k: v.clone().requires_grad_(True) for k, v in _stored(roughness=0.3).items()}
    total, _ = losses.map_losses(pred, _stored(), lights, cams)
    total.backward()
    assert float(pred["roughness"].grad.abs().sum()) > 0
    assert float(pred["diffuse"].grad.abs().sum()) == pytest.approx(0, abs=1e-6)  # already right


def test_rendering_loss_compares_log_renderings():
    lights, cams = _views()
    gt = cv.decode_maps(_stored(), axis=1)
    assert float(losses.rendering_loss(gt, gt, lights, cams)) == 0.0
    darker = dict(gt, diffuse=gt["diffuse"] * 0.5)
    brighter = dict(gt, diffuse=gt["diffuse"] * 1.5)
    assert 0 < float(losses.rendering_loss(brighter, gt, lights, cams)) < float(losses.rendering_loss(darker, gt, lights, cams))


def test_aux_loss_weights_its_parts():
    target = torch.rand(2, 3, SIZE, SIZE, generator=torch.Generator().manual_seed(1))
    pred = (target + 0.1).clamp(0, 1)
    total, parts = losses.aux_loss(target, target)
    assert set(parts) == {"rec"} and float(total) == 0.0
    critic = _Linear(torch.full((1, 3, SIZE, SIZE), 0.01))
    total, parts = losses.aux_loss(pred, target, features=lambda x: [x, F.avg_pool2d(x, 2)], critic=critic)
    assert set(parts) == {"rec", "percep", "adv"}
    assert float(parts["rec"]) == pytest.approx(float((pred - target).abs().mean()))
    assert float(parts["adv"]) == pytest.approx(-float(critic(pred).mean()))
    assert float(total) == pytest.approx(sum(losses.AUX_WEIGHTS[k] * float(v) for k, v in parts.items()))


def test_perceptual_loss_is_a_relative_feature_error():
    def features(x):
        return [x, F.avg_pool2d(x, 2), F.avg_pool2d(x, 4)]

    g = torch.Generator().manual_seed(2)
    target = torch.rand(2, 3, SIZE, SIZE, generator=g)
    pred = target + 0.05 * torch.randn(2, 3, SIZE, SIZE, generator=g)
    assert float(losses.perceptual_loss(features, target, target)) == 0.0
    loss = float(losses.perceptual_loss(features, pred, target))
    assert loss > 0
    # Divided by the target features' magnitude: scaling both leaves it unchanged.
    assert float(losses.perceptual_loss(features, 4 * pred, 4 * target)) == pytest.approx(loss, rel=1e-5)
    assert float(losses.perceptual_loss(features, target + 0.2 * torch.randn(2, 3, SIZE, SIZE, generator=g), target)) > loss


def test_gradient_penalty_of_a_linear_critic_is_its_slope_off_one():
    real, fake = torch.rand(3, 3, 8, 8), torch.rand(3, 3, 8, 8)
    w = torch.randn(1, 3, 8, 8, generator=torch.Generator().manual_seed(3))
    unit = _Linear(w / w.norm())
    assert float(losses.gradient_penalty(unit, real, fake)) == pytest.approx(0.0, abs=1e-6)
    assert float(losses.gradient_penalty(_Linear(3 * w / w.norm()), real, fake)) == pytest.approx(4.0, rel=1e-5)
    # Eq. 15: with a 1-Lipschitz critic only the Wasserstein estimate is left.
    expected = float(unit(fake).mean() - unit(real).mean())
    assert float(losses.critic_loss(unit, real, fake)) == pytest.approx(expected, abs=1e-5)


def test_critic_scores_each_sample_on_its_own():
    torch.manual_seed(0)
    critic = losses.Critic(base=4, levels=2)
    x = torch.rand(3, 3, SIZE, SIZE)
    scores = critic(x)
    assert scores.shape == (3,)
    # No batch statistics: a sample's score does not depend on the rest of the batch (the GP needs it).
    assert torch.allclose(critic(x[1:2]), scores[1:2], atol=1e-6)
