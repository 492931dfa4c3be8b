"""Stage-by-stage training (paper section IV-A4), resumable, on CPU or GPU.

    python -m export.train --stage masks --tier fast --minutes 20 --out runs/fast
    python -m export.train --stage all --tier fast --steps 3000 --device cuda --size 256 --batch 16

Stages train in order with the earlier ones frozen (their checkpoints must
exist in ``--out``): **masks** (L2), **aux** (L1 + perceptual + WGAN-GP),
**maps** (L1 + rendering loss). Adam with betas (0.5, 0.9), lr 2e-4 (the
backbone encoders at a tenth of it: fine-tuning), halved at 30, 60 and 90 %
of the run (the paper halves every 60k of 200k iterations). With
``--minutes`` the step count is set from the measured time of the first
steps; it is then fixed, stored in the checkpoint, and a resumed run keeps it.

Samples come on the fly from :mod:`export.data.dataset` (its generator's
state is checkpointed, so a resumed run sees the samples the uninterrupted
run would have). Each stage writes ``<out>/<stage>.pt`` (weights, optimiser,
generator, step, history) every ``--checkpoint-every`` steps and at the end,
and ``<out>/provenance.json`` records data, steps, device, time and
validation numbers of every stage.
"""

from __future__ import annotations

import dataclasses
import math
import os
import platform
import time

import click
import torch

from export import losses as loss_terms
from export.data import dataset
from export.files import atomic_torch_save, command_errors, read_json, write_json
from export.nets.chain import (ALL_TIERS, NORMAL_LR_SCALE, STAGES, VARIANTS, build, physical_input, refined_maps,
                               tier_variant)
from svbrdf_cli import conventions as cv
from svbrdf_cli.errors import SvbrdfError
from svbrdf_cli.infer.physical import PHYSICAL_VERSION

#: Ground truth each stage needs from the data engine.
STAGE_TARGETS = {"masks": ("M_b", "M_h"), "aux": ("I_bf", "I_hr", "I_hr2"), "maps": ()}
BETAS = (0.5, 0.9)
LR = 2e-4
BACKBONE_LR_SCALE = 0.1
#: Budget split of ``--stage all`` (the paper trains 200k/200k/300k iterations).
ALL_SPLIT = {"masks": 2 / 7, "aux": 2 / 7, "maps": 3 / 7}
VAL_SEED = 1
VAL_STREAM = 10_000


@dataclasses.dataclass
class RunConfig:
    tier: str = "fast"
    size: int = 128
    batch: int = 8
    seed: int = 0
    device: str = "cpu"
    adversarial: bool = True
    perceptual: bool = True
    val_samples: int = 16
    variant: str = "chain"   # or a Table IV ablation: "nomask", "e2e" (export.nets.chain.VARIANTS)
    refine: bool = True      # the maps stage corrects the physical estimate (svbrdf_cli.infer.physical)
    #: The level of the diffuse targets (see :func:`level_factor`): "convention", what the photo shows
    #: at the conventions' flash power (the physical estimate's reading), or "true", the material's own
    #: albedo (runs before session 12). F0 targets are the material's either way.
    albedo_level: str = "convention"


ALBEDO_LEVELS = ("convention", "true")


def level_factor(batch):
    """(B,) how much brighter the photo's flash lit the surface than the conventions' flash does:
    ``intensity / height^2`` over ``FLASH_INTENSITY / CAMERA_HEIGHT^2`` (the irradiance under the flash).

    The physical estimate (and every capture) reads albedo at the conventions' flash power, since one
    photo cannot tell a dark material under a strong flash from a bright one under a weak flash. Half the
    generated photos are auto-exposed, so their true albedo is that reading divided by this factor, which
    nothing in the photo tells. Trained on the true albedo, a network learns a guess of the exposure
    (session 11's checkpoint made Des19's albedo 1.66x too bright: the best per-sample scale of its
    diffuse and specular had median 0.60), and Des19's inputs, like a capture at the conventions' power,
    need none. Diffuse targets times this factor ask for the reading the photo supports. F0 is left as it
    is, as the estimate leaves it (0.04, a dielectric's constant): scaled too, it asked the network to
    guess the exposure for F0 instead (Des19 specular 0.082 -> 0.135 after 200 steps), and an F0 above
    0.04 on a dielectric is the metal-like specular that engine presets turn into chrome.
    """
    height = batch["capture"]["camera"][:, 2]
    k = batch["intensity"].reshape(-1).double() * cv.CAMERA_HEIGHT ** 2 / (cv.FLASH_INTENSITY * height * height)
    return k.float()


