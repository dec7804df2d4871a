"""The one training loop: learning-rate schedule, periodic validation, best and last
checkpoints, resume, a progress bar, log lines and a JSON learning curve.

Every trainer (SMPLR stages, the backbone, the keypoint adapter, PBNS, the outfit resizer)
builds its networks, optimiser and batches, then hands them to ``Trainer.fit`` with a step
function (batch -> loss, and optionally named terms to log) and a validation function
(-> named metrics). With an ``out_dir`` the state is checkpointed at every validation
(modules, optimiser, step, history, elapsed time, random-number generators) and a new
``Trainer`` on the same folder resumes from it: an interrupted run, continued, gives the run
it would have given.
"""
from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from recon.errors import ReconError
from recon.paths import atomic_write, write_text

log = logging.getLogger(__name__)


@dataclass
class Schedule:
    """Learning-rate factor over training progress p in [0, 1]: a cosine ramp from ``start`` to
    1 over the first ``warmup`` of training, then a cosine decay to ``floor``.
    ``Schedule()`` is plain cosine annealing to 0; ``Schedule(warmup=0.3, start=0.04,
    floor=4e-6)`` is the one-cycle shape (PyTorch's OneCycleLR defaults, without its momentum
    cycling)."""

    warmup: float = 0.0
    start: float = 1.0
    floor: float = 0.0

    def __call__(self, progress: float) -> float:
        p = min(max(progress, 0.0), 1.0)
        if p < self.warmup:
            return 1.0 + (self.start - 1.0) * 0.5 * (1.0 + math.cos(math.pi * p / self.warmup))
        q = (p - self.warmup) / (1.0 - self.warmup) if self.warmup < 1.0 else 1.0
        return self.floor + (1.0 - self.floor) * 0.5 * (1.0 + math.cos(math.pi * q))


def _rng_state(g):
    return g.get_state() if isinstance(g, torch.Generator) else g.bit_generator.state


def _set_rng_state(g, state) -> None:
    if isinstance(g, torch.Generator):
        g.set_state(state)
    else:
        g.bit_generator.state = state


def run_dir_for(out: Path) -> Path:
    """Where an interrupted training of ``out`` keeps its state (removed once ``out`` is written)."""
    return out.parent / f".{out.stem}.run"


