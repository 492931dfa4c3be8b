"""Training runs of the ``swift`` chain: stage by stage, checkpointed, resumable exactly.

A run is a folder:

* ``state.pt``: every stage's weights, the optimiser of the stage in training, the step, the
  samples seen, the CPU seconds spent and the run's configuration (each step's batch comes from a
  generator seeded by the step: :meth:`Run.step_batch`);
  written every ``checkpoint_minutes`` of wall time and when the process gets SIGTERM or SIGINT
  (it finishes the step, saves, and exits 0);
* ``curve.jsonl``: one line per evaluation (samples seen, CPU hours, stage, the running training
  loss, the generated validation loss of the stage, and Des19 scores of the whole chain, run at
  the run's image size as the runtime runs it: ``des19_size``; the relighting errors of the maps
  ``svbrdf capture`` makes with it, without and with ``--refine``, on the real card, ``card``, and on
  16 generated captures under known lights, ``known_lights``);
* ``log.txt`` when started with ``python -m export.engine background``.

Stages train in the order of ``schedule`` (the paper's: masks, then aux with the masks frozen,
then maps with both frozen); each gets a sample budget, and a fresh Adam (betas 0.5, 0.9, lr 2e-4
halved every ``halve_every`` samples of the stage). Forward passes run under bf16 autocast with
channels-last tensors on a CPU with native bf16 arithmetic (:func:`autocast`), in fp32 elsewhere; losses
and the renderer stay in fp32.

Resuming restores everything a step depends on, so a run stopped at step n and resumed is the
run that never stopped (``tests/export/test_engine.py``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import math
import os
import signal
import time

import numpy as np
import torch
import torch.nn.functional as F

from export.engine import bank as bank_mod
from export.engine import batches, flash, nets
from export.engine import real as real_mod
from export.files import atomic_torch_save
from svbrdf_cli import conventions as cv
from svbrdf_cli.infer.refine import DEFAULT_ITERATIONS

AUX_NAMES = ("I_bf", "I_hr", "I_hr2")
#: Step ``k`` of a run seeded ``s`` draws its batch from a generator seeded ``STEP_SEEDS * (s + 1) + k``
#: (:meth:`Run.step_batch`): above the bank's shard seeds, the validation's and the known-light captures'.
STEP_SEEDS = 10 ** 12


@dataclasses.dataclass
class RunConfig:
    tier: str = "swift"
    size: int = 128
    batch: int = 16
    seed: int = 0
    #: (stage, samples) in order; a stage ends when it has seen its samples.
    schedule: tuple = (("masks", 300_000), ("aux", 400_000), ("maps", 3_000_000))
    lr: float = 2e-4
    halve_every: int = 960_000
    checkpoint_minutes: float = 10.0
    eval_minutes: float = 30.0
    val_samples: int = 64
    #: Materials in the bank (it grows to this; from 8000 on, :data:`export.engine.bank.PRINT_SHARDS`,
    #: :data:`export.engine.bank.DARK_SHARDS` and, from 12032, :data:`export.engine.bank.GREY_SHARDS`).
    bank_count: int = 9152
    bank_root: str | None = None
    #: Share of the maps stage's steps that are self-supervised batches of real photos
    #: (:mod:`export.engine.real`), and the weight of their rendering loss.
    real_fraction: float = 0.25
    real_weight: float = 1.0
    real_root: str | None = None
    #: Maps loss weights: L1 of each map in its stored encoding, ``relief``, the weight of the
    #: tilt-correlation term (:func:`relief_loss`), and ``render``, of the rendering term (:func:`render_loss`).
    weights: tuple = (("normal", 2.0), ("diffuse", 1.0), ("roughness", 1.0), ("specular", 1.0), ("relief", 0.5),
                      ("render", 0.5))
    #: Decay per step of the moving average of the training stage's weights (:meth:`Run.averaged`),
    #: the weights evaluated and exported; 0: none.
    ema_decay: float = 0.9995
    #: The maps stage's F0 target (:data:`svbrdf_cli.conventions.SPECULAR_LEVELS`): the material's, or at
    #: the photo's flash level as the diffuse (an export records it; the runtime then scales F0 as it
    #: scales the diffuse).
    specular_level: str = "absolute"
    #: Where the flash of the networks' context comes from (:data:`export.engine.batches.FLASH_CONTEXTS`): the
    #: true one jittered, or the runtime's fit on the photo.
    flash_context: str = "jitter"
    #: The :data:`JOINT` stage's learning rate (halved as the others' are): a fine-tune of trained stages.
    joint_lr: float = 2e-5


def _config_from(d):
    known = {f.name for f in dataclasses.fields(RunConfig)}
    d = {k: v for k, v in d.items() if k in known}  # (a setting a later version added is left out)
    d["schedule"] = tuple(tuple(x) for x in d["schedule"])
    d["weights"] = tuple(tuple(x) for x in d["weights"])
    return RunConfig(**d)


#: CPU flags (``/proc/cpuinfo``) of native bf16 arithmetic. Without them bf16 autocast is emulated:
#: measured on an AVX2-only AMD EPYC, a maps step of batch 16 at 128² took 0.9 samples/s under it
#: against 4.5 in fp32; with AVX-512 BF16 it gave 11 against 4.4.
BF16_FLAGS = ("avx512_bf16", "amx_bf16")


def native_bf16(cpuinfo="/proc/cpuinfo"):
    """Whether this CPU does bf16 arithmetic natively; ``$SVBRDF_AUTOCAST`` (``bf16`` or ``fp32``) decides
    instead when set."""
    forced = os.environ.get("SVBRDF_AUTOCAST", "").lower()
    if forced in ("bf16", "fp32"):
        return forced == "bf16"
    try:
        with open(cpuinfo) as f:
            flags = next((line.split(":", 1)[1].split() for line in f if line.startswith("flags")), [])
    except OSError:
        return False
    return any(flag in flags for flag in BF16_FLAGS)


@functools.lru_cache(maxsize=1)
def _bf16():
    return native_bf16()


def autocast():
    """The forward passes' autocast: bf16 where the CPU has it natively (:func:`native_bf16`), else off."""
    return torch.autocast("cpu", dtype=torch.bfloat16, enabled=_bf16())