def _stored_targets(batch):
    maps = {k: batch[k] for k in cv.MAP_NAMES}
    if "level" in batch:  # the diffuse at the conventions' flash power (RunConfig.albedo_level)
        maps["diffuse"] = (maps["diffuse"] * batch["level"].reshape(-1, 1, 1, 1).to(maps["diffuse"])).clamp(0, 1)
    return cv.encode_maps(maps)


class StageTrainer:
    """One stage's training state: model, optimisers, data stream, step."""

    def __init__(self, stage, out, config: RunConfig, net=None, bank=None):
        self.stage, self.out, self.cfg = stage, out, config
        self.device = torch.device(config.device)
        if stage not in VARIANTS[config.variant]:
            raise SvbrdfError(f"the {config.variant} variant has no '{stage}' stage "
                              f"(it trains {', '.join(VARIANTS[config.variant])})")
        self.net = net if net is not None else build(config.tier, variant=config.variant,
                                                       refine=config.refine).to(self.device)
        self.bank = bank
        self.data_cfg = dataset.DataConfig(size=config.size, targets=STAGE_TARGETS[stage])
        self.gen = dataset.worker_generator(config.seed, STAGES.index(stage) + 1, "cpu")
        self.step = 0
        self.total = None
        self.elapsed = 0.0
        self.history = []
        self.init = None  # the checkpoint this run started from (StageTrainer.init_from)
        self._val_batch = None
        self._load_frozen()
        module = self.net.stage(stage)
        self.net.requires_grad_(False)
        module.requires_grad_(True)
        groups = []
        if stage == "masks":
            enc = [p for n, p in module.named_parameters() if ".encoder." in n]
            rest = [p for n, p in module.named_parameters() if ".encoder." not in n]
            groups = [{"params": rest, "lr": LR}, {"params": enc, "lr": LR * BACKBONE_LR_SCALE}]
        else:  # a refining end-to-end net's normal branch learns faster (export.nets.chain.NORMAL_LR_SCALE)
            normal = [p for n, p in module.named_parameters() if n.startswith("normal.")]
            rest = [p for n, p in module.named_parameters() if not n.startswith("normal.")]
            groups = [{"params": rest, "lr": LR}] + ([{"params": normal, "lr": LR * NORMAL_LR_SCALE}] if normal else [])
        for gp in groups:
            gp["base_lr"] = gp["lr"]
        self.opt = torch.optim.Adam(groups, betas=BETAS)
        self.features = self.critics = self.critic_opt = None
        if stage == "aux":
            if config.perceptual:
                from export.nets.lite0 import Lite0Features
                self.features = Lite0Features().to(self.device)
            if config.adversarial:
                self.critics = torch.nn.ModuleDict({k: loss_terms.Critic() for k in ("I_bf", "I_hr", "I_hr2")}).to(self.device)
                self.critic_opt = torch.optim.Adam(self.critics.parameters(), lr=LR, betas=BETAS)
        self.path = os.path.join(out, f"{stage}.pt")

    # -- frozen earlier stages and checkpoints ---------------------------------
    def _load_frozen(self):
        for s in STAGES[:STAGES.index(self.stage)]:
            if s not in VARIANTS[self.cfg.variant]:
                continue
            p = os.path.join(self.out, f"{s}.pt")
            if not os.path.exists(p):
                raise SvbrdfError(f"{p}: stage '{s}' must be trained before '{self.stage}'")
            ck = torch.load(p, map_location=self.device, weights_only=False)
            self.net.stage(s).load_state_dict(ck["weights"])

    def state(self):
        return {"stage": self.stage, "weights": self.net.stage(self.stage).state_dict(),
                "optimizer": self.opt.state_dict(), "step": self.step, "total": self.total,
                "elapsed": self.elapsed, "history": self.history, "generator": self.gen.get_state(),
                "critics": self.critics.state_dict() if self.critics is not None else None,
                "critic_optimizer": self.critic_opt.state_dict() if self.critic_opt is not None else None,
                "config": dataclasses.asdict(self.cfg), "conventions": cv.CONVENTIONS_VERSION,
                "physical_version": PHYSICAL_VERSION, "init": self.init}

    def save(self):
        os.makedirs(self.out, exist_ok=True)
        atomic_torch_save(self.state(), self.path)

    def init_from(self, path):
        """Start from the weights of another run's checkpoint where names and shapes match (a new branch
        keeps its initialisation; the optimiser starts fresh). Returns what was taken, in words."""
        ck = torch.load(path, map_location=self.device, weights_only=False)
        if ck.get("stage") != self.stage:
            raise SvbrdfError(f"{path}: is a {ck.get('stage')!r} checkpoint, not {self.stage!r}")
        # (weights trained on another version of the physical estimate start a run as well as any: the
        # network adapts to the new estimate; the run itself records and exports the current version)
        own = self.net.stage(self.stage).state_dict()
        take = {k: v for k, v in ck["weights"].items() if k in own and own[k].shape == v.shape}
        self.net.stage(self.stage).load_state_dict(take, strict=False)
        self.init = {"from": os.path.abspath(path), "step": ck.get("step"), "tensors": len(take),
                     "new_tensors": len(own) - len(take), "physical_version": ck.get("physical_version")}
        return (f"initialised from {path} (step {ck.get('step')}, estimate version {ck.get('physical_version')}): "
                f"{len(take)} tensors, {len(own) - len(take)} new")

    def resume(self):
        if not os.path.exists(self.path):
            return False
        ck = torch.load(self.path, map_location=self.device, weights_only=False)
        if ck["config"]["tier"] != self.cfg.tier:
            raise SvbrdfError(f"{self.path}: was trained as tier {ck['config']['tier']!r}, not {self.cfg.tier!r}")
        if self.cfg.refine and ck.get("physical_version") != PHYSICAL_VERSION:
            raise SvbrdfError(f"{self.path}: refines version {ck.get('physical_version')!r} of the physical "
                              f"estimate, not the current {PHYSICAL_VERSION!r}; start it again with --fresh")
        if ck["config"].get("refine", False) != self.cfg.refine:
            raise SvbrdfError(f"{self.path}: was trained with refine={ck['config'].get('refine', False)}, "
                              f"not {self.cfg.refine}")
        if ck["config"].get("albedo_level", "true") != self.cfg.albedo_level:
            raise SvbrdfError(f"{self.path}: was trained with --albedo-level {ck['config'].get('albedo_level', 'true')}, "
                              f"not {self.cfg.albedo_level}")
        if ck["config"].get("variant", "chain") != self.cfg.variant:
            raise SvbrdfError(f"{self.path}: was trained as variant {ck['config'].get('variant', 'chain')!r}, "
                              f"not {self.cfg.variant!r}")
        self.net.stage(self.stage).load_state_dict(ck["weights"])
        self.opt.load_state_dict(ck["optimizer"])
        self.step, self.total, self.elapsed = ck["step"], ck["total"], ck["elapsed"]
        self.history = ck["history"]
        self.init = ck.get("init")
        self.gen.set_state(ck["generator"])
        if self.critics is not None and ck.get("critics"):
            self.critics.load_state_dict(ck["critics"])
            self.critic_opt.load_state_dict(ck["critic_optimizer"])
        return True

    # -- one step ---------------------------------------------------------------
    def _lr(self):
        done = self.step / max(1, self.total or 1)
        scale = 0.5 ** sum(done >= f for f in (0.3, 0.6, 0.9))
        for gp in self.opt.param_groups:
            gp["lr"] = gp["base_lr"] * scale
        return scale * LR

    def batch(self, generator=None, n=None):
        b = dataset.make_batch(generator or self.gen, n or self.cfg.batch, self.data_cfg, self.bank, device="cpu")
        if self.stage == "maps" and getattr(self.net, "refine", False):
            b["physical"] = physical_input(b["photo"])
        if self.stage == "maps" and self.cfg.albedo_level == "convention":
            b["level"] = level_factor(b)
        return {k: v.to(self.device) for k, v in b.items() if torch.is_tensor(v)}

    def losses(self, b, train=True):
        net, photo = self.net, b["photo"]
        if self.stage == "masks":
            pred = net.run_masks(photo)
            parts = {k: loss_terms.mask_loss(pred[k], b[k]) for k in ("M_b", "M_h")}
            return sum(parts.values()), parts, pred
        with torch.no_grad():
            masks = net.run_masks(photo)
        if self.stage == "aux":
            pred = net.run_aux(photo, masks)
            total, parts = 0, {}
            for k in ("I_bf", "I_hr", "I_hr2"):
                critic = self.critics[k] if (self.critics is not None and train) else None
                t, p = loss_terms.aux_loss(pred[k], b[k], self.features, critic)
                total = total + t
                parts.update({f"{k}_{n}": v for n, v in p.items()})
            return total, parts, pred
        with torch.no_grad():
            aux = net.run_aux(photo, masks)
        pred = net.run_maps(photo, {**aux, "physical": b.get("physical")})
        target = _stored_targets(b)
        lights, cams = loss_terms.random_light_views(photo.shape[0], generator=self.gen if train else
                                            torch.Generator().manual_seed(0), device=self.device)
        total, parts = loss_terms.map_losses(pred, target, lights, cams)
        return total, parts, pred

    def train_step(self):
        self.net.eval()  # frozen stages keep their BatchNorm statistics
        self.net.stage(self.stage).train()
        self._lr()
        b = self.batch()
        self.opt.zero_grad()
        total, parts, pred = self.losses(b)
        total.backward()
        self.opt.step()
        if self.critics is not None:
            self.critic_opt.zero_grad()
            closs = sum(loss_terms.critic_loss(self.critics[k], b[k], pred[k].detach()) for k in self.critics)
            closs.backward()
            self.critic_opt.step()
            parts["critic"] = closs
        self.step += 1
        return float(total.detach()), {k: float(v.detach()) for k, v in parts.items()}

    @torch.no_grad()
    def validate(self):
        """Fixed validation samples (same every time): RMSE per output."""
        module = self.net.stage(self.stage)
        module.eval()
        if self._val_batch is None:  # the same samples every time: make them once
            self._val_batch = self.batch(dataset.worker_generator(VAL_SEED, VAL_STREAM), self.cfg.val_samples)
        b = self._val_batch
        _, _, pred = self.losses(b, train=False)
        ref = _stored_targets(b) if self.stage == "maps" else b
        out = {f"rmse_{k}": float(((pred[k] - ref[k]) ** 2).mean().sqrt()) for k in pred}
        # Trivial baselines on the same samples: a network must beat them.
        for k in pred:
            if self.stage == "masks":
                base = torch.zeros_like(ref[k])               # "no mask"
            elif self.stage == "aux":
                base = b["photo"]                             # "the input is already it"
            elif k == "normal":
                base = ref[k].new_tensor(cv.FLAT_NORMAL_ENCODED).view(1, 3, 1, 1).expand_as(ref[k])
            else:
                base = ref[k].mean((0, 2, 3), keepdim=True).expand_as(ref[k])  # the set's mean value
            out[f"baseline_{k}"] = float(((base - ref[k]) ** 2).mean().sqrt())
            if self.stage == "maps" and "physical" in b:  # what the network refines: it must do better
                phys = refined_maps(b["physical"], torch.zeros_like(b["physical"]))[k]
                out[f"physical_{k}"] = float(((phys - ref[k]) ** 2).mean().sqrt())
        module.train()
        return out


