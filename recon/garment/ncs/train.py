"""Training of NCS outfits (``recon garment train --model ncs``, thesis 6.3.4) from the outfit's PBNS,
in four stages (``NCSTraining``), on motion cut from the retargeted mocap's train split at 30 fps.
No simulator and no cloth data: only the body's motion and the energies.

1. ``solve``: the teacher (``recon.garment.ncs.data``) integrates the cloth through chunks of
   motion; chunks whose cloth went wrong are dropped, the rest unposed into rest-pose
   displacements from PBNS, with their left-right mirror images;
2. ``init_fields``: the principal components of those displacements (mass-weighted) become D's
   rows after PBNS's (``NCSConfig.dynamic`` of them), zero where the cloth is held;
3. ``fit``: the static encoder and the bias-free dynamic branch learn the chunks' coefficients on
   the new rows (``ncs.losses.Fit``), the val performers' chunks selecting the checkpoint; the
   static code on PBNS's rows stays PBNS's MLP;
4. ``physics``: the thesis' loss on the predictions (``ncs.losses.Physics``, ``StaticPoses``,
   ``FreeMotion``) joins the fitting, and trains D's new rows with ``field_lr``.

The thesis trains the network on the loss directly, the previous states being its own earlier
predictions; on a CPU budget that learns little motion, so the loss's fixed point (the solver's
trajectory) is learnt instead (docs/garments.md).
"""
from __future__ import annotations

import json
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from recon.body.base import BodyModel
from recon.garment import store
from recon.garment.data import MIN_POSE_DISTANCE, pose_set
from recon.garment.ncs.config import NCSTrainConfig
from recon.garment.ncs.data import (
    Chunk,
    Motions,
    Teacher,
    ankle_taper,
    chunk_folder,
    chunks_of,
    integrate_chunks,
    mirror_map,
    sound_chunks,
)
from recon.garment.ncs.losses import (
    Contact,
    Fit,
    FreeMotion,
    Physics,
    StaticPoses,
    gram,
    principal_fields,
    project,
)
from recon.garment.ncs.model import NCS, vertex_masses
from recon.garment.pbns.model import PBNS, trained_outfit
from recon.training import Trainer, run_dir_for

__all__ = ["NCSTrainConfig", "NCSTraining", "train"]


@dataclass
class Solved:
    """Stage 1's output, chunks in the order train (mirrored first), val."""

    train_chunks: list[Chunk]
    val_chunks: list[Chunk]
    dropped: list[list]  # the chunks whose solved cloth went wrong
    du: torch.Tensor  # (C, T, n, 3) rest-pose displacements from PBNS of the hanging part
    off: torch.Tensor  # (C, T, n, 3) posed offsets from PBNS's drape
    inputs: list[torch.Tensor]  # static, dynamic descriptors, PBNS inputs (C, T, ...)
    motions: list[tuple[torch.Tensor, torch.Tensor]]  # (rotations, translation) per chunk
    n_train: int  # chunks that train (with their mirror images)
    integrate_seconds: float


