"""The command line: scoped subcommands, defaults from the dataclasses, user errors vs bugs, and
the demo (needs offscreen GL)."""
import argparse
import importlib
import json
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import trimesh

from recon.backbone.train import BackboneTrainConfig
from recon.cli import COMMANDS, build_parser, main, parsing, recorded_values
from recon.cli.actions import body as cli_body
from recon.cli.actions import garment as cli_garment
from recon.cli.actions import run as cli_run
from recon.cli.actions import synth as cli_synth
from recon.cli.values import VALUES
from recon.fit import FitConfig
from recon.garment import store
from recon.garment.ncs import train as ncs_train
from recon.garment.templates import RestBody


def test_body_info(capsys):
    assert main(["body", "info"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["joints"][0] == "pelvis" and len(info["landmarks"]) == 18
    assert 1.4 < info["height_m"] < 2.1


def test_body_export_is_the_rest_body_garments_are_modelled_on(body, tmp_path):
    assert main(["body", "export", "--out", str(tmp_path / "rest.obj")]) == 0
    m = trimesh.load(tmp_path / "rest.obj", process=False)
    assert np.abs(m.vertices - RestBody(body).v).max() < 1e-6 and len(m.faces) == len(body.faces)


def test_poses_stats_use_the_shipped_set(capsys, mocap):
    assert main(["poses", "stats"]) == 0
    stats = json.loads(capsys.readouterr().out)
    assert stats["train"]["frames"] > stats["test"]["frames"] > 0
    assert stats["file"].endswith("recon/data/poses/mocap-anny-v1.npz")


def test_each_action_takes_only_its_own_flags(capsys):
    p = build_parser()
    assert p.parse_args(["run", "--out", "o"]).refine_steps == FitConfig.steps  # defaults from the dataclasses
    assert p.parse_args(["run", "--out", "o"]).silhouette == FitConfig.silhouette
    assert p.parse_args(["backbone", "train", "--out", "o", "--online"]).batch == BackboneTrainConfig.batch
    for argv in (["body", "info", "--force"], ["run", "--out", "o", "--epochs", "3"], ["demo", "--stages", "psi"],
                 ["garment", "eval", "--frames", "3"], ["poses", "stats", "--limit", "2"]):
        with pytest.raises(SystemExit):
            p.parse_args(argv)
        assert "unrecognized arguments" in capsys.readouterr().err


def test_user_errors_are_one_line_and_bugs_keep_their_traceback(capsys, monkeypatch, tmp_path):
    assert main(["body", "info", "--model", "nope.fbx"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("recon: error: unknown body model") and "Traceback" not in err
    assert main(["eval", "--bench", "nope", "--method", "mean"]) == 2
    assert "unknown benchmark" in capsys.readouterr().err
    assert main(["run", str(tmp_path / "missing.jpg"), "--out", str(tmp_path / "o"), "--source", "backbone"]) == 2
    assert "no such file or folder" in capsys.readouterr().err

    def bug(args):
        raise ValueError("a bug, not the user's fault")

    monkeypatch.setattr(cli_body, "body_info", bug)
    with pytest.raises(ValueError, match="a bug"):
        main(["body", "info"])


def test_threads_flag_sets_torch_threads():
    try:
        assert main(["--threads", "2", "body", "info"]) == 0
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(1)


def test_ncs_train_flags_reach_its_config(monkeypatch):
    seen = []
    monkeypatch.setattr(cli_garment, "default_body", lambda: None)
    monkeypatch.setattr(cli_garment.ncs_train, "train", lambda body, cfg: seen.append(cfg) or {
        "outfit": cfg.outfit, "train_seconds": 0.0, "curve": [{"val_teacher_mm": 1.0}]})
    main(["garment", "train", "--model", "ncs", "--outfit", "top-shorts", "--physics-steps", "400",
          "--static-weight", "3", "--free-weight", "10", "--field-lr", "0.001"])
    cfg = seen[0]
    assert (cfg.outfit, cfg.physics_steps, cfg.static_weight, cfg.free_weight, cfg.field_lr) == (
        "top-shorts", 400, 3.0, 10.0, 0.001)
    assert cfg.chunks == ncs_train.NCSTrainConfig.chunks  # flags not given keep the defaults


def test_demo_finds_an_outfit_trained_into_the_cache(monkeypatch, tmp_path):
    """`recon demo --outfit <own garment>`: the path comes from recon.garment.store, not built by hand."""
    monkeypatch.setattr(store, "user_dir", lambda: tmp_path)
    (tmp_path / "pbns_mine.pt").write_bytes(b"")
    seen = {}
    monkeypatch.setattr(cli_run, "photo_demo", lambda out, outfit: seen.setdefault("outfit", outfit) and [])
    monkeypatch.setattr(cli_run, "body_demo", lambda out, seed: [])
    monkeypatch.setattr(cli_run, "dressed_gif", lambda out, outfit: tmp_path / "x.gif")
    assert main(["demo", "--out", str(tmp_path / "d"), "--outfit", "mine"]) == 0
    assert seen["outfit"] == "mine"


@pytest.mark.slow
def test_demo_writes_png_obj_glb(tmp_path, body, mocap):
    assert main(["demo", "--out", str(tmp_path)]) == 0
    img = cv2.imread(str(tmp_path / "bodies.png"))
    assert img is not None and img.shape[0] > 100
    assert (img < 250).mean() > 0.02  # something was drawn on the white background
    assert cv2.imread(str(tmp_path / "smplr.png")) is not None
    assert cv2.imread(str(tmp_path / "examples.png")) is not None
    mesh = trimesh.load(tmp_path / "body0.glb", force="mesh")
    assert len(mesh.vertices) > 1000
    assert not [p for p in tmp_path.glob(".*") if p.name != ".recon-page"]  # no temp files left behind
    _demo_page_in_a_browser(tmp_path)


def _demo_page_in_a_browser(out):
    """The demo's index.html in headless Chromium: the three photos, each dressed in 3D."""
    from tests.test_page import Chromium, _errors, _painted, _viewer_pixels, find_chromium, rpage
    assert (out / "index.html").is_file()
    if find_chromium() is None or not rpage.viewer_installed():
        pytest.skip("a headless Chromium and model-viewer (bash scripts/setup.sh --tests)")
    with Chromium() as c:
        c.open(out / "index.html")
        assert c.eval("RECON_STATE.cards") == 3
        assert c.eval("[...document.querySelectorAll('.controls button.on')].map(b => b.textContent)") == [
            "dressed"] * 3
        c.wait_for("RECON_STATE.loaded >= 2", timeout=120)
        time.sleep(0.5)
        for n in range(2):
            pixels, _ = _viewer_pixels(c, n)
            assert _painted(pixels) > 0.03
        assert not _errors(c), c.console


def test_synth_generate_framing_wide_is_the_wide_benchmarks_framing(monkeypatch, tmp_path):
    seen = {}

    def generate(out, split, seed, n, store_vertices, cfg, executor):
        seen["cfg"], seen["executor"] = cfg, executor
        raise SystemExit(0)

    monkeypatch.setattr(cli_synth.dataset, "generate", generate)
    for framing, size in (("wide", 512), ("standard", 256)):
        with pytest.raises(SystemExit):
            main(["synth", "generate", "--out", str(tmp_path), "--n", "2", "--framing", framing])
        assert seen["cfg"].size == size
        if framing == "wide":
            assert seen["cfg"] == cli_synth.dataset.bench_config("synth-wide-val")
    assert seen["cfg"] == cli_synth.dataset.SynthConfig()  # standard: the generator's defaults
    with pytest.raises(SystemExit):
        main(["synth", "generate", "--out", str(tmp_path), "--n", "2", "--dressed", "0.5", "--any-shape"])
    assert (seen["cfg"].dressed_prob, seen["cfg"].any_shape) == (0.5, True)
    assert (seen["executor"].kind, seen["executor"].workers) == ("local", 2)  # the generator's own default


def _numeric_flags(parser: argparse.ArgumentParser, prefix=()):
    """(argv that reaches the action, flag, its type) for every numeric flag of every command."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _numeric_flags(sub, (*prefix, name))
        elif action.option_strings and action.type not in (None, str, Path, parsing.device):
            yield prefix, action.option_strings[-1], action


def _required(parser: argparse.ArgumentParser, path) -> list[str]:
    for name in path:
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = sub.choices[name]
    return [w for a in parser._actions if a.required and a.option_strings for w in (a.option_strings[-1], "x")]


def test_every_numeric_flag_refuses_values_out_of_its_range(capsys):
    """One helper (recon.cli.parsing.number) types every int/float flag; a value below or above its
    range, or not a number, exits with 2 and one line naming the flag, before anything runs."""
    parser = build_parser()
    flags = list(_numeric_flags(parser))
    assert len(flags) > 40
    for path, flag, action in flags:
        if path == () and flag == "--threads":
            path = ("body", "info")  # a global flag: any command
        kind = action.type
        assert kind in (parsing.COUNT, parsing.STEPS, parsing.SEED, parsing.POSITIVE, parsing.NON_NEGATIVE) or (
            hasattr(kind, "low")), f"{path} {flag} is typed {kind}, not by parsing.number"
        bad = ["nan", "abc"]
        if kind.low is not None:
            bad.append(str(kind.low if kind.low_open else kind.low - 1))
        if kind.high is not None:
            bad.append(str(kind.high + 1))
        for value in bad:
            values = [value] * (action.nargs if isinstance(action.nargs, int) else 1)
            argv = [*path[:1], *(["--threads", value] if flag == "--threads" else []), *path[1:],
                    *_required(parser, path)]
            if flag != "--threads":
                argv += [flag, *values]
            with pytest.raises(SystemExit) as e:
                parser.parse_args(argv)
            err = capsys.readouterr().err
            assert e.value.code == 2 and err.count("\n") == 1 and "error: argument" in err, (argv, err)


def test_device_flags_refuse_a_device_this_machine_lacks(capsys, monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    for argv in (["run", "--out", "o", "--device", "cuda"], ["run", "--out", "o", "--device", "gpu0"],
                 ["backbone", "recipe", "--device", "cuda:0"]):
        with pytest.raises(SystemExit) as e:
            build_parser().parse_args(argv)
        assert e.value.code == 2 and capsys.readouterr().err.count("\n") == 1
    assert build_parser().parse_args(["run", "--out", "o", "--device", "cpu"]).device == "cpu"


HELP_SECONDS = 0.5  # a whole `recon ... --help` process, Python's start-up included


def help_commands() -> list[list[str]]:
    """`recon --help`, every command's and every action's."""
    out = [[]]
    for name, sub in build_parser()._subparsers._group_actions[0].choices.items():
        out.append([name])
        acts = [a for a in sub._actions if isinstance(a, argparse._SubParsersAction)]
        out += [[name, action] for a in acts for action in a.choices]
    return out


@pytest.mark.parametrize("words", help_commands(), ids=lambda w: " ".join(w) or "recon")
def test_every_help_is_quick_and_loads_no_torch(words):
    """Flags live in modules that import no torch; a command's modules load only when it runs."""
    code = (f"import sys\nfrom recon.cli import main\ntry:\n    main({words + ['--help']!r})\nexcept SystemExit:\n"
            "    pass\nheavy = [m for m in ('torch', 'numpy', 'cv2', 'ray', 'recon.pipeline') if m in sys.modules]\n"
            "assert not heavy, heavy")
    seconds = []
    for _ in range(3):  # the fastest of three: a loaded machine may stall one start-up
        t = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
        seconds.append(time.perf_counter() - t)
        assert out.returncode == 0, out.stderr
        if seconds[-1] < HELP_SECONDS:
            break
    assert min(seconds) < HELP_SECONDS, f"recon {' '.join(words)} --help took {min(seconds):.2f} s"
    if not words:
        for name in COMMANDS:
            assert f"    {name} " in out.stdout, name


def test_the_values_the_flags_show_are_the_library_s():
    """recon/cli/values.py holds what the library says (else: python scripts/cli_values.py)."""
    assert recorded_values() == VALUES


def test_every_action_runs_a_function_of_recon_cli_actions():
    for sub in build_parser()._subparsers._group_actions[0].choices.values():
        parsers = [sub] + [p for a in sub._actions if isinstance(a, argparse._SubParsersAction)
                           for p in a.choices.values()]
        for p in parsers:
            func = p.get_default("func")
            if func is not None:
                module, name = func.spec.split(":")
                assert callable(getattr(importlib.import_module(f"recon.cli.actions.{module}"), name)), func.spec


def test_a_variant_of_another_model_is_refused(capsys):
    assert main(["garment", "train", "--model", "deepsd", "--variant", "no-normals"]) == 2
    assert "has no variant 'no-normals'" in capsys.readouterr().err


def test_author_train_grows_the_data_count_by_count(monkeypatch, capsys):
    """--train-sets: every outfit at a count before the next; models trained on the same data kept."""
    seen = []
    monkeypatch.setattr(cli_garment.author_train, "is_trained", lambda cfg: cfg.data.train_sets == 16)
    monkeypatch.setattr(cli_garment.author_train, "train", lambda cfg: seen.append(
        (cfg.data.outfit, cfg.data.train_sets)) or ("x.pt", {"frames": 1, "sets": 1, "seconds": {}}))
    assert main(["garment", "train", "--model", "author", "--outfit", "tshirt-skirt", "dress",
                 "--train-sets", "143", "16", "32"]) == 0
    assert seen == [("tshirt-skirt", 32), ("dress", 32), ("tshirt-skirt", 143), ("dress", 143)]
    assert capsys.readouterr().out.count("already trained") == 2
    sims = []
    monkeypatch.setattr(cli_garment, "generate_author", lambda data: sims.append(data.train_sets) or "folder")
    assert main(["garment", "train", "--model", "author", "--outfit", "dress", "--train-sets", "8", "64",
                 "--data-only"]) == 0
    assert sims == [64] and len(seen) == 4
    assert main(["garment", "train", "--model", "pbns", "--train-sets", "8"]) == 2
    assert "--model author's" in capsys.readouterr().err