def train_stage(stage, out, config, steps=None, minutes=None, resume=True, checkpoint_every=50,
                val_every=100, progress=True, bank=None, net=None, log=print, until=None, init_from=None):
    """Train one stage; returns the trainer (with its history).

    ``until``: stop (checkpointed) at this step, as an interruption would;
    the run resumes from there. ``init_from``: a checkpoint (``<stage>.pt``) whose weights start a new
    run where names and shapes match (see :meth:`StageTrainer.init_from`).
    """
    from tqdm import tqdm

    t = StageTrainer(stage, out, config, net=net, bank=bank)
    resumed = resume and t.resume()
    if resumed:
        log(f"{stage}: resuming at step {t.step}/{t.total}")
        if steps and int(steps) != t.total:  # a new total: to extend a run, or to end it here (provenance written)
            if int(steps) < t.step:
                raise SvbrdfError(f"{t.path}: already at step {t.step}; give --steps {t.step} or more to end it there")
            log(f"{stage}: the run's total set to {int(steps)} steps (was {t.total})")
            t.total = int(steps)
    elif init_from:
        log(f"{stage}: {t.init_from(init_from)}")
    if t.total is None:
        if steps:
            t.total = int(steps)
        elif not minutes:
            raise SvbrdfError("give --steps or --minutes")
    start = time.perf_counter()
    base_elapsed = t.elapsed
    bar = tqdm(total=t.total, initial=t.step, desc=stage, unit="step", disable=not progress, dynamic_ncols=True)
    last = None
    while t.total is None or t.step < t.total:
        loss, parts = t.train_step()
        t.elapsed = base_elapsed + time.perf_counter() - start
        if t.total is None and t.step >= 2:  # budget -> steps, from the measured pace
            t.total = max(t.step + 1, int(minutes * 60 / (t.elapsed / t.step)))
            bar.total = t.total
            bar.refresh()
        bar.update(1)
        bar.set_postfix(loss=f"{loss:.4f}", lr=f"{t._lr():.1e}")
        t.history.append({"step": t.step, "loss": loss})
        if t.step % val_every == 0 or t.step == t.total:
            last = {"step": t.step, **t.validate()}
            t.history[-1]["val"] = last
            bar.write(f"{stage} step {t.step}: " + " ".join(f"{k}={v:.4f}" for k, v in last.items() if k != "step"))
        if t.step % checkpoint_every == 0 or t.step == t.total:
            t.save()
        if until is not None and t.step >= until:
            t.save()
            bar.close()
            return t
    bar.close()
    if last is None:
        last = {"step": t.step, **t.validate()}
    t.save()
    record_provenance(out, t, last)
    return t


