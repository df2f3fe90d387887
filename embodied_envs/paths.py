"""Where the shipped data lives, and how outputs are written."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

# the shipped layouts, assets and splat are package data: found the same way in a source
# checkout (where ./layouts and ./assets link here) and in an installed wheel
PACKAGE_DATA = Path(__file__).resolve().parent / "data"


def data_root() -> Path:
    """Folder holding ``layouts/`` and ``assets/`` (override with ``EMBODIED_ENVS_DATA``)."""
    return Path(os.environ.get("EMBODIED_ENVS_DATA", PACKAGE_DATA))


def default_layout() -> Path:
    return data_root() / "layouts" / "default.json"


def shipped_layouts() -> list[Path]:
    return sorted((data_root() / "layouts").glob("*.json"))


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary name beside ``path`` (same suffix) to write to; renamed to ``path`` when the
    block ends without error, removed otherwise, so a crash or a full disk never leaves a
    truncated file under the final name."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
