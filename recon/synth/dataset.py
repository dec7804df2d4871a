"""Sharded, resumable, parallel storage of synthetic samples, and the fixed benchmarks.

A dataset folder holds ``shard-00000.npz`` ... (``shard_size`` samples each, written atomically,
images as PNG bytes) and ``manifest.json`` (config, seed, split, per-shard SHA-256). A shard
that exists is never recomputed, so an interrupted run resumes where it stopped. Sample i
depends only on (split, seed, i): results are bit-identical for any number of workers, and on
every x86-64 CPU (``recon.synth.scene`` and ``recon.render.raster``). ``GENERATOR`` numbers the
generator's versions: a folder made by another one is not continued, and the benchmarks' cache
folders carry it in their name.
"""
from __future__ import annotations

import hashlib
import io
import json
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm import tqdm

from recon import paths
from recon.body import default_body
from recon.body.base import BodyModel
from recon.errors import MissingFile, ReconError
from recon.executor import ExecutorConfig, WorkerLost, WorkerSpec, map_tasks
from recon.synth.crowd import CrowdConfig, CrowdSampler, EmptySampler
from recon.synth.other import OtherConfig, OtherSceneSampler
from recon.synth.scene import SceneSampler, SynthConfig

# Fixed benchmark splits: poses of held-out mocap subjects (recon.poses.mocap.SPLIT_SUBJECTS).
# The wide ones frame people as photos do: 512 px frames, the body 30-90 % of the height, its
# centre anywhere in the middle 60 % of the frame, so many are small, off-centre or cut.
# The other-* ones are the other domain (recon.synth.other): another renderer, clothes, photos,
# shapes and framing; every choice is made on other-val. other-empty: its frames without a person;
# other-crowd: street scenes with 4-10 people (recon.synth.crowd).
WIDE = {"size": 512, "focal_range": (600.0, 1400.0), "fill_range": (0.3, 0.9), "shift": 0.3}
# The generators by kind: (sampler, config, version). synth 2: float64 geometry, CPU-independent
# rendering (0.5.0); other 1 (0.12.0).
KINDS = {"synth": (SceneSampler, SynthConfig, 2), "other": (OtherSceneSampler, OtherConfig, 1),
         "empty": (EmptySampler, OtherConfig, 1), "crowd": (CrowdSampler, CrowdConfig, 1)}
GENERATOR = KINDS["synth"][2]
BENCHMARKS = {
    "synth-val": {"split": "val", "seed": 1001, "n": 2000},
    "synth-test": {"split": "test", "seed": 2002, "n": 2000},
    "synth-wide-val": {"split": "val", "seed": 1101, "n": 1000, "config": WIDE},
    "synth-wide-test": {"split": "test", "seed": 2202, "n": 1000, "config": WIDE},
    "other-val": {"kind": "other", "split": "val", "seed": 3001, "n": 600},
    "other-test": {"kind": "other", "split": "test", "seed": 4002, "n": 1000},
    "other-empty-val": {"kind": "empty", "split": "val", "seed": 3101, "n": 150, "shard_size": 50},
    "other-empty-test": {"kind": "empty", "split": "test", "seed": 4102, "n": 300, "shard_size": 50},
    "other-crowd-val": {"kind": "crowd", "split": "val", "seed": 3201, "n": 120, "shard_size": 20},
    "other-crowd-test": {"kind": "crowd", "split": "test", "seed": 4202, "n": 100, "shard_size": 20},
    # views: another benchmark's images changed on reading (``open_bench``)
    "other-val-gray": {"view": "other-val", "gray": True},
    "other-test-gray": {"view": "other-test", "gray": True},
}
IMAGE_KEYS = ("rgb", "mask", "silhouette", "parts", "depth", "ids")
ARRAY_KEYS = ("K", "R", "t", "points3d", "points2d", "pose", "shape", "vertices")


def bench_kind(name: str) -> str:
    b = BENCHMARKS[name]
    return bench_kind(b["view"]) if "view" in b else b.get("kind", "synth")