def record_provenance(out, trainer, val):
    path = os.path.join(out, "provenance.json")
    prov = read_json(path)
    cfg = trainer.cfg
    prov.setdefault("stages", {})[trainer.stage] = {
        "tier": cfg.tier, "variant": cfg.variant, "refine": cfg.refine,
        "albedo_level": cfg.albedo_level if trainer.stage == "maps" else None,
        "physical_version": PHYSICAL_VERSION if cfg.refine else None, "steps": trainer.step, "batch": cfg.batch,
        "size": cfg.size, "seed": cfg.seed,
        "device": str(trainer.device) + ("" if trainer.device.type != "cpu" else
                                         f" ({platform.processor() or platform.machine()}, {torch.get_num_threads()} threads)"),
        "seconds": round(trainer.elapsed, 1), "samples_seen": trainer.step * cfg.batch,
        "losses": {"adversarial": cfg.adversarial, "perceptual": cfg.perceptual} if trainer.stage == "aux" else None,
        "validation": val, "final_loss": trainer.history[-1]["loss"] if trainer.history else None,
        "initialised_from": trainer.init,
        "data": {"generator": "export.data.dataset.make_batch", "config": dataset.config_dict(trainer.data_cfg),
                 "cc0_seeds": trainer.bank.names if trainer.bank is not None else [],
                 "validation": f"{cfg.val_samples} samples, seed {VAL_SEED} stream {VAL_STREAM}"},
        "conventions": cv.CONVENTIONS_VERSION, "torch": torch.__version__,
        "finished": time.strftime("%Y-%m-%dT%H:%M:%S"),
    }
    write_json(path, prov)