def stage_loss(net, stage, b):
    """The loss of ``stage`` on batch ``b`` (earlier stages frozen, under no_grad; :data:`JOINT`: every
    stage trained, :func:`joint_loss`)."""
    if stage == JOINT:
        return joint_loss(net, b)
    photo, context = b["photo"], b["context"]
    with autocast():
        if stage == "masks":
            return masks_error(net.run_masks(photo, context), b)
        if stage == "aux":
            with torch.no_grad():
                masks = net.run_masks(photo, context).clamp(0, 1)
            return aux_error(net.run_aux(photo, masks, context), b)
        pred = _chain(net, photo, context, b["base"], grad=False)[2]
    return maps_loss(pred, b, net_weights(net))


def masks_error(pred, b):
    """The masks stage's loss: squared error of the predicted ``M_b``, ``M_h`` against batch ``b``'s."""
    return ((pred.float() - torch.cat([b["M_b"], b["M_h"]], 1)) ** 2).mean()


def aux_error(pred, b):
    """The aux stage's loss: L1 of the predicted auxiliary renderings against batch ``b``'s."""
    return (pred.float() - torch.cat([b[k] for k in AUX_NAMES], 1)).abs().mean()


#: The stage after the three of the paper, when a run's schedule names it: the whole chain trained at once
#: from the stages' weights, its masks and auxiliary renderings still held to their targets
#: (:func:`joint_loss`), and the real photos' rendering loss reaching them too (:func:`real_loss`).
JOINT = "joint"
#: :func:`joint_loss`'s default weights of the masks' squared error and the auxiliary renderings' L1 (a run's
#: ``masks`` and ``aux`` weights, :data:`EXTRA_TERMS`, override them). At the end of their own stages these
#: losses were about 0.0015 and 0.05 against the maps' 0.40: weighed so, a drift that doubles either costs a
#: few percent of the maps' loss.
INTERMEDIATE = {"masks": 10.0, "aux": 1.0}
#: The stages whose steps are a share of real photos (:data:`RunConfig.real_fraction`) and carry the rendering
#: term's lights and views.
REAL_STAGES = ("maps", JOINT)


def _chain(net, photo, context, base, grad):
    """(masks, aux, maps) of the chain on a batch, the masks and aux unclamped; the earlier stages under
    no_grad unless ``grad``."""
    with torch.set_grad_enabled(grad and torch.is_grad_enabled()):
        masks = net.run_masks(photo, context)
        seen = masks.clamp(0, 1)
        aux = net.run_aux(photo, seen, context)
    return masks, aux, net.run_maps(photo, seen, aux.clamp(0, 1), base, context)


def joint_loss(net, b):
    """The :data:`JOINT` stage's loss on a synthetic batch ``b``: the maps stage's (:func:`maps_loss`) of the
    chain run end to end, plus the masks' squared error and the auxiliary renderings' L1 against their
    targets (the paper's intermediate losses, :data:`INTERMEDIATE`), every stage in the gradient."""
    weights = net_weights(net)
    with autocast():
        masks, aux, pred = _chain(net, b["photo"], b["context"], b["base"], grad=True)
    inter = weights.get("masks", INTERMEDIATE["masks"]) * masks_error(masks, b)
    return maps_loss(pred, b, weights) + inter + weights.get("aux", INTERMEDIATE["aux"]) * aux_error(aux, b)


def real_loss(net, b, stage="maps"):
    """The rendering loss of the chain's maps on a batch of real photos (earlier stages frozen, or in the
    :data:`JOINT` stage trained too), plus ``weights["real_f0"]`` times F0's shortfall under a dielectric's
    (:func:`export.engine.real.f0_floor_loss`)."""
    photo, light = b["photo"], b["light"]
    context, base = flash.context(light, light, photo.shape[-1]), flash.base(photo, light, light)
    with autocast():
        pred = _chain(net, photo, context, base, grad=stage == JOINT)[2]
    pred = {k: v.float() for k, v in pred.items()}
    loss = real_mod.rendering_loss(pred, photo, light)
    floor = net_weights(net).get("real_f0", 0.0)
    return loss + floor * real_mod.f0_floor_loss(pred["specular"]) if floor else loss


def net_weights(net):
    return getattr(net, "loss_weights", dict(RunConfig.weights))