class NCSTraining:
    """One NCS training run: the outfit's PBNS, its teacher and the network, then the stages."""

    def __init__(self, body: BodyModel, cfg: NCSTrainConfig, out: Path | None = None, log=print, progress: bool = True):
        torch.manual_seed(cfg.seed)
        self.t0 = time.time()
        self.body, self.cfg, self.log, self.progress = body, cfg, log, progress
        self.pbns_path = store.pbns_path(cfg.outfit)
        self.outfit, self.shape, self.name = trained_outfit(body, self.pbns_path)
        self.out = Path(out or store.ncs_path(self.name))
        self.run_dir = run_dir_for(self.out)
        self.pbns, _ = PBNS.load(self.pbns_path)
        self.model = NCS.from_pbns(self.pbns, cfg.model)
        self.teacher = Teacher(body, self.name, cfg)
        self.idx = self.teacher.idx  # the moving part (``ncs.data.moving_part``)
        self.masses = torch.from_numpy(vertex_masses(self.outfit.vertices, self.outfit.faces))
        self.motions = Motions(body, self.shape, cfg.smooth_motion)
        self.e = self.pbns.D.shape[0]  # D's rows before the new ones
        self.g = torch.Generator().manual_seed(cfg.seed)

    def solve(self) -> Solved:
        """Stage 1: the teacher's chunks, the unsound ones dropped, with their mirror images."""
        cfg, motions = self.cfg, self.motions
        train_chunks = chunks_of("train", cfg.chunk, cfg.chunks, cfg.seed, cfg.stops, cfg.lead)
        val_chunks = chunks_of("val", cfg.chunk, cfg.val_chunks, cfg.seed, cfg.stops, cfg.lead)
        off = integrate_chunks(self.name, train_chunks + val_chunks, motions, cfg, chunk_folder(self.pbns_path, cfg),
                               self.log)
        seconds = time.time() - self.t0
        solved = [self.teacher.rest_displacement(*motions.motion(c), torch.from_numpy(o).float())
                  for c, o in zip(train_chunks + val_chunks, off)]
        sound = sound_chunks([strain for _, strain in solved], cfg.max_strain)
        n_t = len(train_chunks)
        dropped = [list(c) for c, ok in zip(train_chunks + val_chunks, sound) if not ok]
        if dropped:
            self.log(f"ncs {self.name}: {len(dropped)} solved chunks failed (an edge strained > "
                     f"{cfg.max_strain * 1000:.0f} mm), dropped: {dropped}")
        train_chunks = [c for c, ok in zip(train_chunks, sound[:n_t]) if ok]
        val_chunks = [c for c, ok in zip(val_chunks, sound[n_t:]) if ok]
        du = torch.stack([d for (d, _), ok in zip(solved, sound) if ok])
        off = torch.from_numpy(off[np.array(sound)]).float()
        del solved
        n_train = len(train_chunks)
        inputs = [motions.inputs(c) for c in train_chunks + val_chunks]
        if cfg.mirror:  # the train chunks' mirror images: the cloth's displacement (and offset) mirrored in x
            mp_ = torch.from_numpy(mirror_map(self.outfit.vertices[self.idx.numpy()]))
            flip = torch.tensor([-1.0, 1.0, 1.0])
            du = torch.cat([du[:n_train, :, mp_] * flip, du])
            off = torch.cat([off[:n_train, :, mp_] * flip, off])
            inputs = [motions.inputs(c, mirror=True) for c in train_chunks] + inputs
            n_train *= 2
        inputs = [torch.stack(x) for x in zip(*inputs)]
        chunk_motions = [motions.motion(c, mirror=True) for c in train_chunks] if cfg.mirror else []
        chunk_motions += [motions.motion(c) for c in train_chunks + val_chunks]
        return Solved(train_chunks, val_chunks, dropped, du, off, inputs, chunk_motions, n_train, seconds)

    def init_fields(self, s: Solved) -> tuple[torch.Tensor, torch.Tensor]:
        """Stage 2: D's new rows, the principal fields of the train chunks' displacements (tapered
        to zero at the ankles, ``ankle_taper``); returns the fields (k, n, 3) and every chunk's
        coefficients on them (C, T, k)."""
        cfg, idx = self.cfg, self.idx
        self.taper = torch.from_numpy(ankle_taper(self.body, self.shape, self.outfit.vertices[idx.numpy()],
                                                  cfg.ankle_hold))
        du = s.du * self.taper[:, None]
        k = cfg.model.dynamic
        fields = principal_fields(du[:s.n_train, 5:], self.masses[idx], k, cfg.seed)
        coef = project(du, fields, self.masses[idx])
        self.initial_rows = torch.zeros(k, len(self.outfit.vertices), 3)
        self.initial_rows[:, idx] = fields
        with torch.no_grad():
            self.model.D[self.e:] = self.initial_rows.reshape(k, -1)
        return fields, coef

    def fit(self, s: Solved, fields: torch.Tensor, coef: torch.Tensor) -> tuple[dict, Fit, list[torch.Tensor]]:
        """Stage 3: the networks fitted to the coefficients; returns the curve, the fitting loss and
        the trained parameters (the best checkpoint loaded)."""
        cfg, model, idx, e, k = self.cfg, self.model, self.idx, self.e, self.cfg.model.dynamic
        contact = contact_val = None
        if cfg.contact_weight:
            every4 = torch.arange(cfg.lead, cfg.chunk, 4)

            def moving_fields() -> torch.Tensor:  # D's new rows on the hanging part, as they are now
                return model.D[e:].view(k, -1, 3)[:, idx]

            contact, contact_val = (Contact.build(self.teacher, s.motions[a:b], s.off[a:b], every4, moving_fields,
                                                  cfg.collision.eps)
                                    for a, b in ((0, s.n_train), (s.n_train, len(s.off))))
        fit = Fit(model, s.inputs, coef, gram(fields.reshape(k, -1), self.masses[idx]), cfg.lead, contact,
                  cfg.contact_weight, cfg.contact_frames)
        for p in (model.D, model.weight_logits, *model.pbns_mlp.parameters()):  # PBNS's, kept
            p.requires_grad_(False)
        params = [p for p in model.parameters() if p.requires_grad]
        opt = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=cfg.weight_decay)
        self.val_i, self.n_train = torch.arange(s.n_train, len(s.du)), s.n_train
        self.contact_val = contact_val
        trainer = Trainer({"ncs": model}, opt, cfg.steps, eval_every=max(1, cfg.steps // 12),
                          out_dir=self.run_dir / "fit", select="val_teacher_mm", config=asdict(cfg),
                          desc=f"ncs {self.name}", generators=[self.g], progress=self.progress)
        self.log(f"ncs {self.name}: {len(idx)} of {len(self.outfit.vertices)} vertices move; {len(s.train_chunks)} "
                 f"train (+ mirrored: {cfg.mirror}) / {len(s.val_chunks)} val chunks of {cfg.chunk} frames integrated "
                 f"in {s.integrate_seconds:.0f} s (chunks cached in {chunk_folder(self.pbns_path, cfg)})")
        curve = trainer.fit(self.chunk_batches(s.n_train, contact), fit, lambda: self.validate(fit, coef))
        trainer.load_best()
        return curve, fit, params

    def chunk_batches(self, n_train: int, contact: Contact | None):
        """Batches of train chunks (and with ``contact`` their frame slots), drawn from ``self.g``."""
        cfg = self.cfg
        while True:
            b = (torch.randint(n_train, (cfg.batch,), generator=self.g),)
            if contact is not None:
                b += (torch.randint(len(contact.frames), (cfg.batch, cfg.contact_frames), generator=self.g),)
            yield b

    @torch.no_grad()
    def validate(self, fit: Fit, coef: torch.Tensor) -> dict:
        """The fitting's validation: the teacher error on the val and some train chunks, and the
        error of predicting no displacement at all."""
        model, val_i, lead = self.model, self.val_i, self.cfg.lead
        model.eval()
        zs, zd, _ = model.codes(*(x[val_i] for x in fit.inputs))
        v = {"val_teacher_mm": float(fit.teacher_error(val_i, zs + zd).mean().sqrt() * 1000),
             "train_teacher_mm": float(fit.teacher_error(torch.arange(min(self.n_train, 32))).mean().sqrt() * 1000),
             "val_zero_mm": float(torch.einsum("btk,kl,btl->bt", coef[val_i][:, lead:], fit.gram_new,
                                               coef[val_i][:, lead:]).mean().sqrt() * 1000)}
        if self.contact_val is not None:
            slots = torch.arange(len(self.contact_val.frames)).expand(len(val_i), -1)
            v["val_contact_pct"] = float(self.contact_val(torch.arange(len(val_i)), slots,
                                                          (zs + zd)[..., self.e:])[1])
        model.train()
        return v

    def physics(self, s: Solved, fit: Fit, coef: torch.Tensor, params: list[torch.Tensor]) -> dict:
        """Stage 4: the thesis' loss and the energies join the fitting; D's new rows train too."""
        cfg, model, body, shape, g = self.cfg, self.model, self.body, self.shape, self.g
        physics = Physics(model, self.teacher, s.motions, s.off, s.inputs)
        lo = max(cfg.lead, 2)
        val_t = torch.linspace(lo, cfg.chunk - 1, cfg.physics_frames).long().expand(len(self.val_i), -1)
        still = val_still = free = None
        if cfg.static_poses:
            rot_s = pose_set("train", cfg.static_poses, MIN_POSE_DISTANCE, cfg.seed)
            still = StaticPoses(model, self.outfit, cfg, body, shape, rot_s, physics.unit)
            val_still = StaticPoses(model, self.outfit, cfg, body, shape,
                                    pose_set("val", max(16, cfg.static_poses // 8), MIN_POSE_DISTANCE,
                                             cfg.seed), physics.unit)
        if cfg.free_windows:
            windows = chunks_of("train", cfg.chunk, cfg.chunks + cfg.free_windows, cfg.seed, cfg.stops,
                                cfg.lead)[cfg.chunks:]  # after the teacher's own
            w_in = [self.motions.inputs(c) for c in windows]
            free = FreeMotion(model, self.teacher, [torch.stack(x) for x in zip(*w_in)],
                              [self.motions.motion(c) for c in windows], physics.unit)

        def batches():
            for b in self.chunk_batches(s.n_train, fit.contact):
                p = torch.randint(s.n_train, (cfg.physics_chunks,), generator=g)
                t = torch.randint(lo, cfg.chunk, (cfg.physics_chunks, cfg.physics_frames), generator=g)
                st = torch.randint(cfg.static_poses, (cfg.static_batch,), generator=g) if still is not None else None
                w = None
                if free is not None:
                    w = (torch.randint(len(free.motions), (cfg.free_batch,), generator=g),
                         torch.randint(cfg.lead, cfg.chunk, (cfg.free_batch, cfg.free_frames), generator=g))
                yield b, p, t, st, w

        def step(batch):
            b, p, t, st, w = batch
            loss, terms = fit(b)
            e, more = physics(p, t)
            loss, terms = loss + e, {**terms, **more, "physics": e}
            if still is not None:
                es, more = still(st)
                loss, terms = loss + cfg.static_weight * es, {**terms, **more, "static": es}
            if free is not None:
                ef, more = free(*w)
                loss, terms = loss + cfg.free_weight * ef, {**terms, **more, "free": ef}
            return loss, terms

        @torch.no_grad()
        def validate():
            model.eval()
            v = self.validate(fit, coef)
            e, more = physics(self.val_i, val_t)
            v = {**v, "val_physics": float(e), **{f"val_{k}": float(x) for k, x in more.items()}}
            if val_still is not None:
                es, more = val_still(torch.arange(len(val_still.bt)))
                v = {**v, "val_static": float(es), **{f"val_{k}": float(x) for k, x in more.items()}}
            model.train()
            return v

        groups = [{"params": params}]
        if cfg.field_lr:
            model.D.requires_grad_(True)
            rows = (torch.arange(model.D.shape[0]) >= self.e).float()[:, None]
            cols = torch.zeros(len(self.outfit.vertices), 3)
            cols[self.idx] = (self.taper > 0).float()[:, None]
            cols = cols.reshape(1, -1)
            model.D.register_hook(lambda grad: grad * rows * cols)  # PBNS's rows and the part that does not move stay
            groups.append({"params": [model.D], "lr": cfg.field_lr, "weight_decay": 0.0})
        opt = torch.optim.AdamW(groups, lr=cfg.physics_lr, weight_decay=cfg.weight_decay)
        trainer = Trainer({"ncs": model}, opt, cfg.physics_steps, eval_every=max(1, cfg.physics_steps // 4),
                          out_dir=self.run_dir / "physics", config=asdict(cfg), desc=f"ncs {self.name} physics",
                          generators=[g], progress=self.progress)
        if not trainer.resumed:
            trainer.validate_now(validate, "start")
        return trainer.fit(batches(), step, validate)

    def save(self, s: Solved, curve: dict, physics_curve: dict) -> dict:
        """The weights file with its training record inside; returns the record."""
        cfg, model, k = self.cfg, self.model, self.cfg.model.dynamic
        model.eval()
        with torch.no_grad():  # how far the physics steps moved the fields (rms per unit code, mm)
            moved = (model.D[self.e:] - self.initial_rows.reshape(k, -1)).view(k, -1, 3)[:, self.idx]
            moved = moved.pow(2).sum(-1).mean(-1).sqrt()
        meta = {"outfit": self.name, "pbns": self.pbns_path.name, "config": asdict(cfg), "model": asdict(model.cfg),
                "vertices": int(len(self.outfit.vertices)), "moving_vertices": int(len(self.idx)),
                "ankle_held_vertices": int((self.taper == 0).sum()),
                "chunks": [list(c) for c in s.train_chunks], "val_chunks": [list(c) for c in s.val_chunks],
                "dropped_chunks": s.dropped, "integrate_seconds": round(s.integrate_seconds, 1),
                "train_seconds": round(time.time() - self.t0, 1), "workers": cfg.workers,
                "threads": torch.get_num_threads(), "best": curve["best"],
                "field_change_mm": round(float(moved.mean()) * 1000, 3),
                "garments": [gg.name for gg in self.outfit.garments], "curve": curve["history"],
                "physics_curve": physics_curve["history"]}
        model.save(self.out, {"meta_json": json.dumps(meta), "layer": torch.from_numpy(self.outfit.layer),
                              "garment_id": torch.from_numpy(self.outfit.garment_id), "shape": self.shape},
                   pbns_path=self.pbns_path)
        shutil.rmtree(self.run_dir, ignore_errors=True)
        return meta


def train(body: BodyModel, cfg: NCSTrainConfig | None = None, out: Path | None = None, log=print,
          progress: bool = True) -> dict:
    """Train the NCS of ``cfg.outfit`` from its PBNS; writes ``out`` (default ``store.ncs_path``)
    with the training record inside and returns that record."""
    run = NCSTraining(body, cfg or NCSTrainConfig(), out, log, progress)
    solved = run.solve()
    fields, coef = run.init_fields(solved)
    curve, fit, params = run.fit(solved, fields, coef)
    physics_curve = run.physics(solved, fit, coef, params)
    return run.save(solved, curve, physics_curve)