def load_trained(out, tier=None, device="cpu", stages=STAGES):
    """The network (of the run's tier and variant) with the stage weights found in ``out`` (eval mode)."""
    recorded = list(read_json(os.path.join(out, "provenance.json")).get("stages", {}).values())
    tier = tier or (recorded[0].get("tier") if recorded else "fast")
    variant = recorded[0].get("variant", "chain") if recorded else "chain"
    refine = recorded[0].get("refine", False) if recorded else True  # runs before refinement existed: False
    net = build(tier, pretrained=False, variant=variant, refine=refine).to(device)
    for s in stages:
        if s not in VARIANTS[variant]:
            continue
        p = os.path.join(out, f"{s}.pt")
        if os.path.exists(p):
            # a run from before the normal branch (export.nets.chain.E2E_NORMAL_BASE) lacks only that
            # branch, whose zero head leaves the maps as they were trained
            missing, unexpected = net.stage(s).load_state_dict(
                torch.load(p, map_location=device, weights_only=False)["weights"], strict=False)
            if unexpected or any(not k.startswith("normal.") for k in missing):
                raise SvbrdfError(f"{p}: does not match the {tier} network (missing {missing[:3]}, "
                                  f"unexpected {unexpected[:3]})")
    return net.eval()


def benchmark_rows(tier="fast", size=128, batch=16, repeats=2, log=print):
    """The same rows for a tier of the first training loop (:mod:`export.train`: samples made from
    scratch by :func:`export.data.dataset.make_batch`, the numpy physical estimate per sample, fp32),
    on a throw-away run folder; the baseline the engine is measured against."""
    import contextlib
    import io
    import tempfile

    from export.engine import benchmark as engine_benchmark

    import sys

    old = sys.modules[__name__]
    rows = []
    with tempfile.TemporaryDirectory() as out:
        cfg = old.RunConfig(tier=tier, size=size, batch=batch)
        for stage in old.VARIANTS[old.tier_variant(tier)]:
            with contextlib.redirect_stdout(io.StringIO()):
                t = old.StageTrainer(stage, out, cfg)
            ready = t.batch()

            def step(b=None):
                t.net.eval()
                t.net.stage(stage).train()
                t.opt.zero_grad()
                total, _, _ = t.losses(b if b is not None else ready)
                total.backward()
                t.opt.step()

            data = engine_benchmark.rate(t.batch, batch, repeats)
            stepped = engine_benchmark.rate(step, batch, repeats)
            loop = engine_benchmark.rate(t.train_step, batch, repeats)
            params = sum(p.numel() for p in t.net.stage(stage).parameters())
            rows.append((stage, params, data, stepped, loop))
            log(f"{stage}: data {data:.1f}/s, step {stepped:.1f}/s, loop {loop:.1f}/s")
            t.save()  # the next stage loads this one, frozen
    return rows, size