class Trainer:
    """``Trainer(modules, optimizer, steps, ...).fit(batches, step, validate) -> log``.

    Args:
        modules: the trained networks by name (saved and restored together).
        optimizer: its parameter groups' learning rates are the peak rates; the schedule scales them.
        steps: total optimiser steps (the schedule's length).
        schedule: learning-rate factor over progress.
        eval_every: validate (and checkpoint) every this many steps, and at the end.
        out_dir: checkpoint folder (``state.pt``, ``optimizer.pt``, ``best.pt``, ``curve.json``);
            None keeps everything in memory.
        select: the validation metric whose minimum is the best checkpoint (None: no selection).
        minutes: wall-clock budget; the schedule follows steps or time, whichever is further.
        run_minutes: stop this invocation after this long (checkpointed; run again to resume).
        generators: random-number generators (torch or numpy) the batches draw from, saved and
            restored with the state; the global torch generator always is.
        config: what made this run (stored with the state and the curve).
        identity: the part of the config a resumed run must share (default: all of it);
            resuming with another one is refused.
        extra: stored in ``best.pt`` beside the weights (e.g. the network's config).
        steps_per_epoch: adds an "epoch" column to the curve.
    """

    def __init__(self, modules: dict[str, nn.Module], optimizer: torch.optim.Optimizer, steps: int, *,
                 schedule: Schedule | None = None, eval_every: int | None = None, out_dir: str | Path | None = None,
                 select: str | None = None, minutes: float = 0.0, run_minutes: float = 0.0, desc: str = "train",
                 generators: Sequence = (), config: dict | None = None, identity: dict | None = None,
                 extra: dict | None = None,
                 steps_per_epoch: int | None = None, progress: bool = True):
        self.modules, self.optimizer, self.steps = modules, optimizer, int(steps)
        self.schedule = schedule or Schedule()
        self.eval_every = eval_every or self.steps
        self.out_dir = None if out_dir is None else Path(out_dir)
        self.select, self.minutes, self.run_minutes = select, minutes, run_minutes
        self.desc, self.generators, self.progress = desc, list(generators), progress
        self.config = json.loads(json.dumps(config or {}))  # as stored: tuples become lists
        self.identity = self.config if identity is None else json.loads(json.dumps(identity))
        self.extra, self.steps_per_epoch = extra or {}, steps_per_epoch
        self.base_lrs = [g["lr"] for g in optimizer.param_groups]
        self.step, self.best, self.history, self.seconds = 0, math.inf, [], 0.0
        self.best_state: dict | None = None
        self.resumed = self._resume()

    # --- checkpoints ------------------------------------------------------------------------
    def _resume(self) -> bool:
        if self.out_dir is None or not (self.out_dir / "state.pt").exists():
            return False
        s = torch.load(self.out_dir / "state.pt", map_location="cpu", weights_only=True)
        if s.get("identity", {}) != self.identity:
            raise ReconError(f"{self.out_dir} holds a run with other settings: remove it to start again, "
                             "or give another folder")
        for name, m in self.modules.items():
            m.load_state_dict(s["modules"][name])
        device = next((p.device for g in self.optimizer.param_groups for p in g["params"]), torch.device("cpu"))
        self.optimizer.load_state_dict(torch.load(self.out_dir / "optimizer.pt", map_location=device,
                                                  weights_only=True))
        self.step, self.best, self.history, self.seconds = s["step"], s["best"], s["history"], s["seconds"]
        torch.set_rng_state(s["rng"])
        for g, state in zip(self.generators, s["generators"], strict=True):
            _set_rng_state(g, state)
        log.info("%s: resuming at step %d of %d", self.desc, self.step, self.steps)
        return True

    def _checkpoint(self, elapsed: float) -> None:
        if self.out_dir is None:
            return
        state = {"modules": {k: m.state_dict() for k, m in self.modules.items()}, "step": self.step,
                 "best": self.best, "history": self.history, "seconds": elapsed, "config": self.config,
                 "identity": self.identity,
                 "rng": torch.get_rng_state(), "generators": [_rng_state(g) for g in self.generators]}
        # optimiser moments apart from the weights: each file stays small enough to move around
        atomic_write(self.out_dir / "optimizer.pt", lambda t: torch.save(self.optimizer.state_dict(), t))
        atomic_write(self.out_dir / "state.pt", lambda t: torch.save(state, t))
        write_text(self.out_dir / "curve.json", json.dumps({"config": self.config, "history": self.history}, indent=1))

    def _record(self, row: dict, elapsed: float) -> None:
        self.history.append(row)
        log.info("%s: %s", self.desc, ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                                                for k, v in row.items()))
        value = row.get(self.select) if self.select else None
        if value is not None and value < self.best:
            self.best = value
            self.best_state = {k: {n: t.detach().clone() for n, t in m.state_dict().items()}
                               for k, m in self.modules.items()}
            if self.out_dir is not None:
                best = {**self.best_state, "step": self.step, "metrics": row, **self.extra}
                atomic_write(self.out_dir / "best.pt", lambda t: torch.save(best, t))
        self._checkpoint(elapsed)

    def load_best(self) -> None:
        """Put the best validation checkpoint's weights back into the modules."""
        state = self.best_state
        if state is None and self.out_dir is not None and (self.out_dir / "best.pt").exists():
            state = torch.load(self.out_dir / "best.pt", map_location="cpu", weights_only=True)
        if state is None:
            raise ReconError(f"{self.desc}: no validated checkpoint to load")
        for k, m in self.modules.items():
            m.load_state_dict(state[k])

    # --- the loop ---------------------------------------------------------------------------
    def validate_now(self, validate: Callable[[], dict], tag: str = "eval") -> dict:
        """Validate without training (e.g. the starting point of a fine-tuning run) and record it."""
        row = {"step": self.step, "tag": tag, **validate()}
        self._record(row, self.seconds)
        return row

    def fit(self, batches: Iterable, step: Callable, validate: Callable[[], dict] | None = None) -> dict:
        """Train until ``steps`` (or the time budget). ``step(batch)`` returns the loss, or
        (loss, {name: value}) to log running means of terms; ``validate()`` returns metrics.
        Returns {"steps", "best", "history", "seconds"}."""
        t0 = time.time()
        bar = tqdm(total=self.steps, initial=self.step, desc=self.desc, unit="step", mininterval=10,
                   disable=not self.progress)
        sums: dict[str, float] = {}
        count = 0
        done = self.step >= self.steps
        it = iter(batches)
        while not done:
            elapsed = self.seconds + time.time() - t0
            progress = self.step / self.steps
            if self.minutes > 0:
                progress = max(progress, elapsed / (60.0 * self.minutes))
            factor = self.schedule(progress)
            for g, base in zip(self.optimizer.param_groups, self.base_lrs, strict=True):
                g["lr"] = base * factor
            out = step(next(it))
            loss, terms = out if isinstance(out, tuple) else (out, {})
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            self.optimizer.step()
            self.step += 1
            bar.update(1)
            count += 1
            for k, v in {"loss": loss, **terms}.items():
                sums[k] = sums.get(k, 0.0) + float(v.detach().mean() if torch.is_tensor(v) else v)
            elapsed = self.seconds + time.time() - t0
            done = self.step >= self.steps or (self.minutes > 0 and elapsed >= 60.0 * self.minutes)
            done = done or (self.run_minutes > 0 and time.time() - t0 >= 60.0 * self.run_minutes)
            if self.step % self.eval_every == 0 or done:
                row = {"step": self.step}
                if self.steps_per_epoch:
                    row["epoch"] = self.step / self.steps_per_epoch
                row |= {"seconds": round(elapsed, 1), "lr": self.optimizer.param_groups[0]["lr"]}
                row |= {k: s / count for k, s in sums.items()}
                sums, count = {}, 0
                if validate is not None:
                    row |= validate()
                self._record(row, elapsed)
                bar.set_postfix({k: f"{v:.4g}" for k, v in row.items() if k.startswith("val_")})
        bar.close()
        self.seconds += time.time() - t0
        return {"steps": self.step, "best": self.best, "history": self.history, "seconds": self.seconds}


def epoch_batches(n: int, batch: int, start_step: int = 0,
                  generator: torch.Generator | np.random.Generator | None = None, epochs: int | None = None):
    """Index batches (LongTensor) of a permutation of range(n) per epoch, the incomplete last
    batch dropped, from optimiser step ``start_step`` on (resume). The permutation of an epoch
    is drawn when the epoch starts, from torch's global generator or ``generator`` (torch or
    numpy), so a run resumed at an epoch boundary (where the trainers here validate and
    checkpoint) draws what the uninterrupted one would have."""
    per = n // batch
    if per == 0:
        raise ReconError(f"{n} training samples cannot fill one batch of {batch}")
    epoch, offset = divmod(start_step, per)
    while epochs is None or epoch < epochs:
        if isinstance(generator, np.random.Generator):
            order = torch.from_numpy(generator.permutation(n))
        else:
            order = torch.randperm(n, generator=generator)
        for b in range(offset, per):
            yield order[b * batch:(b + 1) * batch]
        epoch, offset = epoch + 1, 0
