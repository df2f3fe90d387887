"""The ``embodied-envs`` command line: thin parsing over the package."""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path

from embodied_envs.cli import (
    collect,
    demo,
    eval_cmd,
    layout_cmds,
    lerobot_cmd,
    replay,
    splat_cmds,
)
from embodied_envs.cluster import ClusterError
from embodied_envs.config import ConfigError
from embodied_envs.datasets.records import DatasetError
from embodied_envs.layout import LayoutError, PlacementError
from embodied_envs.pipelines.resume import ResumeError, kept_episodes
from embodied_envs.splat import SplatFileError
from embodied_envs.workers import WorkerError, start_up, started


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="embodied-envs", description="Layout-driven ManiSkill pick environments."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    layout_cmds.add_parser(sub)
    demo.add_parser(sub)
    collect.add_parser(sub)
    eval_cmd.add_parser(sub)
    replay.add_parser(sub)
    lerobot_cmd.add_parser(sub)
    splat_cmds.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["replay"]:  # every option after it is ManiSkill's replay_trajectory's
        args = argparse.Namespace(options=argv[1:], func=replay.cmd_replay)
    else:
        args = build_parser().parse_args(argv)
    if getattr(args, "builds_env", False):  # its task calls started() once its env is built
        start_up()
    try:
        return int(args.func(args) or 0)
    except (
        ClusterError, ConfigError, DatasetError, LayoutError, PlacementError, ResumeError,
        SplatFileError, WorkerError,
    ) as e:  # fmt: skip
        print(f"error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # Ctrl-C: what was kept and the command that resumes, one line
        print(interrupted_line(args, argv), file=sys.stderr)
        return 130
    except OSError as e:  # a full disk, a read-only folder, a vanished file: one line
        where = f"{e.filename}: " if e.filename else ""
        print(f"error: {where}{e.strerror or e}. Fix: free space or choose a writable --out.",
              file=sys.stderr)  # fmt: skip
        return 1
    finally:
        started()


def interrupted_line(args, argv: list[str]) -> str:
    """The line an interrupted command prints: the episodes a ``collect`` or ``eval`` run
    received, kept in its ``--out`` (``OUT/.resume-<name>/``, docs/scaling.md), and the
    command that resumes them; else that nothing is kept to resume."""
    out = getattr(args, "out", None)
    kept = kept_episodes(Path(out)) if out is not None else {}
    command = shlex.join(["embodied-envs", *argv])
    if not kept:
        return f"interrupted: nothing kept to resume; to start again: {command}"
    where = ", ".join(f"{n} in {s}" for s, n in kept.items())
    return f"interrupted: kept the episodes received ({where}); to resume them: {command}"


if __name__ == "__main__":
    sys.exit(main())