@click.command()
@click.option("--benchmark", is_flag=True,
              help="Measure data, step and whole-loop samples/s of every stage of the tier (default swift, the "
                   "fast engine's chain, export.engine) and stop; the last line is samples/s=<slowest> size=<size>.")
@click.option("--stage", type=click.Choice(STAGES + ("all",)), default="all", show_default=True)
@click.option("--tier", type=click.Choice(ALL_TIERS + ("swift",)), default=None,
              help="lite: one small end-to-end UNet; fast, balanced, best: the chain at three widths (default "
                   "fast); swift: the fast engine's chain (--benchmark only; train it with python -m export.engine).")
@click.option("--out", type=click.Path(file_okay=False), default=None, help="Run folder (default runs/<tier>).")
@click.option("--steps", type=int, default=None,
              help="Steps per stage (split for --stage all). On a resumed run, its new total: more to extend it, "
                   "its current step to end it there (validation and provenance written).")
@click.option("--minutes", type=float, default=None, help="Time budget instead of --steps (split for --stage all).")
@click.option("--batch", default=8, show_default=True)
@click.option("--size", default=128, show_default=True, help="Training crop size (multiple of 32).")
@click.option("--device", default="cpu", show_default=True)
@click.option("--seed", default=0, show_default=True)
@click.option("--threads", default=0, help="torch threads (0: default).")
@click.option("--fresh", is_flag=True, help="Start over instead of resuming a stage's checkpoint.")
@click.option("--init-from", type=click.Path(exists=True, file_okay=False), default=None,
              help="A run folder whose <stage>.pt weights start this run where names and shapes match.")
