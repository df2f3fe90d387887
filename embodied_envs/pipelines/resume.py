"""What a run has received, kept in its output folder: :class:`ResumeStore`.

``collect`` keeps each episode in ``OUT/.resume-<dataset>/seed_<seed>/`` and ``eval`` in
``OUT/.resume-eval/<task>/`` as it arrives, whichever backend ran it; a run interrupted
(Ctrl-C, killed) and started again with the same ``--out`` and settings keeps them and runs
the rest. The store is removed once the dataset or the evaluation is complete. It imports
nothing of the simulator: the command line names its error and its folders.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path
from typing import Any

from embodied_envs.paths import atomic_output

RESUME_PREFIX = ".resume-"  # in --out: what an interrupted run received


class ResumeError(RuntimeError):
    """The output folder holds an interrupted run of other settings."""


class ResumeStore:
    """A run's received results in ``folder`` (in its output folder): one sub-folder per key,
    written under a temporary name and renamed, for the settings ``fingerprint`` (a JSON-able
    value). The folder is made with the first result; one left by a run of other settings is
    refused."""

    PLAN = "plan.json"

    def __init__(self, folder: Path, fingerprint: Any):
        self.folder = Path(folder)
        self.text = json.dumps(fingerprint, sort_keys=True, indent=1, default=str)
        plan = self.folder / self.PLAN
        if plan.is_file() and plan.read_text() != self.text:
            raise ResumeError(
                f"{self.folder} holds an interrupted run of other settings (see its "
                f"{self.PLAN}). Fix: run again with that run's flags to resume it, or remove "
                "that folder"
            )

    def keys(self) -> list[str]:
        if not self.folder.is_dir():
            return []
        return sorted(p.name for p in self.folder.iterdir()
                      if p.is_dir() and not p.name.startswith("."))  # fmt: skip

    def path(self, key: str) -> Path:
        return self.folder / key

    def save(self, key: str, files: dict[str, bytes]) -> Path:
        """Keeps ``files`` (name -> bytes) under ``key``, whole or not at all."""
        self.folder.mkdir(parents=True, exist_ok=True)
        plan = self.folder / self.PLAN
        if not plan.is_file():
            with atomic_output(plan) as tmp:
                tmp.write_text(self.text)
        work = Path(tempfile.mkdtemp(prefix=f".{key}.", dir=self.folder))
        for name, data in files.items():
            (work / name).write_bytes(data)
        final = self.path(key)
        shutil.rmtree(final, ignore_errors=True)
        work.rename(final)
        return final

    def remove(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)


def kept_episodes(out: Path) -> dict[str, int]:
    """The stores in ``out`` that hold episodes, and how many each holds (a folder being
    written is not counted)."""
    stores = sorted(Path(out).glob(f"{RESUME_PREFIX}*"))
    kept = {str(s): sum(1 for p in s.iterdir() if p.is_dir() and not p.name.startswith("."))
            for s in stores if s.is_dir()}  # fmt: skip
    return {s: n for s, n in kept.items() if n}
