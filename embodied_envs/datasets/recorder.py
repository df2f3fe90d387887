"""``collect``'s recorder: ManiSkill's ``RecordEpisode``, the same files, cheaper per step.

ManiSkill's ``RecordEpisode.step`` turns every recorded value (the env state, the action, the
reward, the flags) into a batched numpy array and concatenates it onto the episode's buffer, one
leaf at a time, on every step: 0.25 ms of a 1.45 ms recorded control step on the CPU simulation
(``tools/bench/bench_collect.py``, docs/benchmarks.md). :class:`EpisodeRecorder` keeps each
step's values as they come and folds a whole episode into ManiSkill's buffer, one stack per
leaf, before anything reads the buffer (``flush_trajectory``, ``reset``, ``close``); the arrays,
the ``.h5`` and the ``.json`` are ManiSkill's (``tests/datasets/test_recorder.py`` compares them
file against file). Values that a later step could change in place (the action the caller
passes, the controller's state, the observation: a camera's image can be a view of its render
buffer) are copied when they are kept. A recorder that films (``save_video``) or runs on the GPU
simulation records through ManiSkill's own ``step``.
"""

from __future__ import annotations

import numpy as np
import torch
from mani_skill.utils import common
from mani_skill.utils.io_utils import dump_json
from mani_skill.utils.wrappers.record import RecordEpisode, clean_trajectories

# the per-step fields of ManiSkill's trajectory buffer (``record.Step``), in its order
FIELDS = ("state", "observation", "action", "reward", "terminated", "truncated", "done",
          "success", "fail")  # fmt: skip


class EpisodeRecorder(RecordEpisode):
    """``RecordEpisode`` with the per-step copies deferred to the episode's end (module doc)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._pending: list[tuple] = []  # one tuple of FIELDS per step not yet in the buffer

    def step(self, action):
        if self.save_video or not self.save_trajectory or self.base_env.gpu_sim_enabled:
            self._fold()  # GPU tensors go to the host at once, as ManiSkill's step sends them
            return super().step(action)
        obs, rew, terminated, truncated, info = self.env.step(action)
        state = None
        if self.record_env_state:
            state = self.base_env.get_state_dict()
            if "controller" in state:  # the controller's targets change in place
                state = {**state, "controller": _copied(state["controller"])}
        self._pending.append((
            state, _copied(obs), _copied(action), rew if self.record_reward else None, terminated,
            truncated, terminated | truncated, info.get("success"), info.get("fail"),
        ))  # fmt: skip
        self._elapsed_record_steps += 1
        return obs, rew, terminated, truncated, info

    def _fold(self) -> None:
        """Appends the pending steps to ManiSkill's buffer as its ``step`` would have."""
        if not self._pending:
            return
        steps, self._pending = self._pending, []
        buffer = self._trajectory_buffer
        for k, name in enumerate(FIELDS):
            values = [step[k] for step in steps]
            if name == "state" and not self.record_env_state:
                continue
            if name == "reward" and not self.record_reward:
                continue
            if name in ("success", "fail") and values[0] is None:
                setattr(buffer, name, None)  # as ManiSkill's step: the env gave none
                continue
            setattr(buffer, name, common.append_dict_array(getattr(buffer, name), _stack(values)))

    def flush_trajectory(self, *args, **kwargs):
        self._fold()
        return super().flush_trajectory(*args, **kwargs)

    def reset(self, *args, **kwargs):
        self._fold()
        return super().reset(*args, **kwargs)

    def close(self):
        self._fold()
        return super().close()

    def close_files(self) -> None:
        """Writes and closes this recorder's ``.h5`` and ``.json`` as ``close`` does, leaving
        the env open (``collect --ray``: a new recorder wraps it for the next task)."""
        self._fold()
        if self.save_trajectory and not self._closed:
            self._closed = True
            if self.clean_on_close:
                clean_trajectories(self._h5_file, self._json_data)
            dump_json(self._json_path, self._json_data, indent=2)
            self._h5_file.close()


def _copied(value):
    """A copy of ``value`` (a dict tree of tensors or arrays) that later in-place changes of it
    do not reach."""
    if isinstance(value, dict):
        return {k: _copied(v) for k, v in value.items()}
    if isinstance(value, torch.Tensor):
        return value.clone()
    if isinstance(value, np.ndarray):
        return value.copy()
    return value


def _stack(values: list):
    """The steps' ``values`` (one per step, each a dict tree) as ManiSkill's buffer holds them:
    ``to_numpy(batch(v))`` of each, concatenated along the first axis, one call per leaf."""
    first = values[0]
    if isinstance(first, dict):
        return {k: _stack([v[k] for v in values]) for k in first}
    if isinstance(first, torch.Tensor) and first.ndim > 0:
        return common.to_numpy(torch.stack(values))
    if isinstance(first, np.ndarray) and first.ndim > 0:
        return np.stack(values)
    return np.concatenate([common.to_numpy(common.batch(v)) for v in values])