@click.option("--no-adversarial", is_flag=True, help="Aux stage without the WGAN-GP term.")
@click.option("--checkpoint-every", default=50, show_default=True)
@click.option("--val-every", default=100, show_default=True)
@click.option("--shared", type=click.Path(file_okay=False), default=None,
              help="Shared data folder with materials/ (CC0 seeds); default ../shared/data.")
@click.option("--refine/--no-refine", default=True, show_default=True,
              help="The maps stage corrects the physical estimate (svbrdf_cli.infer.physical) instead of predicting "
                   "maps from scratch.")
@click.option("--variant", type=click.Choice(tuple(VARIANTS)), default=None,
              help="chain: the paper's model; nomask / e2e: Table IV ablations (aux without masks; "
                   "one UNet from photo to maps with the chain's parameter count). Default: the tier's own.")
@click.option("--albedo-level", type=click.Choice(ALBEDO_LEVELS), default="convention", show_default=True,
              help="The maps stage's diffuse targets: at the conventions' flash power, as the photo and the physical "
                   "estimate read them, or the material's true albedo (runs before session 12). F0: the material's.")
def cli(benchmark, stage, tier, out, steps, minutes, batch, size, device, seed, threads, fresh, init_from,
        no_adversarial, checkpoint_every, val_every, shared, refine, variant, albedo_level):
    """Train the model stage by stage."""
    if benchmark:
        from export.engine import benchmark as engine_benchmark

        rows = benchmark_rows(tier, log=lambda m: None) if tier not in (None, "swift") else None
        engine_benchmark.main(tier or "swift", threads or 1, log=click.echo, rows=rows)
        return
    tier = tier or "fast"
    if tier == "swift":
        raise click.BadParameter("train swift with python -m export.engine train", param_hint="--tier")
    if threads:
        torch.set_num_threads(threads)
    if size % 32:
        raise click.BadParameter("must be a multiple of 32", param_hint="--size")
    try:
        variant = tier_variant(tier, variant)
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="--variant") from None
    out = out or os.path.join("runs", tier if variant == tier_variant(tier) else f"{tier}-{variant}")
    bank = dataset.SeedBank.find(shared)
    cfg = RunConfig(tier=tier, size=size, batch=batch, seed=seed, device=device, adversarial=not no_adversarial,
                    variant=variant, refine=refine, albedo_level=albedo_level)
    stages = VARIANTS[variant] if stage == "all" else (stage,)
    for s in stages:
        share = ALL_SPLIT[s] / sum(ALL_SPLIT[x] for x in stages) if stage == "all" else 1.0
        with command_errors():
            train_stage(s, out, cfg, steps=math.ceil(steps * share) if steps else None,
                        minutes=minutes * share if minutes else None, resume=not fresh,
                        checkpoint_every=checkpoint_every, val_every=val_every, bank=bank,
                        log=click.echo, init_from=os.path.join(init_from, f"{s}.pt") if init_from else None)
    click.echo(f"{out}: " + ", ".join(f"{s}.pt" for s in stages) + ", provenance.json")


if __name__ == "__main__":
    cli()
