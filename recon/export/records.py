"""Records beside the files: JSON (``result.json``, ``people.json``, ``motion.json``, ...), written
atomically so that a reader or an interrupted batch never sees half of one."""
from __future__ import annotations

import json
from pathlib import Path

from recon.paths import write_text


def write_json(path: str | Path, data, indent: int | None = 1) -> Path:
    """Atomically write ``data`` as JSON."""
    return write_text(path, json.dumps(data, indent=indent))
