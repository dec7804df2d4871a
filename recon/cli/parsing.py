"""Argument parsing shared by the commands: a parser whose errors are one line, the help
formatter, ``known`` (a flag's default or choices: the library's value, from the committed table
recon/cli/values.py, so that no flag module imports torch), ``run_by`` (a command's function,
imported when it runs) and ``number`` (every numeric flag's type, with its range checked at parse
time)."""
from __future__ import annotations

import argparse
import dataclasses
import importlib
import inspect
import math
import sys
from pathlib import Path

from recon.cli.values import VALUES

ROOT = Path(__file__).resolve().parents[2]  # the folder holding recon/ (and eval/ in a clone)
# None, or a dict: ``known`` then reads every value from the library itself and records it here
# (scripts/cli_values.py writes the table; tests/test_cli.py checks it)
RECORDING: dict | None = None


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line on stderr (exit 2): what is wrong and where the
    flags are listed."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (`{self.prog} --help` lists the flags)\n")

    def exit(self, status: int = 0, message: str | None = None):
        if message:
            sys.stderr.write(message)
        raise SystemExit(status)


class formatter(argparse.ArgumentDefaultsHelpFormatter):  # noqa: N801 - passed where argparse takes a class
    """Shows a flag's default only where there is one to show (not None, not a switch's False)."""

    def _get_help_string(self, action):
        if action.default in (None, False) or action.default is argparse.SUPPRESS:
            return action.help
        return super()._get_help_string(action)


def actions(p: Parser):
    """The action subparsers of a command group, and a helper adding one action."""
    sub = p.add_subparsers(dest="action", required=True, metavar="ACTION", parser_class=Parser)

    def action(name: str, func, help: str) -> Parser:
        """``func``: the function, or ``"module:function"`` of recon.cli.actions (``run_by``)."""
        a = sub.add_parser(name, help=help, description=help, formatter_class=formatter)
        a.set_defaults(func=run_by(func) if isinstance(func, str) else func)
        return a

    return action


def known(name: str, field: str | None = None):
    """A library value a flag shows: ``"module:NAME"`` (a constant) or ``"module:Owner", "field"``
    (a dataclass field's or a function parameter's default, also written ``"module:Owner.field"``).
    Read from the committed table (the library imports torch, which would make every ``--help``
    take seconds); a path inside the project is stored relative to it."""
    name = name if field is None else f"{name}.{field}"
    if RECORDING is not None:
        RECORDING[name] = literal(live(name))
    value = VALUES[name] if RECORDING is None else RECORDING[name]
    return str(ROOT / value["path"]) if isinstance(value, dict) and set(value) == {"path"} else value


def live(name: str):
    """The library's own value of a ``known`` name (imports its module)."""
    module, attr = name.split(":")
    owner, _, field = attr.partition(".")
    obj = getattr(importlib.import_module(module), owner)
    return default(obj, field) if field else obj


def literal(value):
    """A value as the table keeps it: a mapping's keys as a tuple, a path in the project relative
    to it; anything else must be a plain literal."""
    if isinstance(value, dict):
        return tuple(value)
    if isinstance(value, Path) or (isinstance(value, str) and value.startswith(str(ROOT) + "/")):
        path = Path(value).resolve()
        return {"path": str(path.relative_to(ROOT))} if path.is_relative_to(ROOT) else str(value)
    if isinstance(value, (list, tuple)):
        return type(value)(literal(v) for v in value)
    assert value is None or isinstance(value, (str, int, float, bool)), f"{value!r} is no literal"
    return value


def run_by(spec: str):
    """The function a command runs, ``"module:function"`` of recon.cli.actions, imported when the
    command runs (its imports take seconds; ``--help`` needs none of them)."""
    module, name = spec.split(":")

    def run(args):
        return getattr(importlib.import_module(f"recon.cli.actions.{module}"), name)(args)

    run.spec = spec
    return run


def default(owner, name: str):
    """The default of a dataclass field (plain or from its factory) or of a function's parameter, so
    that a flag's default has one home: the code it configures."""
    if dataclasses.is_dataclass(owner):
        f = {f.name: f for f in dataclasses.fields(owner)}[name]
        return f.default_factory() if f.default is dataclasses.MISSING else f.default
    return inspect.signature(owner).parameters[name].default


def number(kind: type = float, low: float | None = None, high: float | None = None, low_open: bool = False):
    """The type of a numeric flag: ``kind`` (int or float), finite, in [low, high] (``low_open``:
    above low). A value outside is refused at parse time with the range in the message. The
    returned function carries ``kind``, ``low``, ``high`` and ``low_open`` for the tests."""
    lo = "" if low is None else (f"> {low:g}" if low_open else f">= {low:g}")
    hi = "" if high is None else f"<= {high:g}"
    rule = " and ".join(s for s in (lo, hi) if s) or "a number"

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
        if not math.isfinite(value) or (low is not None and (value <= low if low_open else value < low)) or (
                high is not None and value > high):
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in its messages
    parse.kind, parse.low, parse.high, parse.low_open = kind, low, high, low_open
    return parse


COUNT = number(int, 1)  # how many of something: at least one
STEPS = number(int, 0)  # optimiser steps, 0 allowed
SEED = number(int, 0)
POSITIVE = number(float, 0, low_open=True)
NON_NEGATIVE = number(float, 0)


def device(text: str) -> str:
    """The type of a ``--device`` flag: a torch device this machine has."""
    torch = importlib.import_module("torch")  # the commands that take a device load torch anyway
    try:
        dev = torch.device(text)
    except (RuntimeError, ValueError):
        raise argparse.ArgumentTypeError(f"{text!r} is not a torch device (cpu, cuda, cuda:1, ...)") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise argparse.ArgumentTypeError(f"{text}: no CUDA GPU is visible to this torch ({torch.__version__})")
    if dev.type == "cuda" and dev.index is not None and dev.index >= torch.cuda.device_count():
        raise argparse.ArgumentTypeError(f"{text}: this machine has {torch.cuda.device_count()} CUDA device(s)")
    if dev.type not in ("cpu", "cuda"):
        raise argparse.ArgumentTypeError(f"{text}: recon runs on cpu or cuda")
    return text


def add_executor(p: argparse.ArgumentParser, local_workers: int = 1, what: str = "worker processes") -> None:
    """``--executor``, ``--workers`` and ``--ray-address`` (``recon.executor``)."""
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="where the work runs: this machine, or a Ray cluster (pip install 'recon[cluster]'; "
                        "$RAY_ADDRESS or --ray-address joins one, else a local Ray with this machine's cores); "
                        "the outputs are the same")
    p.add_argument("--workers", type=COUNT, default=None,
                   help=f"{what} (default: {local_workers} local; with Ray one per CPU of the cluster)")
    p.add_argument("--ray-address", default=None, help="the Ray cluster to join (default: $RAY_ADDRESS)")


def executor_args(args, local_workers: int = 1) -> dict:
    """The ``recon.executor.ExecutorConfig`` keywords of the flags ``add_executor`` added."""
    workers = args.workers if args.workers is not None else (local_workers if args.executor == "local" else None)
    return {"kind": args.executor, "workers": workers, "address": args.ray_address}
