"""The backbone's training crops: from stored synthetic shards (``CropDataset``), rendered on
demand by index (``RenderedCrops``, validation) or endlessly (``OnlineCrops``, ``--online``: in
the data-loader workers, or in Ray actors on any node of a cluster, ``RayCrops``). Each image is
cropped with the thesis' metric 2.5 m crop around the mean joint (``make_crop``)."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch
from torch.utils.data import Dataset, IterableDataset, default_collate, get_worker_info

from recon.backbone.crop import Crop
from recon.body import create
from recon.executor import WorkerSpec, stream_results
from recon.synth.dataset import SynthDataset
from recon.synth.scene import SceneSampler

CROP_KEYS = ("rgb", "K", "points3d")  # what a training crop reads of a stored sample


def make_crop(s: dict, size: int, jitter: bool, rng: np.random.Generator):
    """One sample -> (image (3, S, S) float tensor in [0, 1], grid targets (42, 3), crop vector,
    K, camera points). ``jitter``: the crop's centre and scale are perturbed (training)."""
    pts = s["points3d"].astype(np.float64)
    centre = pts[:24].mean(0)
    extent = 2.5
    if jitter:
        centre = centre + rng.normal(0, 0.05, 3) * [1, 1, 0]
        extent *= rng.uniform(0.9, 1.1)
    crop = Crop.around(centre, s["K"].astype(np.float64), extent)
    img = crop.image(s["rgb"], size).astype(np.float32) / 255.0
    crop_vec = np.array([crop.u0, crop.v0, crop.side, crop.zc, crop.extent], np.float64)
    return (torch.from_numpy(np.ascontiguousarray(img.transpose(2, 0, 1))).float(),
            torch.from_numpy(crop.to_grid(pts)).float(), torch.from_numpy(crop_vec),
            torch.from_numpy(s["K"].astype(np.float64)), torch.from_numpy(pts))


class CropDataset(Dataset):
    """Crops of stored ``recon synth`` samples (jittered for training)."""

    def __init__(self, roots: list[Path], input_size: int, jitter: bool, seed: int = 0):
        self.sets = [SynthDataset(r, keys=CROP_KEYS) for r in roots]
        self.index = [(i, j) for i, s in enumerate(self.sets) for j in range(len(s))]
        self.size, self.jitter, self.seed = input_size, jitter, seed

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, n: int):
        i, j = self.index[n]
        rng = np.random.default_rng([self.seed, n, int(torch.randint(1 << 30, ()).item()) if self.jitter else 0])
        return make_crop(self.sets[i][j], self.size, self.jitter, rng)


def _scene_sampler(split: str, seed: int) -> SceneSampler:
    if get_worker_info() is not None:  # many workers: one thread each, or OpenCV/BLAS pools oversubscribe the CPU
        torch.set_num_threads(1)
        cv2.setNumThreads(1)
    return SceneSampler(create(), split, seed)


class RenderedCrops(Dataset):
    """Samples 0..n-1 of a (split, seed) stream rendered on demand: with a benchmark's split and
    seed these are that benchmark's images."""

    def __init__(self, split: str, seed: int, n: int, input_size: int):
        self.split, self.seed, self.n, self.size = split, seed, n, input_size
        self.sampler = None

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int):
        if self.sampler is None:  # per worker process: its own GL context
            self.sampler = _scene_sampler(self.split, self.seed)
        return make_crop(self.sampler.sample(i), self.size, False, np.random.default_rng(0))


class OnlineCrops(IterableDataset):
    """Endless jittered training crops rendered by each data-loader worker; worker w uses the
    stream (train, seed * 1000 + w) from sample ``start`` on (``stream``: w given, for a renderer
    outside a DataLoader). Each render gives ``repeats`` crops, mixed through a shuffle buffer
    (rendering is the bottleneck)."""

    def __init__(self, input_size: int, seed: int = 0, start: int = 0, repeats: int = 1, buffer: int = 64,
                 stream: int | None = None):
        self.size, self.seed, self.start, self.repeats, self.buffer = input_size, seed, start, repeats, buffer
        self.stream = stream

    def __iter__(self):
        info = get_worker_info()
        w = self.stream if self.stream is not None else (info.id if info is not None else 0)
        sampler = _scene_sampler("train", self.seed * 1000 + w)
        rng = np.random.default_rng([self.seed, w, self.start, 7])
        pool, i = [], self.start
        while True:
            s = sampler.sample(i)
            pool += [make_crop(s, self.size, True, rng) for _ in range(self.repeats)]
            i += 1
            while len(pool) > (self.buffer if self.repeats > 1 else 0):
                yield pool.pop(int(rng.integers(len(pool))))


class CropBatches:
    """A batch of online training crops a call (a Ray actor's worker): stream ``stream`` of
    ``OnlineCrops``, on one thread."""

    def __init__(self, input_size: int, batch: int, seed: int, stream: int, start: int, repeats: int):
        torch.set_num_threads(1)
        cv2.setNumThreads(1)
        self.crops = iter(OnlineCrops(input_size, seed, start, repeats, stream=stream))
        self.batch = batch

    def __call__(self, _task=None):
        return default_collate([next(self.crops) for _ in range(self.batch)])


class RayCrops:
    """Endless batches of online training crops from ``actors`` Ray actors (any node of the
    cluster; stream w as DataLoader worker w would render it), ``in_flight`` batches queued at
    each (a bounded queue: rendering runs ahead of the trainer by at most that much). A lost actor
    is replaced by one on a new stream."""

    def __init__(self, input_size: int, batch: int, actors: int, seed: int = 0, start: int = 0, repeats: int = 1,
                 address: str | None = None, in_flight: int = 2):
        self.input_size, self.batch, self.actors, self.seed = input_size, batch, actors, seed
        self.start, self.repeats, self.address, self.in_flight = start, repeats, address, in_flight

    def _spec(self, stream: int) -> WorkerSpec:
        return WorkerSpec(CropBatches, (self.input_size, self.batch, self.seed, stream, self.start, self.repeats))

    def __iter__(self):
        return stream_results(self._spec, self.actors, self.address, self.in_flight)
