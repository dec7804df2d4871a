"""Training of the motion prior (``recon.video.prior``) on mocap's train split.

Each sample is a window of a mocap clip (train-split performers only; val and test subjects stay
out) on a body of a random shape, seen by a still camera at a random bearing, height and distance.
Its clean J+ are the target; the input is the same window with the per-frame pass's noise as
eval/motion_noise.py measured it on the validation clips (``eval/results/motion-noise.json``):

* each joint's local rotation off by a bias per window and a wobble, split into a slow part
  (correlation 0.97 a frame: indistinguishable from motion, so the network learns to leave it) and
  a fast part, chosen so that together they have the measured deviation and frame-to-frame
  correlation; the body's shape off by the measured spread. The noisy J+ are a body's, as the
  per-frame pass's always are (noise drawn on the points themselves taught an earlier prior to
  undo bone-length errors the real input never has);
* the root's error relative to its depth, drawn the same way in each window's camera;
* the whole noise scaled by a random factor per window, and gaps (frames not seen) bridged
  linearly, as ``smooth.fill_gaps`` bridges them.

Losses: the root-relative J+ (L1, metres) and the root's features (L1) as two terms, their
accelerations (L1), and the feet's planted flags
(binary cross-entropy; planted as eval/video.py scores foot skating, ``recon.metrics.planted_feet``,
over the window).

    OMP_NUM_THREADS=2 .venv/bin/python scripts/train_motion_prior.py   # -> recon/video/weights/motion_prior.pt
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import roma
import torch

from recon import metrics, report
from recon.body import default_body
from recon.body.base import BodyModel
from recon.poses.mocap import MocapPoses
from recon.poses.sampler import ShapeSampler
from recon.video import prior as motion_prior

NOISE = report.RESULTS / "motion-noise.json"
SLOW_RHO = 0.97


@dataclass
class PriorTrainConfig:
    steps: int = 3000
    batch: int = 32
    frames: int = 96
    lr: float = 2e-3
    seed: int = 0
    windows: int = 5000  # mocap windows posed (each on a random body) and made noisy once, then sampled
    noise_scale: tuple[float, float] = (0.2, 1.5)  # x the measured noise, per window
    # the joints' rotation noise (its bias and slow part; its fast part further) scaled so that at
    # scale 1 the noisy J+ have the measured J+ error and acceleration error: measured per joint, the
    # errors are drawn independently here, while the real ones partly cancel along a limb
    calibration: tuple[float, float] = (0.5, 0.75)
    gap_share: float = 0.3  # windows with a gap of unseen frames
    distance: tuple[float, float] = (3.0, 9.0)  # m, camera to the person
    elevation: tuple[float, float] = (-5.0, 25.0)  # degrees the camera looks down


class Motions:
    """Windows of the mocap clips of one split, posed on random bodies: clean, and as the
    per-frame pass would see them (``Noise``), as world J+."""

    def __init__(self, body: BodyModel, split: str, frames: int, seed: int):
        mocap = MocapPoses.load(split)
        self.body, self.frames = body, frames
        self.shapes = ShapeSampler(body, seed=seed)
        self.clips = [idx for c in np.unique(mocap.clip) if len(idx := np.flatnonzero(mocap.clip == c)) >= frames]
        self.rot = roma.rotvec_to_rotmat(torch.tensor(mocap.rotvec))
        self.transl = torch.tensor(mocap.transl)

    def bank(self, n: int, noise: Noise, cfg: PriorTrainConfig, gen: torch.Generator, chunk: int = 16) -> dict:
        """n windows: clean and noisy world J+ (n, T, 42, 3), planted feet (n, T, 2)."""
        lengths = torch.tensor([len(c) - self.frames + 1 for c in self.clips], dtype=torch.float)
        out = {"clean": [], "noisy": [], "planted": []}
        lo, hi = cfg.noise_scale
        for a in range(0, n, chunk):
            m = min(chunk, n - a)
            pick = torch.multinomial(lengths, m, replacement=True, generator=gen).tolist()
            idx = torch.stack([torch.as_tensor(self.clips[c][int(torch.randint(int(lengths[c]), (1,), generator=gen)):]
                                               [:self.frames]) for c in pick])
            rot, transl = self.rot[idx].flatten(0, 1), self.transl[idx].flatten(0, 1)
            shape = self.shapes.sample(m)
            scale = lo + (hi - lo) * torch.rand(m, generator=gen)
            turn, dshape = noise.pose(m, self.frames, scale, gen)
            noisy_rot = rot @ roma.rotvec_to_rotmat(turn.flatten(0, 1))
            with torch.no_grad():
                clean = self.body(rot, shape.repeat_interleave(self.frames, 0), transl=transl, points_only=True).points
                noisy_shape = (shape + dshape).clamp(0, 1).repeat_interleave(self.frames, 0)
                noisy = self.body(noisy_rot, noisy_shape, transl=transl, points_only=True).points
            clean, noisy = clean.unflatten(0, (m, self.frames)), noisy.unflatten(0, (m, self.frames))
            noisy = noisy - noisy[:, :, :1] + clean[:, :, :1]  # the root's error: drawn in the camera (Noise.root)
            out["clean"].append(clean)
            out["noisy"].append(noisy)
            out["planted"].append(metrics.planted_feet(clean[:, :, list(motion_prior.FEET)]))
        return {k: torch.cat(v) for k, v in out.items()}


def cameras(world: torch.Tensor, cfg: PriorTrainConfig, gen: torch.Generator, *more: torch.Tensor
            ) -> list[torch.Tensor]:
    """The windows' J+ (n, T, 42, 3) seen by a still camera each (OpenCV: y down, z forward)
    looking at the window's mean root from a random bearing, elevation and distance; ``more``:
    other J+ of the same windows seen by the same cameras."""
    n = world.shape[0]
    u = lambda lo, hi: lo + (hi - lo) * torch.rand(n, generator=gen)  # noqa: E731
    yaw = u(0, 2 * math.pi)
    el = torch.deg2rad(u(*cfg.elevation))
    dist = u(*cfg.distance)
    target = world[:, :, 0].mean(1)
    back = torch.stack([torch.cos(el) * torch.sin(yaw), torch.sin(el), torch.cos(el) * torch.cos(yaw)], -1)
    eye = target + dist[:, None] * back
    z = -back
    up = torch.tensor([0.0, 1.0, 0.0]).expand(n, 3)
    y = -(up - (up * z).sum(-1, keepdim=True) * z)
    y = y / y.norm(dim=-1, keepdim=True)
    x = torch.cross(y, z, dim=-1)
    r = torch.stack([x, y, z], 1)  # rows: the camera's axes in the world
    return [torch.einsum("nij,ntpj->ntpi", r, w - eye[:, None, None]) for w in (world, *more)]


def ar_noise(sigma: torch.Tensor, rho: torch.Tensor, n: int, t: int, gen: torch.Generator) -> torch.Tensor:
    """(n, t, *sigma.shape) stationary AR(1) noise with these per-channel deviations and correlations."""
    e = torch.randn(n, t, *sigma.shape, generator=gen)
    out = torch.empty_like(e)
    out[:, 0] = e[:, 0]
    inno = (1 - rho ** 2).clamp_min(0).sqrt()
    for k in range(1, t):
        out[:, k] = rho * out[:, k - 1] + inno * e[:, k]
    return out * sigma


class Noise:
    """The per-frame pass's noise (module doc) from eval/motion_noise.py's measurement."""

    def __init__(self, measured: dict, calibration: tuple[float, float] = (1.0, 1.0)):
        def split(sigma, rho):
            sigma, rho = torch.tensor(sigma), torch.tensor(rho)
            fast = (sigma ** 2 * (SLOW_RHO - rho).clamp_min(0) / SLOW_RHO).clamp_max(sigma ** 2)
            return (sigma ** 2 - fast).sqrt(), fast.sqrt()
        self.turn_bias = torch.tensor(measured["turn_bias_sigma"])
        self.turn_slow, self.turn_fast = split(measured["turn_sigma"], measured["turn_rho"])
        self.turn_bias, self.turn_slow = self.turn_bias * calibration[0], self.turn_slow * calibration[0]
        self.turn_fast = self.turn_fast * calibration[0] * calibration[1]
        self.shape = torch.tensor(measured["shape_sigma"])
        self.root_bias = torch.tensor(measured["root_bias_sigma"])
        self.root_slow, self.root_fast = split(measured["root_sigma"], measured["root_rho"])

    def pose(self, n: int, t: int, scale: torch.Tensor, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """Rotation offsets (n, t, 24, 3) of the joints (axis-angle, each in its joint's frame) and
        body shape offsets (n, S; anny's phenotypes: the caller keeps them in [0, 1]), scaled by ``scale`` (n,)."""
        e = self.turn_bias * torch.randn(n, 1, *self.turn_bias.shape, generator=gen)
        e = e + ar_noise(self.turn_slow, torch.full_like(self.turn_slow, SLOW_RHO), n, t, gen)
        e = e + self.turn_fast * torch.randn(n, t, *self.turn_fast.shape, generator=gen)
        shape = self.shape * torch.randn(n, len(self.shape), generator=gen) * scale[:, None]
        return e * scale[:, None, None, None], shape

    def root(self, points: torch.Tensor, scale: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
        """Camera-frame J+ (n, T, 42, 3) moved as a whole by the root's error (relative to its depth)."""
        n, t = points.shape[:2]
        e = self.root_bias * torch.randn(n, 1, 3, generator=gen)
        e = e + ar_noise(self.root_slow, torch.full_like(self.root_slow, SLOW_RHO), n, t, gen)
        e = e + self.root_fast * torch.randn(n, t, 3, generator=gen)
        return points + (scale[:, None, None] * e * points[:, :, 0, 2:])[:, :, None, :]


def bridge(x: torch.Tensor, seen: torch.Tensor) -> torch.Tensor:
    """Unseen frames of (T, ...) linearly between the nearest seen ones (held at the ends)."""
    idx = torch.nonzero(seen).flatten()
    out = x.clone()
    for f in torch.nonzero(~seen).flatten().tolist():
        after, before = idx[idx > f], idx[idx < f]
        if not len(before) or not len(after):
            out[f] = x[after[0] if len(after) else before[-1]]
            continue
        a, b = int(before[-1]), int(after[0])
        w = (f - a) / (b - a)
        out[f] = (1 - w) * x[a] + w * x[b]
    return out


def batch(bank: dict, noise: Noise, cfg: PriorTrainConfig, gen: torch.Generator, n: int):
    """Inputs (noisy J+, seen), clean J+ and planted flags of n windows of the ``bank``
    (``Motions.bank``), each in a random camera with the root's error drawn there, and gaps."""
    pick = torch.randint(len(bank["clean"]), (n,), generator=gen)
    clean, noisy = cameras(bank["clean"][pick], cfg, gen, bank["noisy"][pick])
    lo, hi = cfg.noise_scale
    noisy = noise.root(noisy, lo + (hi - lo) * torch.rand(n, generator=gen), gen)
    seen = torch.ones(n, clean.shape[1], dtype=torch.bool)
    for i in torch.nonzero(torch.rand(n, generator=gen) < cfg.gap_share).flatten().tolist():
        length = int(torch.randint(3, 21, (1,), generator=gen))
        a = int(torch.randint(1, clean.shape[1] - length - 1, (1,), generator=gen))
        seen[i, a:a + length] = False
        noisy[i] = bridge(noisy[i], seen[i])
    return noisy, seen, clean, bank["planted"][pick]


def losses(prior: motion_prior.MotionPrior, noisy, seen, clean, plant) -> dict:
    x, mean = motion_prior.features(noisy, seen)
    y = prior(x)
    target, clean_mean = motion_prior.features(clean, seen)
    out = x[..., :-1] + y[..., :-2]
    tgt = target[..., :-1].clone()
    tgt[..., -3:] += clean_mean - mean  # the clean root as the network sees roots: less the noisy track's mean
    acc = lambda v: v[:, 2:] - 2 * v[:, 1:-1] + v[:, :-2]  # noqa: E731
    err, aerr = (out - tgt).abs(), (acc(out) - acc(tgt)).abs()
    rel, root = slice(0, motion_prior.POINTS * 3), slice(motion_prior.POINTS * 3, None)
    return {"position": err[..., rel].mean(), "root": err[..., root].mean(),
            "acceleration": (aerr[..., rel].mean() + aerr[..., root].mean()) * 10,
            "planted": torch.nn.functional.binary_cross_entropy_with_logits(y[..., -2:], plant.float()) * 0.1}


def evaluate(prior, data) -> dict:
    """mm: the J+ (root-relative) and their acceleration against the clean ones, input and output."""
    noisy, seen, clean, plant = data
    with torch.no_grad():
        out, planted = motion_prior.apply(prior, noisy, seen)
    rel = lambda p: p - p[..., :1, :]  # noqa: E731
    acc = lambda v: v[:, 2:] - 2 * v[:, 1:-1] + v[:, :-2]  # noqa: E731
    err = lambda a, b: float((rel(a) - rel(b)).norm(dim=-1).mean() * 1000)  # noqa: E731
    aerr = lambda a, b: float((acc(rel(a)) - acc(rel(b))).norm(dim=-1).mean() * 1000)  # noqa: E731
    root = lambda a: float((a[..., 0, :] - clean[..., 0, :]).norm(dim=-1).mean() * 1000)  # noqa: E731
    return {"mpjpe_in": err(noisy, clean), "mpjpe_out": err(out, clean), "accel_in": aerr(noisy, clean),
            "accel_out": aerr(out, clean), "root_mm_in": root(noisy), "root_mm_out": root(out),
            "planted_accuracy": float(((planted > 0.5) == plant).float().mean())}


def train(out: Path, cfg: PriorTrainConfig | None = None, pcfg: motion_prior.PriorConfig | None = None,
          noise_file: Path = NOISE, log=print) -> dict:
    cfg = cfg or PriorTrainConfig()
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    body = default_body()
    noise = Noise(json.loads(Path(noise_file).read_text()), cfg.calibration)
    t0 = time.perf_counter()
    train_bank = Motions(body, "train", cfg.frames, cfg.seed).bank(cfg.windows, noise, cfg, gen)
    val = batch(Motions(body, "val", cfg.frames, cfg.seed + 1).bank(256, noise, cfg, gen), noise, cfg,
                torch.Generator().manual_seed(12345), 256)
    log(f"data: {cfg.windows} windows of {cfg.frames} frames ({time.perf_counter() - t0:.0f} s)")
    prior = motion_prior.MotionPrior(pcfg)
    opt = torch.optim.AdamW(prior.parameters(), lr=cfg.lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, cfg.lr, total_steps=cfg.steps, pct_start=0.05)
    best, history = None, []
    for step in range(1, cfg.steps + 1):
        prior.train()
        parts = losses(prior, *batch(train_bank, noise, cfg, gen, cfg.batch))
        loss = sum(parts.values())
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(prior.parameters(), 1.0)
        opt.step()
        sched.step()
        if step % 250 == 0 or step == cfg.steps:
            prior.eval()
            m = evaluate(prior, val) | {"step": step, "minutes": (time.perf_counter() - t0) / 60}
            history.append(m)
            log(json.dumps({k: round(v, 3) for k, v in m.items()}))
            if best is None or m["mpjpe_out"] + m["accel_out"] < best["mpjpe_out"] + best["accel_out"]:
                best = m
                meta = {"train": asdict(cfg), "noise": Path(noise_file).name,
                        "best": best, "history": history}
                motion_prior.save(prior, out, meta)
    return {"best": best, "history": history, "seconds": time.perf_counter() - t0}