#: Terms of the maps stage's weights that are not one map's L1: :func:`maps_loss`'s ``relief`` and ``render``,
#: ``real_f0``, :func:`real_loss`'s, and the :data:`JOINT` stage's ``masks`` and ``aux`` (:data:`INTERMEDIATE`).
EXTRA_TERMS = ("relief", "render", "real_f0", "masks", "aux")
#: :func:`render_loss` renders the maps at this side (area-averaged down from the batch's): 4x cheaper
#: than at 128², and what relighting errors are made of (a highlight's level and spread) is broader.
RENDER_SIDE = 64
#: Lights (and views) of each of :func:`render_views`' three configurations.
RENDER_EACH = 3


def maps_loss(pred, target, weights):
    """L1 of each map (stored encodings) plus ``weights["relief"]`` times :func:`relief_loss` and, when the
    batch carries ``lights`` and ``cameras`` (:func:`render_views`; training batches do, validation ones
    not), ``weights["render"]`` times :func:`render_loss`."""
    loss = sum(w * (pred[k].float() - target[k]).abs().mean() for k, w in weights.items() if k not in EXTRA_TERMS)
    if weights.get("relief"):
        loss = loss + weights["relief"] * relief_loss(pred["normal"].float(), target["normal"])
    if weights.get("render") and "lights" in target:
        loss = loss + weights["render"] * render_loss(pred, target, target["lights"], target["cameras"])
    return loss


def render_views(g, batch):
    """(L, B, 3) light and camera positions for :func:`render_loss`, :data:`RENDER_EACH` of each kind:

    * the paper's (Eq. 18, Des18's draws): light and view each from the hemisphere, cosine-distributed,
      2-5 half-widths away (:func:`export.losses.random_light_views`);
    * Des18's specular kind: the view the light's mirror image, shifted by up to half a half-width, so
      the highlight shows in the frame;
    * a flash camera above the surface (its height 0.8-1.2 times the conventions', off centre by up to
      0.3) with the light beside the lens, 0-0.22 of the height away and 0.98-1.13 of it high: the
      geometry of a capture under known lights (``export/engine/known_lights.py``), and of a phone's
      flash seen from a little off its lens.
    """
    from export.losses import random_light_views

    def u(*shape):
        return torch.rand(*shape, generator=g, dtype=torch.float32)

    n = RENDER_EACH
    lights_a, cams_a = random_light_views(batch, n, generator=g)
    lights_b, _ = random_light_views(batch, n, generator=g)
    shift = torch.cat([(u(n, batch, 2) - 0.5), torch.zeros(n, batch, 1)], -1)
    cams_b = lights_b * torch.tensor([-1.0, -1.0, 1.0]) + shift
    h = cv.CAMERA_HEIGHT * (0.8 + 0.4 * u(n, batch, 1))
    cams_c = torch.cat([(u(n, batch, 2) - 0.5) * 0.6, h], -1)
    angle, radius = u(n, batch, 1) * (2 * math.pi), u(n, batch, 1) * 0.22 * h
    lights_c = cams_c * torch.tensor([1.0, 1.0, 0.0]) + torch.cat(
        [radius * angle.cos(), radius * angle.sin(), h * (0.98 + 0.15 * u(n, batch, 1))], -1)
    return torch.cat([lights_a, lights_b, lights_c]), torch.cat([cams_a, cams_b, cams_c])


def render_loss(pred, target, lights, cameras, side=RENDER_SIDE):
    """Mean L1 of log renderings (log(x + 0.01), the paper's and Des18's) of the predicted against the
    true maps under each light and view of ``lights``/``cameras`` (L, B, 3), the maps area-averaged to
    ``side``. The whole predicted set is rendered at once (not one map at a time with the true others, as
    the paper's Eq. 18): relighting is what the known-light captures and the card score, and the L1 terms
    hold each map."""
    from export.losses import rendering_loss

    def linear(maps):
        down = {k: maps[k].float() for k in cv.MAP_NAMES}
        if down["normal"].shape[-1] > side:
            down = {k: F.adaptive_avg_pool2d(v, side) for k, v in down.items()}
        return cv.decode_maps(down, axis=1)

    return rendering_loss(linear(pred), linear(target), lights, cameras)


def relief_loss(pred, target):
    """1 - the correlation of predicted and true tilt (normals' x, y about each sample's mean), the
    batch's mean: the scorer's relief, made a loss.

    Measured on one core (300 steps from the run's checkpoint or from scratch, generated validation):
    under the L1 terms alone the maps stage leaves the normals flat (tilt correlation 0.00-0.05, mean
    |tilt| 0.002 against the truth's 0.097) while the other maps improve, though a network trained on
    the normals alone reaches 0.18 as fast: the other maps' gradients take the shared features, and
    L1's median is flat wherever the tilt's sign is uncertain. This term rewards the tilt's pattern
    whatever its depth."""
    p = pred[:, :2] - pred[:, :2].mean((2, 3), keepdim=True)
    t = target[:, :2] - target[:, :2].mean((2, 3), keepdim=True)
    c = (p * t).sum((1, 2, 3)) / ((p * p).sum((1, 2, 3)) * (t * t).sum((1, 2, 3)) + 1e-8).sqrt()
    return (1 - c).mean()