def bench_config(name: str):
    """The generator settings of a fixed benchmark (its kind's config)."""
    return KINDS[bench_kind(name)][1](**BENCHMARKS[name].get("config", {}))


def make_sampler(kind: str, body: BodyModel, split: str, seed: int, cfg):
    """The scene sampler of a generator kind (``KINDS``)."""
    return KINDS[kind][0](body, split, seed, cfg)


def bench_sampler(name: str, body: BodyModel):
    """The sampler that renders sample i of a fixed benchmark on the fly."""
    b = BENCHMARKS[BENCHMARKS[name].get("view", name)]
    return make_sampler(bench_kind(name), body, b["split"], b["seed"], bench_config(name))


def bench_dir(name: str) -> Path:
    if name not in BENCHMARKS:
        raise ReconError(f"unknown benchmark {name!r}; known: {', '.join(BENCHMARKS)}")
    name = BENCHMARKS[name].get("view", name)
    return paths.cache_dir() / "synth" / f"{name}-v{KINDS[bench_kind(name)][2]}"


def open_bench(name: str, keys: tuple[str, ...] | None = None):
    """A fixed benchmark to read: its dataset, or for a view (``other-test-gray``) the viewed one's
    images changed as the view says (gray: the luma in all three channels, as a black-and-white
    photo loads)."""
    ds = SynthDataset(bench_dir(name), keys)
    return GrayView(ds) if BENCHMARKS[name].get("gray") else ds


class GrayView:
    """A dataset whose images are read as grayscale photos (``cv2``'s luma, three equal channels)."""

    def __init__(self, ds):
        self.ds, self.root = ds, getattr(ds, "root", None)

    def __len__(self) -> int:
        return len(self.ds)

    def __getitem__(self, i: int) -> dict:
        s = self.ds[i]
        if "rgb" in s:
            g = cv2.cvtColor(s["rgb"], cv2.COLOR_RGB2GRAY)
            s["rgb"] = np.ascontiguousarray(np.repeat(g[..., None], 3, 2))
        return s


