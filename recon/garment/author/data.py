"""The authoring model's data (``recon garment train --model author``, stage 1): the hanging part
of an outfit simulated through mocap chunks with randomly drawn *intrinsic parameters* (fabric,
environment, solver damping), the dataset of Wang et al. 2019 (section 3.6) on our outfits.

The simulator is NCS's teacher (``ncs.data.Teacher``: PBNS's energies plus inertia, integrated
implicitly frame by frame; recon.garment.integrate): the project's own dynamic solver, much faster
than newton's VBD on the hanging part (times: the model card), and the solver whose default fabric
NCS learnt, so "NCS with default parameters" is a fair baseline. Per parameter set
the fabric's terms are rescaled (``fabric``); friction, which the teacher lacks, enters as a
velocity filter at contacts (``integrate.contact_friction``).

Splits: held-out parameter sets (a Latin-hypercube draw) x windows of the val (tuning) and test
performers' clips; train parameter sets x chunks of the train performers' clips. The train part is
a sequence that only grows: set ``s`` is the ``s``-th point of a scrambled Halton sequence and gets
the train chunks ``s * train_chunks ...`` (the clips' chunks, reshuffled each time they run out),
and the folder's key leaves ``train_sets`` out, so a dataset of N sets is the first N of any
larger one: ``train_sets`` can be raised and the job continued (days of simulation) while models
are trained on its prefixes (the learning curve). Each simulation settles ``settle`` frames on its
first pose; its first ``lead`` frames are not used (the swing builds up from rest there).
Simulations run in ``workers`` processes, val and test first, each kept in ``<cache>/author-sims/``
as it is done (resumable).
"""
from __future__ import annotations

import hashlib
import json
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.stats import qmc
from tqdm import tqdm

from recon import paths
from recon.body import default_body
from recon.body.base import BodyModel
from recon.executor import ExecutorConfig, WorkerSpec, map_strict
from recon.garment import losses, store
from recon.garment.ncs.config import NCSTrainConfig
from recon.garment.ncs.data import Chunk, Motions, Teacher, chunks_of
from recon.garment.pbns.model import PBNS
from recon.timing import add_seconds


@dataclass(frozen=True)
class Intrinsics:
    """Everything but the motion that shapes the cloth: multipliers of the outfit's trained fabric
    (edge stiffness, bending stiffness, density, gravity) and, absolute, the share of the cloth's
    velocity relative to the body kept a frame (air and fabric damping) and the contact friction."""
    stretch: float = 1.0
    bend: float = 1.0
    mass: float = 1.0
    gravity: float = 1.0
    damping: float = 0.95
    friction: float = 0.0

    def vector(self) -> np.ndarray:
        """The parameters as the ranges scale them (log for the multipliers), each in [0, 1]."""
        return np.array([_to_unit(getattr(self, k), *RANGES[k]) for k in NAMES])


# name: (low, high, log-uniform); wide enough that one motion gives visibly different cloth, narrow
# enough that the solver stays sound (stiffer edges than x3 need more than 20 iterations a frame)
RANGES = {"stretch": (0.3, 3.0, True), "bend": (0.1, 10.0, True), "mass": (0.5, 2.0, True),
          "gravity": (0.6, 1.4, False), "damping": (0.85, 0.99, False), "friction": (0.0, 0.6, False)}
NAMES = tuple(RANGES)


def _to_unit(x: float, lo: float, hi: float, log: bool) -> float:
    return float((np.log(x / lo) / np.log(hi / lo)) if log else (x - lo) / (hi - lo))


def _from_unit(u: float, lo: float, hi: float, log: bool) -> float:
    return float(lo * (hi / lo) ** u if log else lo + u * (hi - lo))


def sample_intrinsics(n: int, seed: int, extendable: bool = False) -> list[Intrinsics]:
    """``n`` parameter sets spread over the ranges: a Latin hypercube, or with ``extendable`` the
    first ``n`` points of a scrambled Halton sequence (those of ``n`` + 1 start with these)."""
    d = len(NAMES)
    u = (qmc.Halton(d=d, seed=seed) if extendable else qmc.LatinHypercube(d=d, seed=seed)).random(n)
    return [Intrinsics(**{k: round(_from_unit(x, *RANGES[k]), 4) for k, x in zip(NAMES, row)}) for row in u]