class Run:
    """One run folder: load or start, train, save, evaluate."""

    def __init__(self, folder, config=None, log=print, des19=None, checkpoint=None):
        self.folder = folder
        self.log = log
        os.makedirs(folder, exist_ok=True)
        path = os.path.join(folder, "state.pt")
        state = None
        if os.path.isfile(path):
            state = torch.load(path, map_location="cpu", weights_only=False)
        elif checkpoint and os.path.isfile(os.path.join(checkpoint, "manifest.json")):
            state = read_compact(checkpoint)
            self._restore_curve(checkpoint)
            log(f"{folder}: resumed from the committed checkpoint {checkpoint}")
        if state is not None:
            self.config = _config_from(state["config"])
            if config is not None and dataclasses.asdict(config)["schedule"] != dataclasses.asdict(self.config)["schedule"]:
                self.config = dataclasses.replace(self.config, schedule=config.schedule)
        else:
            self.config = config or RunConfig()
        c = self.config
        with torch.random.fork_rng():
            torch.manual_seed(c.seed)  # the initial weights are the run's, whatever the process did before
            self.net = nets.build(c.tier)
        self.net.loss_weights = dict(c.weights)
        self.step, self.stage_index, self.stage_samples, self.samples, self.cpu = 0, 0, 0, 0, 0.0
        self.started = None
        self.ema = None
        if state is not None:
            own = self.net.state_dict()
            own.update(state["model"])  # a compact checkpoint leaves out the stages not trained yet
            self.net.load_state_dict(own)
            self.step, self.stage_index = state["step"], state["stage_index"]
            self.stage_samples, self.samples, self.cpu = state["stage_samples"], state["samples"], state["cpu"]
            if state.get("ema"):
                self.ema = {k: v.clone() for k, v in state["ema"].items()}
        self.optimizer = self._optimizer()
        if state is not None and state.get("optimizer") is not None:
            self.optimizer.load_state_dict(state["optimizer"])
        self.bank = None
        self.real = None
        self.prefetch, self.prefetcher, self.prefetched = False, None, 0
        self.des19 = des19
        self.card = None
        self.known_lights = None
        self.stop_requested = False

    # -- state --------------------------------------------------------------------------------
    @property
    def stage(self):
        sched = self.config.schedule
        return sched[self.stage_index][0] if self.stage_index < len(sched) else None

    def trained(self):
        """The module the current stage trains: one stage's network, or for :data:`JOINT` the whole chain."""
        return self.net if self.stage == JOINT else getattr(self.net, self.stage)

    def _optimizer(self):
        if self.stage is None:
            return None
        return torch.optim.Adam(self.trained().parameters(), lr=self._lr(), betas=(0.5, 0.9), fused=True)

    def state(self):
        return {"model": self.net.state_dict(), "optimizer": self.optimizer.state_dict() if self.optimizer else None,
                "step": self.step, "stage_index": self.stage_index,
                "stage_samples": self.stage_samples, "samples": self.samples, "cpu": self.cpu,
                "config": dataclasses.asdict(self.config), "ema": self.ema}

    def save(self):
        atomic_torch_save(self.state(), os.path.join(self.folder, "state.pt"))

    def _restore_curve(self, checkpoint):
        src = os.path.join(checkpoint, "curve.jsonl")
        dst = os.path.join(self.folder, "curve.jsonl")
        if os.path.isfile(src) and not os.path.isfile(dst):
            with open(src) as f, open(dst, "w") as g:
                g.write(f.read())

    def save_compact(self, out):
        """The run's state as files under 25 MB in ``out`` (weights of the stages trained so far, the
        optimiser and counters; the later stages' weights are their seeded start),
        with its curve: what a session commits so the next one resumes exactly."""
        state = self.state()
        done = {s for s, _ in self.config.schedule[:self.stage_index + 1]}
        state["model"] = {k: v for k, v in state["model"].items() if k.split(".")[0] in done}
        write_compact(state, out)
        src = os.path.join(self.folder, "curve.jsonl")
        if os.path.isfile(src):
            with open(src) as f, open(os.path.join(out, "curve.jsonl"), "w") as g:
                g.write(f.read())

    def restart_stage(self, stage):
        """Train ``stage`` again from its seeded start, and the stages after it, under this code's
        loss settings (:class:`RunConfig`'s ``weights``, ``real_fraction``, ``real_weight``); the
        earlier stages keep their weights, and the run's step, samples and CPU time go on counting
        (the curve keeps what the run has spent)."""
        names = [s for s, _ in self.config.schedule]
        if stage not in names:
            raise ValueError(f"{stage!r}: not a stage of this run ({', '.join(names)})")
        index = names.index(stage)
        with torch.random.fork_rng():
            torch.manual_seed(self.config.seed)
            fresh = nets.build(self.config.tier)
        for name in names[index:]:
            if name != JOINT:  # (its weights are the stages')
                getattr(self.net, name).load_state_dict(getattr(fresh, name).state_dict())
        d = RunConfig()
        self.config = dataclasses.replace(self.config, weights=d.weights, real_fraction=d.real_fraction,
                                          real_weight=d.real_weight)
        self.net.loss_weights = dict(self.config.weights)
        self.stage_index, self.stage_samples = index, 0
        self.optimizer = self._optimizer()
        self.ema = None
        self.log(f"stage {stage} restarted at step {self.step} ({self.samples} samples)")

    # -- training -----------------------------------------------------------------------------
    def _lr(self):
        base = self.config.joint_lr if self.stage == JOINT else self.config.lr
        return base * 0.5 ** (self.stage_samples // self.config.halve_every)

    def load_bank(self):
        if self.bank is None:
            root = self.config.bank_root or bank_mod.default_root()
            if bank_mod.count(root) < self.config.bank_count:
                bank_mod.grow(root, self.config.bank_count, progress=self.log)
            # the first bank_count materials, whatever more a bigger run left in the folder
            self.bank = bank_mod.Bank(root, limit_shards=math.ceil(self.config.bank_count / bank_mod.SHARD))
        return self.bank

    def load_real(self):
        """The real training photos (:mod:`export.engine.real`), or False without the shared data."""
        if self.real is None:
            from export.files import shared_data

            root = self.config.real_root or os.path.join(shared_data(), "real")
            train = real_mod.split(root)[0] if os.path.isdir(root) else []
            self.real = real_mod.RealPhotos(train, log=self.log) if train else False
            if self.real:
                self.log(f"real photos: {len(self.real)} in the training pool")
        return self.real

    def step_batch(self, step, stage):
        """What step ``step`` of ``stage`` trains on: ``("real", photos)``, a self-supervised batch of real
        photos (:data:`RunConfig.real_fraction` of the maps stage's steps), else ``("synthetic", batch)``;
        drawn from a generator seeded by the run's seed and the step alone, so that any process makes the
        same (:mod:`export.engine.prefetch`)."""
        c = self.config
        g = torch.Generator().manual_seed(STEP_SEEDS * (c.seed + 1) + step)
        late = stage in REAL_STAGES
        real = late and c.real_fraction > 0 and float(torch.rand(1, generator=g)) < c.real_fraction
        if real and self.load_real():
            return "real", self.real.batch(g, c.batch, c.size)
        b = batches.make(self.load_bank(), g, c.batch, c.size, stage, specular_level=c.specular_level,
                         flash_context=c.flash_context)
        if late and dict(c.weights).get("render"):
            b["lights"], b["cameras"] = render_views(g, c.batch)
        return "synthetic", b

    def train_step(self, made=None):
        """One step of the current stage (on ``made``, its :meth:`step_batch` if another process made it);
        returns its loss."""
        c = self.config
        t0 = time.process_time()
        kind, b = made if made is not None else self.step_batch(self.step, self.stage)
        self.net.train()
        for group in self.optimizer.param_groups:
            group["lr"] = self._lr()
        if kind == "real":
            loss = c.real_weight * real_loss(self.net, b, self.stage)
        else:
            loss = stage_loss(self.net, self.stage, b)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self._update_ema()
        self.step += 1
        self.stage_samples += c.batch
        self.samples += c.batch
        self.cpu += time.process_time() - t0
        if self.stage_samples >= c.schedule[self.stage_index][1]:
            self.log(f"stage {self.stage} done at {self.stage_samples} samples")
            with self.averaged():  # the stage ends with the weights it is evaluated and exported with
                finished = {k: v.detach().clone() for k, v in self.trained().state_dict().items()}
            self.trained().load_state_dict(finished)
            self.stage_index += 1
            self.stage_samples = 0
            self.optimizer = self._optimizer()
            self.ema = None
        return float(loss.detach())

    # -- the moving average of the weights ----------------------------------------------------------
    def _update_ema(self):
        """``ema = decay * ema + (1 - decay) * weights`` for the training stage's parameters (fp32).

        With batch 16 on one core, the weights of successive evaluations differed enough that the
        card's relighting went 0.142 -> 0.153 and Des19's specular 0.074 -> 0.083 within 18k samples:
        the average over the last ~1/(1 - decay) steps (2000 at 0.9995: 32k samples, about 20 minutes of
        the run) is what gets evaluated and exported."""
        decay = self.config.ema_decay
        if not decay:
            return
        params = dict(self.trained().named_parameters())
        with torch.no_grad():
            if self.ema is None:
                self.ema = {k: p.detach().clone() for k, p in params.items()}
            else:
                names = list(self.ema)
                torch._foreach_lerp_([self.ema[k] for k in names], [params[k].detach() for k in names], 1.0 - decay)

    @contextlib.contextmanager
    def averaged(self):
        """The training stage's averaged weights in the network for the duration (a no-op before the
        first step or without an average); the trained weights are put back after."""
        if self.ema is None or self.stage is None:
            yield self.net
            return
        params = dict(self.trained().named_parameters())
        saved = {k: p.detach().clone() for k, p in params.items()}
        with torch.no_grad():
            for k, v in self.ema.items():
                params[k].copy_(v)
        try:
            yield self.net
        finally:
            with torch.no_grad():
                for k, v in saved.items():
                    params[k].copy_(v)

    def request_stop(self, *_):
        self.stop_requested = True

    def train(self, steps=None, minutes=None, evaluate=True, prefetch=False):
        """Train until the schedule ends, ``steps`` more steps, ``minutes`` of wall time or a signal;
        checkpoints as configured; returns the number of steps taken. ``prefetch``: the batches are made
        ahead on the machine's idle CPU time too (:mod:`export.engine.prefetch`; the same run)."""
        old = {s: signal.signal(s, self.request_stop) for s in (signal.SIGTERM, signal.SIGINT)}
        self.prefetch, self.prefetched = prefetch, 0
        try:
            return self._train(steps, minutes, evaluate)
        finally:
            self._close_prefetcher()
            for s, h in old.items():
                signal.signal(s, h)

    def _made(self):
        """The current step's batch if a prefetching child made it (started, or restarted at a new stage,
        here: it forks the run with its bank loaded), else None."""
        if not self.prefetch:
            return None
        p = self.prefetcher
        if p is not None and p.stage != self.stage:
            self._close_prefetcher()
            p = None
        if p is None:
            from export.engine.prefetch import Prefetcher

            self.load_bank()
            if self.stage in REAL_STAGES:
                self.load_real()
            self.prefetcher = Prefetcher(self.step_batch, self.stage, self.step + 1)
            return None
        made = p.take(self.step)
        self.cpu += p.spent()
        self.prefetched += made is not None
        return made

    def _close_prefetcher(self):
        p = self.prefetcher
        if p is not None:
            p.close()
            self.cpu += p.spent()
            self.prefetcher = None

    def _train(self, steps, minutes, evaluate):
        c = self.config
        start = time.time()
        last_save = last_eval = time.time()
        taken, running = 0, []
        last_line, helped_before = time.time(), 0
        while self.stage is not None and not self.stop_requested:
            if steps is not None and taken >= steps:
                break
            if minutes is not None and time.time() - start > minutes * 60:
                break
            running.append(self.train_step(self._made()))
            taken += 1
            if time.time() - last_save > c.checkpoint_minutes * 60:
                self.save()
                last_save = time.time()
            if evaluate and time.time() - last_eval > c.eval_minutes * 60:
                self.record(float(np.mean(running)) if running else None)
                running = []
                last_eval = time.time()
                self.save()
                last_save = time.time()
            if taken % 50 == 0:
                now = time.time()
                helped = f", {self.prefetched - helped_before} of 50 batches made ahead" if self.prefetch else ""
                self.log(f"step {self.step} stage {self.stage} samples {self.samples} "
                         f"loss {np.mean(running[-50:]):.4f} cpu {self.cpu / 3600:.2f} h "
                         f"({50 * c.batch / max(now - last_line, 1e-9):.1f} samples/s{helped})")
                last_line, helped_before = now, self.prefetched
        self.save()
        if evaluate and running:
            self.record(float(np.mean(running)))
        return taken

    # -- evaluation ---------------------------------------------------------------------------
    def _val_batches(self, stage):
        g = torch.Generator().manual_seed(12345)
        n = self.config.val_samples
        return [batches.make(self.load_bank(), g, 16, self.config.size, stage, specular_level=self.config.specular_level,
                             flash_context=self.config.flash_context) for _ in range(max(1, n // 16))]

    @torch.no_grad()
    def validate(self, stage):
        self.net.eval()
        losses = [float(stage_loss(self.net, stage, b)) for b in self._val_batches(stage)]
        return float(np.mean(losses))

    def _load_known_lights(self):
        """The first :data:`KNOWN_LIGHTS_COUNT` generated captures under known lights (made once and kept
        in their cache), or False for a run given its own Des19 (the tests')."""
        if self.des19 is not None:
            return False
        from export.engine.known_lights import captures

        return captures(KNOWN_LIGHTS_COUNT, log=self.log)

    def record(self, train_loss):
        """One line of ``curve.jsonl``, the network evaluated with its averaged weights (``ema``)."""
        stage = self.stage or self.config.schedule[-1][0]
        des19 = self.des19 if self.des19 is not None else load_des19()
        with self.averaged():
            entry = {"samples": self.samples, "cpu_hours": round(self.cpu / 3600, 4), "step": self.step,
                     "stage": stage, "train_loss": train_loss, "val_loss": self.validate(stage), "time": time.time(),
                     "ema": self.ema is not None, "specular_level": self.config.specular_level}
            if des19:
                entry["des19"] = score_des19(self.net, des19, self.config.size, self.config.flash_context)
                entry["des19_size"] = self.config.size
            if self.card is None:
                self.card = (load_card() if self.des19 is None else None) or False
            if self.card:
                entry.update(score_card(self.net, self.card, self.config.size,
                                        specular=self.config.specular_level == "photo"))
            if self.known_lights is None:
                self.known_lights = self._load_known_lights()
            if self.known_lights:
                entry.update(score_known_lights(self.net, self.known_lights, self.config.size,
                                                specular=self.config.specular_level == "photo"))
        with open(os.path.join(self.folder, "curve.jsonl"), "a") as f:
            f.write(json.dumps(entry) + "\n")
        self.log(f"eval: {json.dumps(entry)}")
        return entry


# -- compact checkpoints -----------------------------------------------------------------------
PART_BYTES = 20_000_000


def write_compact(state, out):
    """``state`` as ``part_NN.pt`` files of at most about :data:`PART_BYTES` each (tensors in order,
    grouped by :func:`_part_group`) and ``manifest.json``; old parts are replaced, never left mixed with new ones."""
    import shutil
    import tempfile

    flat, rest = {}, {}

    def walk(prefix, x):
        if torch.is_tensor(x):
            flat[prefix] = x
        elif isinstance(x, dict):
            rest_keys = {}
            for k, v in x.items():
                sub = walk(f"{prefix}/{k}", v)
                if sub is not None:
                    rest_keys[k] = sub
            return rest_keys
        else:
            return x
        return None

    rest = walk("", state)
    parts, current, size, group = [], {}, 0, None
    for k, v in flat.items():
        n = v.numel() * v.element_size()
        if current and (size + n > PART_BYTES or _part_group(k) != group):
            parts.append(current)
            current, size = {}, 0
        current[k] = v
        size += n
        group = _part_group(k)
    parts.append(current)
    parent = os.path.dirname(os.path.abspath(out))
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(dir=parent, prefix=".compact-")
    for i, p in enumerate(parts):
        torch.save(p, os.path.join(tmp, f"part_{i:02d}.pt"))
    with open(os.path.join(tmp, "manifest.json"), "w") as f:
        json.dump({"parts": len(parts), "rest": rest}, f, indent=1, default=str)
    if os.path.isdir(out):
        for name in os.listdir(out):
            if name.startswith("part_") or name in ("manifest.json", "curve.jsonl"):
                os.remove(os.path.join(out, name))
    os.makedirs(out, exist_ok=True)
    for name in os.listdir(tmp):
        os.replace(os.path.join(tmp, name), os.path.join(out, name))
    shutil.rmtree(tmp)


def _part_group(key):
    """Tensors that go in parts of their own: each stage's weights (a finished stage's part is then
    the same file from one commit to the next, stored once by git), the optimiser, the average."""
    names = key.strip("/").split("/")
    return ("model", names[1].split(".")[0]) if names[0] == "model" else names[0]


def read_compact(folder):
    """The state :func:`write_compact` wrote."""
    with open(os.path.join(folder, "manifest.json")) as f:
        m = json.load(f)
    flat = {}
    for i in range(m["parts"]):
        flat.update(torch.load(os.path.join(folder, f"part_{i:02d}.pt"), map_location="cpu", weights_only=True))
    state = m["rest"]
    for key, v in flat.items():
        node = state
        names = key.strip("/").split("/")
        for n in names[:-1]:
            node = node.setdefault(n, {})
        node[names[-1]] = v
    return _fix_int_keys(state)


def _fix_int_keys(x):
    """JSON turned the optimiser's integer keys into strings: turn them back."""
    if isinstance(x, dict):
        return {(int(k) if isinstance(k, str) and k.isdigit() else k): _fix_int_keys(v) for k, v in x.items()}
    return x


# -- Des19 ------------------------------------------------------------------------------------
def load_des19(root=None):
    """[(name, photo (1, 3, 256, 256) encoded, ground truth dict of (H, W, C) numpy as the scorer reads
    them)] or [] without the shared data."""
    from export.files import shared_data
    from svbrdf_cli.imageio import read_image

    root = root or os.path.join(shared_data(), "validation", "des19")
    if not os.path.isdir(root):
        return []
    out = []
    for name in sorted(os.listdir(root)):
        d = os.path.join(root, name)
        if not os.path.isfile(os.path.join(d, "input.png")):
            continue
        photo = torch.from_numpy(read_image(os.path.join(d, "input.png"))[..., :3].copy()).permute(2, 0, 1)[None].float()
        gt = {k: read_image(os.path.join(d, k + ".png"))[..., :3].astype(np.float64) for k in cv.MAP_NAMES}
        out.append((name, photo, gt))
    return out


def relief(pn, gn):
    """The reference scorer's relief: correlation of predicted and true tilt (stored normals)."""
    p = pn[..., :2] * 2 - 1
    g = gn[..., :2] * 2 - 1
    p = (p - p.mean((0, 1))).ravel()
    g = (g - g.mean((0, 1))).ravel()
    den = np.sqrt((p ** 2).sum() * (g ** 2).sum())
    return float((p * g).sum() / den) if den > 1e-9 else 0.0


def des19_geometry(n):
    light = torch.tensor(cv.FLASH_POSITION, dtype=torch.float32).expand(n, 3)
    return light, light


@torch.no_grad()
def predict(net, photo, camera, light, size=None):
    """Stored maps (B, C, H, W) of the whole chain for encoded photos (B, 3, H, W).

    ``size``: run the chain on the photo area-shrunk to ``size``² (the scale it was trained at) and
    bring its maps back bicubically (normals renormalised; :class:`svbrdf_cli.infer.swift.SwiftModel`
    brings the normals and the diffuse back with the photo's detail, :func:`svbrdf_cli.infer.swift.to_photo_size`,
    and the run's curve keeps bicubic to stay comparable along it); None runs it at the photo's size."""
    net.eval()
    h = photo.shape[-1]
    small = F.interpolate(photo, size=(size, size), mode="area") if size and size < h else photo
    context = flash.context(camera, light, small.shape[-1])
    base = flash.base(small, camera, light)
    with autocast():
        masks, aux, maps = net(small, context, base)
    maps = {k: v.float() for k, v in maps.items()}
    if small is not photo:
        maps = {k: F.interpolate(v, size=photo.shape[-2:], mode="bicubic", align_corners=False).clamp(0, 1)
                for k, v in maps.items()}
        n = maps["normal"] * 2 - 1
        n[:, 2:] = n[:, 2:].clamp_min(1e-3)
        maps["normal"] = F.normalize(n, dim=1) * 0.5 + 0.5
    return maps


def runtime_twin(net, size):
    """``net`` as :class:`svbrdf_cli.infer.swift.SwiftModel` runs an export of it, on photos of any size
    (flash fit, the network at ``size``, the physical steps after it), torch in place of onnxruntime."""
    from svbrdf_cli.infer.swift import PASSES, SECOND_PASSES, SwiftModel

    class Twin(SwiftModel):
        def __init__(self):  # what SwiftModel reads from an export's metadata
            self.multiple, self.run_size, self.timings, self.found, self.fit = 32, size, {}, None, None
            self.passes, self.second_passes = PASSES, SECOND_PASSES

        @torch.no_grad()
        def forward(self, feeds):
            net.eval()
            with autocast():
                masks, aux, maps = net(*(torch.from_numpy(feeds[k]) for k in ("photo", "context", "base")))
            return (masks.float().numpy(), aux.float().clamp(0, 1).numpy(),
                    torch.cat([maps[k].float() for k in cv.MAP_NAMES], 1).numpy())

    return Twin()


def load_card():
    """``card_blue_9lights`` (:class:`export.studies.benchmark.NineLights`), or None without the shared data."""
    from export.files import shared_data
    from export.render.relight import NineLights

    folder = os.path.join(shared_data(), "real", "card_blue_9lights")
    return NineLights(folder) if os.path.isdir(folder) else None


def captured_maps(twin, image, refine_steps=DEFAULT_ITERATIONS):
    """The maps ``svbrdf capture`` makes of the encoded ``image`` with ``twin`` (:func:`runtime_twin`):
    as the chain gives them, and after ``--refine refine_steps`` under the geometry estimated from the
    photo alone (no EXIF)."""
    from svbrdf_cli.infer import geometry, refine

    out = twin(image)
    maps = {k: out[k] for k in cv.MAP_NAMES}
    geo = geometry.estimate(image, height=twin.found["flash_height"])
    refined = refine.refine(image, maps, geo, refine_steps).stored
    return maps, {k: refined[k] for k in cv.MAP_NAMES}


def score_card(net, card, size, refine_steps=DEFAULT_ITERATIONS, specular=False):
    """The card's relighting errors of the chain's maps from photo 00 as ``svbrdf capture`` writes them
    (:func:`captured_maps`, the diffuse, and with ``specular`` the F0, brought back to the photo as shot),
    lit as the 8 other photos were: ``{"card": ..., "card_refined": ...}``, the second after ``--refine
    refine_steps`` on the same maps."""
    from svbrdf_cli.infer.exposure import network_gain, photo_level, to_photo_level

    level = photo_level(network_gain(cv.image_to_linear(card.photos[0])))
    maps, refined = (to_photo_level(m, level, specular) for m in
                     captured_maps(runtime_twin(net, size), card.network_input(), refine_steps))
    return {"card": round(card.relight_rmse(maps), 4), "card_refined": round(card.relight_rmse(refined), 4)}


#: Generated captures under known lights the run scores its chain on (the first of the study's 48).
KNOWN_LIGHTS_COUNT = 16


def score_known_lights(net, caps, size, refine_steps=DEFAULT_ITERATIONS, specular=False):
    """The mean relighting errors, on the generated captures ``caps`` (:mod:`export.engine.known_lights`),
    of the chain's maps as ``svbrdf capture`` writes them from each photo 0 (the diffuse, and with
    ``specular`` the F0, at the photo's level as shot): ``{"known_lights": ..., "known_lights_refined":
    ...}``. The card is one real material; these are many, so a state that gains on Des19 and the card
    while it drifts from materials it never saw shows here."""
    from export.engine.known_lights import photo_input, score_as_shot

    twin = runtime_twin(net, size)
    plain, refined = [], []
    for c in caps:
        maps, better = captured_maps(twin, photo_input(c), refine_steps)
        plain.append(score_as_shot(maps, c, specular))
        refined.append(score_as_shot(better, c, specular))
    return {"known_lights": round(float(np.mean(plain)), 4), "known_lights_refined": round(float(np.mean(refined)), 4)}


def score_des19(net, des19, size=None, flash_context="jitter"):
    """The reference scorer's numbers (8-bit maps, linear albedo, adapted roughness) for the chain,
    run at ``size`` (:func:`predict`) on each input exposed as the runtime exposes it
    (:func:`export.engine.batches.runtime_gain`, as the chain is trained), its diffuse then brought
    back to the input's own level (times the inverse gain: ``svbrdf capture``'s ``photo_level``). The
    flash at the conventions' position, or (``flash_context`` "fit", a chain trained on the runtime's
    fit) where the runtime reads it from the input (:func:`export.engine.batches.fitted_flash`)."""
    from export.engine.batches import fitted_flash, runtime_gain

    rows = {k: [] for k in ("normal", "diffuse", "roughness", "specular", "relief")}
    for name, photo, gt in des19:
        gain = runtime_gain(photo)
        exposed = cv.image_to_encoded(cv.image_to_linear(photo) * gain.reshape(-1, 1, 1, 1))
        cam, light = des19_geometry(1) if flash_context != "fit" else (fitted_flash(exposed),) * 2
        pred = predict(net, exposed, cam, light, size)
        p = {k: (v[0].permute(1, 2, 0).numpy().astype(np.float64) * 255).round() / 255 for k, v in pred.items()}
        p["roughness"] = np.repeat(p["roughness"], 3, -1)
        for k in ("diffuse", "specular"):
            p[k] = p[k] ** cv.ALBEDO_GAMMA
        p["diffuse"] = np.clip(p["diffuse"] / float(gain[0]), 0.0, 1.0)
        for k in ("normal", "diffuse", "specular"):
            rows[k].append(np.sqrt(((p[k] - gt[k]) ** 2).mean()))
        rows["relief"].append(relief(p["normal"], gt["normal"]))
        r = (lambda x: 0.9 * x[..., 0] + 0.1)
        rows["roughness"].append(np.sqrt(((r(p["roughness"]) - r(gt["roughness"])) ** 2).mean()))
    return {k: round(float(np.mean(v)), 4) for k, v in rows.items()}
