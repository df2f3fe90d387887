"""The one way episodes run (``pipelines/runner.py`` over ``pipelines/executor.py``'s
backends): tasks in order, each result kept as it arrives, a resumed run keeping what the store
holds; ``collect --workers 2`` interrupted by Ctrl-C and run again gives, seed for seed, the
dataset of an uninterrupted run."""

import json
import os
import signal
import subprocess
import sys
import time
from concurrent.futures import Future
from dataclasses import asdict
from pathlib import Path

import h5py
import numpy as np
import pytest

from embodied_envs.pipelines.episodes import Episode
from embodied_envs.pipelines.executor import EpisodeExecutor, chained
from embodied_envs.pipelines.resume import ResumeError, ResumeStore
from embodied_envs.pipelines.runner import run_episodes

CLI = [sys.executable, "-m", "embodied_envs.cli.main"]
ENV = {**os.environ, "MS_SKIP_ASSET_DOWNLOAD_PROMPT": "1", "OMP_NUM_THREADS": "1"}
SEED, NUM = 40, 6  # --obs-mode state demos of the default layout


class Here(EpisodeExecutor):
    """A backend that runs each task at once, in this process, and counts them; two are
    submitted at a time."""

    slots = 2

    def __init__(self):
        super().__init__()
        self.submitted = []

    def submit(self, fn, /, *args) -> Future:
        self.submitted.append(args)
        done: Future = Future()
        try:
            done.set_result((fn(*args), "here", 0))
        except Exception as e:
            done.set_exception(e)
        return chained(done, self.ran, lambda e: e)

    def shutdown(self, cancel_futures: bool = False) -> None:
        pass


def episode(seed: int) -> tuple[Episode, dict]:
    if seed == 99:
        raise ValueError("seed 99 is bad")
    return Episode("a.json", seed, seed % 2 == 0, False, 10, 1.0), {"x.bin": bytes([seed])}


def tasks(seeds) -> list:
    return [(f"seed_{s:06d}", (s,)) for s in seeds]


def test_a_resumed_run_keeps_what_the_store_holds_and_runs_the_rest(tmp_path):
    store = ResumeStore(tmp_path / ".resume-x", {"plan": 1})
    first, arrived = Here(), []
    with pytest.raises(ValueError, match="seed 99 is bad"):
        run_episodes(first, store, episode, tasks([1, 2, 99, 3]), progress=arrived.append)
    # 3 arrived with the error (submitted beside 99): kept before the error is raised
    assert [e.seed for e in arrived] == [1, 2, 3]
    assert store.keys() == ["seed_000001", "seed_000002", "seed_000003"]
    assert (store.path("seed_000002") / "x.bin").read_bytes() == bytes([2])
    again, resumed, arrived = Here(), [], []
    got = run_episodes(again, store, episode, tasks([1, 2, 3, 4]), progress=arrived.append,
                       on_resume=lambda n, folder: resumed.append((n, folder)))  # fmt: skip
    assert resumed == [(3, store.folder)]
    assert again.submitted == [(4,)], "each seed once over both runs"
    assert [e.seed for e in arrived] == [1, 2, 3, 4] and sorted(got) == store.keys()
    with pytest.raises(ResumeError, match="interrupted run of other settings"):
        ResumeStore(store.folder, {"plan": 2})


def two_successes(results: dict) -> bool:
    return sum(e.success for e in results.values()) >= 2


def test_enough_stops_submitting(tmp_path):
    store = ResumeStore(tmp_path / ".resume-x", {"plan": 1})
    executor = Here()
    got = run_episodes(executor, store, episode, tasks(range(10)), enough=two_successes)
    assert sorted(e.seed for e in got.values()) == [0, 1, 2, 3], "two at a time, then enough"
    assert len(executor.submitted) == 4
    assert json.loads((store.path("seed_000000") / "episode.json").read_text()) == asdict(got[
        "seed_000000"])  # fmt: skip


def collect(out: Path, *extra: str, **popen):
    args = [*CLI, "collect", "--num", str(NUM), "--seed", str(SEED), "--obs-mode", "state",
            "--out", str(out), *extra]  # fmt: skip
    if popen:
        return subprocess.Popen(args, env=ENV, **popen)
    return subprocess.run(args, env=ENV, capture_output=True, text=True, timeout=600)


def arrays(dataset: Path) -> dict[int, dict[str, np.ndarray]]:
    """Per episode seed: every array of its trajectory (actions, observations, states...)."""
    meta = json.loads((dataset / "trajectory.json").read_text())
    out = {}
    with h5py.File(dataset / "trajectory.h5") as f:
        for e in meta["episodes"]:
            leaves = {}
            f[f"traj_{e['episode_id']}"].visititems(
                lambda name, obj, leaves=leaves: leaves.__setitem__(name, obj[()])
                if isinstance(obj, h5py.Dataset) else None
            )  # fmt: skip
            out[e["episode_seed"]] = leaves
    return out


def ctrl_c_default() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.slow  # three collects of 6 demos: about a minute on the 2-core machine
def test_ctrl_c_then_the_same_command_resumes_with_workers(tmp_path):
    ref = collect(tmp_path / "ref", "--workers", "1")
    assert ref.returncode == 0, ref.stdout + ref.stderr
    out = tmp_path / "out"
    store = out / ".resume-default"
    # its own process group, Ctrl-C's default (a shell's background job would ignore it)
    proc = collect(out, "--workers", "2", stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                   text=True, start_new_session=True, preexec_fn=ctrl_c_default)  # fmt: skip
    deadline = time.time() + 300
    while len(list(store.glob("seed_*"))) < 1 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C: the whole process group
    _, err = proc.communicate(timeout=120)
    kept = sorted(store.glob("seed_*"))
    assert proc.returncode == 130, err
    assert 1 <= len(kept) < NUM, "interrupted midway"
    assert f"interrupted: kept the episodes received ({len(kept)} in {store})" in err
    assert "Traceback" not in err
    assert not list(out.glob(".collect-*")) and not (out / "default").exists()
    record = json.loads((kept[0] / "episode.json").read_text())  # marked: kept, not run again
    (kept[0] / "episode.json").write_text(json.dumps(dict(record, instruction="first run's")))
    res = collect(out, "--workers", "2")
    assert res.returncode == 0, res.stdout + res.stderr
    n = len(kept)
    assert f"resuming an interrupted run: kept {n} episode{'s' * (n != 1)} from {store}" in (
        res.stdout)  # fmt: skip
    meta = json.loads((out / "default" / "trajectory.json").read_text())
    assert [e["episode_seed"] for e in meta["episodes"]] == list(range(SEED, SEED + NUM))
    marked = [e["episode_seed"] for e in meta["episodes"] if e["instruction"] == "first run's"]
    assert marked == [record["seed"]]
    got, want = arrays(out / "default"), arrays(tmp_path / "ref" / "default")
    assert got.keys() == want.keys()
    for seed in want:
        assert got[seed].keys() == want[seed].keys(), seed
        for name in want[seed]:
            assert np.array_equal(got[seed][name], want[seed][name]), f"seed {seed}: {name}"
    assert sorted(p.name for p in out.iterdir()) == ["default"], "the store is removed"