def cycled_chunks(split: str, frames: int, n: int, seed: int) -> list[Chunk]:
    """``n`` chunks of a split's clips: all of them in a random order, again in another order when
    they run out, and so on (the first ``n`` of ``n`` + 1 are the ``n``'s)."""
    out: list[Chunk] = []
    for epoch in range(n):
        if len(out) >= n:
            break
        more = chunks_of(split, frames, n - len(out), seed + 7919 * epoch)
        if not more:
            raise ValueError(f"the {split} clips have no chunk of {frames} frames")
        out += more
    return out


def fabric(cfg: NCSTrainConfig, p: Intrinsics) -> NCSTrainConfig:
    """The teacher's configuration with ``p``'s fabric: gravity's weight is mass x g, inertia's mass."""
    return replace(cfg, edge=losses.EdgeConfig(cfg.edge.weight * p.stretch),
                   bend=losses.BendConfig(cfg.bend.weight * p.bend),
                   gravity=losses.GravityConfig(cfg.gravity.weight * p.mass * p.gravity),
                   inertia=losses.InertiaConfig(cfg.inertia.weight * p.mass, keep_velocity=p.damping))


@dataclass
class AuthorDataConfig:
    outfit: str = "tshirt-skirt"
    train_sets: int = 32  # parameter sets simulated on the train performers' motion
    train_chunks: int = 2  # chunks per train set
    # train sets simulated on the same chunks (1: each set its own; k: k materials on each motion)
    motion_share: int = 1
    chunk: int = 90  # frames a train chunk
    val_sets: int = 2  # held-out parameter sets on windows of the val performers (tuning)
    val_windows: int = 2
    test_sets: int = 4  # held-out parameter sets on windows of the test performers (the tables)
    test_windows: int = 3
    window: int = 200  # frames a val or test window (a clip to author)
    settle: int = 10  # frames on a simulation's first pose, before it
    lead: int = 20  # a simulation's first frames, not used
    workers: int = 2
    seed: int = 0


class Sim(NamedTuple):
    """One simulation: parameter set ``set`` of split ``split`` on ``chunk``."""
    split: str
    set: int
    chunk: Chunk
    params: Intrinsics

    @property
    def name(self) -> str:
        c = self.chunk
        return f"{self.split}-{self.set:03d}-{c.clip}-{c.start}-{c.frames}"


