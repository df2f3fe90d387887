"""Where the shipped data lives."""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent


def data_root() -> Path:
    """Folder holding ``layouts/`` and ``assets/`` (override with ``EMBODIED_ENVS_DATA``)."""
    return Path(os.environ.get("EMBODIED_ENVS_DATA", REPO_ROOT))


def default_layout() -> Path:
    return data_root() / "layouts" / "default.json"


def shipped_layouts() -> list[Path]:
    return sorted((data_root() / "layouts").glob("*.json"))
