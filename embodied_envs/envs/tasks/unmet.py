"""Which conditions of success an episode's end misses, in words, per env: the reason a
summary gives for a failed episode (``pipelines/episodes.py``), from each kind's
``conditions`` (``envs/tasks/<kind>.py``). Read once at an episode's end, not every step."""

from __future__ import annotations

import numpy as np

from embodied_envs.envs.tasks import RULES
from embodied_envs.envs.tasks.state import TaskState


def unmet_conditions(state: TaskState, results: dict, tasks) -> list[list[str]]:
    """Per env, each mover's unmet conditions, ``"NODE: not released, not at rest"`` (a mover
    that meets them all is left out; ``[]``: success). ``results``: kind -> that kind's
    ``evaluate(state)``; ``tasks``: each env's :class:`~embodied_envs.layout.task.Task`."""
    met = {
        kind: {why: np.asarray(_numpy(v)) for why, v in RULES[kind].conditions(state, res).items()}
        for kind, res in results.items()
    }  # fmt: skip
    out = []
    for i, task in enumerate(tasks):
        lines = []
        for j, node in enumerate(task.objects):
            whys = [why for why, ok in met[task.kind].items() if not ok[i, j]]
            if whys:
                lines.append(f"{node}: {', '.join(whys)}")
        out.append(lines)
    return out


def _numpy(x):
    return x.cpu().numpy() if hasattr(x, "cpu") else x