def plan(cfg: AuthorDataConfig) -> list[Sim]:
    """Every simulation of the dataset: val, then test, then the train sets in order."""
    sims = []
    for split, n_sets, n_win, off in (("val", cfg.val_sets, cfg.val_windows, 1), ("test", cfg.test_sets,
                                                                                 cfg.test_windows, 2)):
        ps = sample_intrinsics(n_sets, cfg.seed + off)
        for c in chunks_of(split, cfg.window, n_win, cfg.seed + off):
            sims += [Sim(split, s, c, p) for s, p in enumerate(ps)]
    train_p = sample_intrinsics(cfg.train_sets, cfg.seed, extendable=True)
    groups = -(-cfg.train_sets // cfg.motion_share)  # each group of sets shares its chunks
    chunks = cycled_chunks("train", cfg.chunk, groups * cfg.train_chunks, cfg.seed)
    for s in range(cfg.train_sets):
        g = s // cfg.motion_share
        sims += [Sim("train", s, c, train_p[s]) for c in chunks[g * cfg.train_chunks:(g + 1) * cfg.train_chunks]]
    return sims


def train_frames(cfg: AuthorDataConfig) -> int:
    """Training frames of the dataset (after each simulation's lead)."""
    return cfg.train_sets * cfg.train_chunks * (cfg.chunk - cfg.lead)


def teacher_config(outfit: str) -> NCSTrainConfig:
    """The simulator's base configuration: NCS's teacher on the outfit's trained fabric."""
    return NCSTrainConfig(outfit=outfit)


def sim_folder(cfg: AuthorDataConfig) -> Path:
    """``<cache>/author-sims/<outfit>-<hash of everything the simulations depend on>``: all but the
    number of train sets and how they share motions, which only choose the simulations (a
    simulation's name says its set and chunk)."""
    base = teacher_config(cfg.outfit)
    chosen = ("workers", "train_sets", "motion_share")  # which simulations, not what they are
    key = json.dumps({"pbns": hashlib.sha256(store.trained_pbns(cfg.outfit).read_bytes()).hexdigest(),
                      "data": {k: v for k, v in asdict(cfg).items() if k not in chosen},
                      "ranges": RANGES,
                      **{k: asdict(base)[k] for k in ("edge", "bend", "collision", "gravity", "pin", "inertia",
                                                      "integrate", "smooth_motion", "waist_hold")}},
                     sort_keys=True, default=str)
    return paths.cache_dir() / "author-sims" / f"{cfg.outfit}-{hashlib.sha256(key.encode()).hexdigest()[:12]}"


def simulate(body: BodyModel, outfit: str, base: NCSTrainConfig, sim: Sim,
             motions: Motions | None = None) -> np.ndarray:
    """One simulation's hanging part as posed offsets from PBNS's drape (T, n, 3) float16."""
    teacher = Teacher(body, outfit, fabric(base, sim.params), friction=sim.params.friction)
    motions = motions or Motions(body, teacher.shape, base.smooth_motion)
    return teacher(*motions.motion(sim.chunk)).detach().numpy().astype(np.float16)


class Simulator:
    """A worker (``recon.executor``) running the teacher's simulations of one outfit: the body
    made once per process, the motions on the body the outfit's PBNS was trained on (as the
    teacher's) at its first run; ``simulator(sim)`` is ``simulate``."""

    def __init__(self, outfit: str, settle: int):
        self.body, self.outfit = default_body(), outfit
        self.base = replace(teacher_config(outfit), settle=settle)
        self.motions: Motions | None = None

    def __call__(self, sim: Sim) -> np.ndarray:
        if self.motions is None:
            shape = PBNS.load(store.trained_pbns(self.outfit))[1]["shape"][None]
            self.motions = Motions(self.body, shape, self.base.smooth_motion)
        return simulate(self.body, self.outfit, self.base, sim, self.motions)


def generate(cfg: AuthorDataConfig, log=print) -> Path:
    """Run every simulation of ``plan(cfg)`` not yet in ``sim_folder(cfg)``; returns the folder,
    which holds one ``<name>.npy`` per simulation, ``plan.json`` and ``timing.json``."""
    folder = sim_folder(cfg)
    folder.mkdir(parents=True, exist_ok=True)
    sims = plan(cfg)
    meta = {"config": asdict(cfg), "sims": [{"name": s.name, "split": s.split, "set": s.set,
                                            "chunk": s.chunk._asdict(), "params": asdict(s.params)} for s in sims]}
    old = folder / "plan.json"  # for people: the largest plan simulated into this folder
    if not old.exists() or json.loads(old.read_text())["config"]["train_sets"] <= cfg.train_sets:
        paths.atomic_write(old, lambda t: Path(t).write_text(json.dumps(meta, indent=1)))
    todo = missing(folder, sims)
    t0 = time.time()
    if todo:
        log(f"simulating {len(todo)} of {len(sims)} runs ({sum(s.chunk.frames + cfg.settle for s in todo)} frames) "
            f"in {cfg.workers} processes -> {folder}")
        try:  # the time spent counts even when the job is stopped (the runs it finished are kept)
            jobs = map_strict(WorkerSpec(Simulator, (cfg.outfit, cfg.settle)), todo,
                             ExecutorConfig(workers=cfg.workers, threads=1))
            for k, x in tqdm(jobs, total=len(todo), desc="simulations", unit="run"):
                paths.atomic_write(folder / f"{todo[k].name}.npy", lambda t, x=x: _save_npy(t, x))
        finally:
            add_seconds(folder / "timing.json", time.time() - t0, cfg.workers)
    return folder


def missing(folder: Path, sims: list[Sim]) -> list[Sim]:
    """Those of ``sims`` not yet simulated into ``folder``."""
    return [s for s in sims if not (folder / f"{s.name}.npy").exists()]


def _save_npy(path, array: np.ndarray) -> None:
    with open(path, "wb") as f:
        np.save(f, array)