def _encode(key: str, a: np.ndarray) -> bytes:
    if key == "rgb":
        a = a[..., ::-1]
    elif key == "depth":  # millimetres, uint16
        a = np.clip(np.nan_to_num(a.astype(np.float32)) * 1000.0, 0, 65535).astype(np.uint16)
    elif a.dtype == bool:
        a = a.astype(np.uint8) * 255
    ok, buf = cv2.imencode(".png", a, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise RuntimeError(f"PNG encoding of {key} failed")
    return buf.tobytes()


def _decode(key: str, b: np.ndarray) -> np.ndarray:
    a = cv2.imdecode(b, cv2.IMREAD_UNCHANGED)
    if key == "rgb":
        return a[..., ::-1]
    if key == "depth":
        return a.astype(np.float32) / 1000.0
    if key in ("mask", "silhouette"):
        return a > 0
    return a


def _blobs(out: dict, member: str, blobs: list[bytes]) -> None:
    out[member] = np.concatenate([np.frombuffer(b, np.uint8) for b in blobs])
    out[member.rsplit("_", 1)[0] + "_offsets"] = np.cumsum([0] + [len(b) for b in blobs]).astype(np.int64)


def pack(samples: list[dict], store_vertices: bool) -> dict[str, np.ndarray]:
    """Samples -> a shard's arrays: images as PNG bytes (an ``rgb_jpg`` sample keeps its JPEG
    bytes instead: the image is that JPEG), other arrays stacked."""
    out: dict[str, np.ndarray] = {}
    jpg = "rgb_jpg" in samples[0]
    for key in samples[0]:
        if key == "rgb_jpg":
            _blobs(out, "rgb_jpg", [s["rgb_jpg"] for s in samples])
        elif key in IMAGE_KEYS:
            if not (key == "rgb" and jpg):
                _blobs(out, key + "_png", [_encode(key, s[key]) for s in samples])
        elif key != "vertices" or store_vertices:
            out[key] = np.stack([s[key] for s in samples])
    return out


class ShardWriter:
    """Renders shards (a worker process or Ray actor builds one: its scene sampler, on one torch
    thread). ``ship``: return the shard's bytes for the driver to write (a worker on another
    machine), else write it into ``out_dir`` here."""

    def __init__(self, split: str, seed: int, cfg: dict, out_dir: str, store_vertices: bool, ship: bool = False,
                 kind: str = "synth"):
        torch.set_num_threads(1)  # one process per core; also what the committed hashes were made with
        self.scene = make_sampler(kind, default_body(), split, seed, KINDS[kind][1](**cfg))
        self.out_dir, self.store_vertices, self.ship = Path(out_dir), store_vertices, ship

    def __call__(self, task: tuple[int, int, int]) -> tuple[int, str | bytes]:
        """(shard, first, stop) -> (shard, its hash), or (shard, its .npz bytes) when shipping."""
        shard, start, stop = task
        arrays = pack([self.scene.sample(i) for i in range(start, stop)], self.store_vertices)
        if self.ship:
            buf = io.BytesIO()
            np.savez(buf, **arrays)
            return shard, buf.getvalue()
        path = self.out_dir / f"shard-{shard:05d}.npz"
        paths.atomic_write(path, lambda tmp: np.savez(open(tmp, "wb"), **arrays))
        return shard, _sha256(path)


def _sha256(path: Path) -> str:
    with np.load(path) as z:  # hash the arrays, not the zip container (timestamps)
        h = hashlib.sha256()
        for k in sorted(z.files):
            h.update(k.encode())
            h.update(np.ascontiguousarray(z[k]).tobytes())
    return h.hexdigest()


def generate(out_dir: Path, split: str, seed: int, n: int, shard_size: int = 250, workers: int = 2,
             cfg=None, store_vertices: bool = True, progress: bool = True,
             executor: ExecutorConfig | None = None, kind: str = "synth") -> Path:
    """Generate (or finish generating) ``n`` samples of a generator ``kind`` (``KINDS``) into
    ``out_dir``: shards rendered by ``workers`` local processes, or by ``executor``
    (``recon.executor``: any kind, any number of workers, the same bits)."""
    config_type, version = KINDS[kind][1], KINDS[kind][2]
    cfg = cfg or config_type()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    meta = {"split": split, "seed": seed, "n": n, "shard_size": shard_size, "config": asdict(cfg),
            "store_vertices": store_vertices, "generator": version}
    if kind != "synth":
        meta["kind"] = kind
    meta = json.loads(json.dumps(meta))  # tuples -> lists, as stored
    man_path = out_dir / "manifest.json"
    manifest = json.loads(man_path.read_text()) if man_path.exists() else {**meta, "shards": {}}
    # settings added since a folder was made read as their defaults (what made it)
    defaults = json.loads(json.dumps(asdict(config_type())))
    manifest["config"] = {**defaults, **manifest.get("config", {})}
    if any(manifest.get(k) != v for k, v in meta.items() if k != "n"):
        raise ReconError(f"{out_dir} holds a dataset made with other settings or another version of the "
                         "generator; use another folder")
    manifest["n"] = n
    todo = [(shard, start, min(start + shard_size, n)) for shard, start in enumerate(range(0, n, shard_size))
            if not (out_dir / f"shard-{shard:05d}.npz").exists()]
    executor = executor or ExecutorConfig(workers=workers)
    spec = WorkerSpec(ShardWriter, (split, seed, asdict(cfg), str(out_dir), store_vertices, executor.remote, kind))
    bar = tqdm(total=len(todo), desc=f"synth {split}", unit="shard", disable=not progress)
    threads = torch.get_num_threads()  # in this process a worker sets one thread: restored after
    results = map_tasks(spec, todo, executor)
    try:
        for t, result in results:
            if isinstance(result, WorkerLost):
                raise ReconError(f"shard {todo[t][0]} of {out_dir}: {result}; the same command continues with the "
                                 "shards not yet written")
            shard, got = result
            if isinstance(got, bytes):
                path = out_dir / f"shard-{shard:05d}.npz"
                paths.atomic_write(path, lambda tmp, b=got: Path(tmp).write_bytes(b))
                got = _sha256(path)
            manifest["shards"][str(shard)] = got
            paths.write_text(man_path, json.dumps(manifest, indent=1))
            bar.update(1)
    finally:
        results.close()
        bar.close()
        torch.set_num_threads(threads)
    return out_dir


def reference_hashes_path(name: str) -> Path:
    """Committed per-shard hashes of a benchmark, to check a regeneration is bit-identical."""
    return paths.REPO_ROOT / "eval" / "benchmarks" / f"{name}.sha256.json"


def build_benchmark(name: str, workers: int = 2, n: int | None = None, executor: ExecutorConfig | None = None) -> Path:
    name = BENCHMARKS[name].get("view", name)
    b = BENCHMARKS[name]
    return generate(bench_dir(name), b["split"], b["seed"], n or b["n"], workers=workers, cfg=bench_config(name),
                    executor=executor, kind=bench_kind(name), shard_size=b.get("shard_size", 250))


def compare_with_reference(name: str) -> list[int]:
    """Shards of the local benchmark whose hash differs from the committed reference."""
    ref = json.loads(reference_hashes_path(name).read_text())["shards"]
    local = json.loads((bench_dir(name) / "manifest.json").read_text())["shards"]
    return sorted(int(k) for k in ref if local.get(k) != ref[k])


class SynthDataset:
    """Random access to a generated folder: ``ds[i]`` -> dict of decoded arrays. ``keys``: only
    these (default: all); the last ``cache`` shards stay in memory, each with only those keys, so
    shuffled reading of a few keys (training crops) does not reload whole shards."""

    def __init__(self, root: str | Path, keys: tuple[str, ...] | None = None, cache: int = 4):
        self.root = Path(root)
        self.keys, self.cache_size = keys, cache
        man = self.root / "manifest.json"
        if not man.exists():
            raise MissingFile(f"{self.root} has no manifest.json: generate it with `recon synth generate`, or "
                              "`recon synth bench NAME` for a fixed benchmark")
        self.manifest = json.loads(man.read_text())
        self.shard_size = self.manifest["shard_size"]
        self.n = min(self.manifest["n"], len(self.manifest["shards"]) * self.shard_size)
        self._cache: dict[int, dict] = {}

    def __len__(self) -> int:
        return self.n

    def _wanted(self, member: str) -> bool:
        key = member.removesuffix("_png").removesuffix("_jpg").removesuffix("_offsets")
        return self.keys is None or key in self.keys

    def _shard(self, k: int) -> dict:
        if k not in self._cache:
            if len(self._cache) >= self.cache_size:
                self._cache.pop(next(iter(self._cache)))  # the oldest
            with np.load(self.root / f"shard-{k:05d}.npz") as z:
                self._cache[k] = {m: z[m] for m in z.files if self._wanted(m)}
        return self._cache[k]

    def __getitem__(self, i: int) -> dict[str, np.ndarray]:
        if not 0 <= i < self.n:
            raise IndexError(i)
        z = self._shard(i // self.shard_size)
        j = i % self.shard_size
        out = {}
        for member, blob in z.items():
            key = member.removesuffix("_png").removesuffix("_jpg")
            if member.endswith("_offsets"):
                continue
            if key != member:
                off = z[key + "_offsets"]
                data = blob[off[j]:off[j + 1]]
                out[key] = _decode(key, data) if member.endswith("_png") else \
                    np.ascontiguousarray(cv2.imdecode(data, cv2.IMREAD_COLOR)[..., ::-1])
            else:
                out[key] = blob[j]
        return out

    def verify(self) -> list[int]:
        """Shards whose content differs from the manifest's hash."""
        return [int(k) for k, h in self.manifest["shards"].items()
                if _sha256(self.root / f"shard-{int(k):05d}.npz") != h]

