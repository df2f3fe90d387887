"""Outputs under faults: a killed command, a full disk, two layouts into one folder."""

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import DEFAULT_LAYOUT, snapshot

from embodied_envs.cli.main import main

CLI = [sys.executable, "-m", "embodied_envs.cli.main"]


def finals(out: Path) -> list[Path]:
    return sorted(p for p in out.glob("*.json") if not p.name.startswith("."))


def processes_mentioning(text: str) -> list[int]:
    found = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            try:
                if text in (proc / "cmdline").read_bytes().decode(errors="ignore"):
                    found.append(int(proc.name))
            except OSError:
                continue
    return found


def test_kill_9_leaves_whole_files_and_no_workers(tmp_path):
    out = tmp_path / "variants_killed"
    cmd = [*CLI, "layout", "generate", str(DEFAULT_LAYOUT), "--num", "3000", "--workers", "2",
           "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while len(finals(out)) < 20 and time.time() < deadline:
        time.sleep(0.2)
    assert len(finals(out)) >= 20, "the command should be writing variants"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    try:
        time.sleep(2.0)  # the workers notice within PARENT_CHECK_SECONDS
        after_kill = len(finals(out))
        time.sleep(2.0)
        assert len(finals(out)) == after_kill, "no orphaned worker writes on"
        assert processes_mentioning(str(out)) == [], "every worker ended with its parent"
    finally:
        for pid in processes_mentioning(str(out)):  # a failing run leaves no strays behind
            os.kill(pid, signal.SIGKILL)
    assert 20 <= after_kill < 3000
    for path in finals(out):  # every file under its final name is whole
        data = json.loads(path.read_text())
        assert set(data["position"]) >= {"can", "table", "franka"}


def test_full_disk_is_one_line_and_leaves_no_partial_file(tmp_path, monkeypatch, capsys):
    out = tmp_path / "variants"
    real = Path.write_text

    def full(self, *args, **kwargs):
        if out in self.parents:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", full)
    code = main(["layout", "generate", str(DEFAULT_LAYOUT), "--num", "2", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1
    assert len(err) == 1 and "No space left on device" in err[0] and "Traceback" not in err[0]
    assert list(out.iterdir()) == []


def test_variants_of_another_layout_are_not_replaced(tmp_path, scene_copy, capsys):
    out = tmp_path / "variants"
    assert main(["layout", "generate", str(DEFAULT_LAYOUT), "--num", "2", "--out", str(out)]) == 0
    before = snapshot(out)
    other = scene_copy / "layouts" / "default.json"  # same stem, another file
    with pytest.raises(SystemExit) as e:
        main(["layout", "generate", str(other), "--num", "2", "--out", str(out)])
    msg = str(e.value.code)
    assert "already holds variants default_*.json of" in msg and str(DEFAULT_LAYOUT) in msg
    assert "Fix: choose another --out" in msg
    assert snapshot(out) == before
    # the same layout again is fine: its own variants are re-written
    assert main(["layout", "generate", str(DEFAULT_LAYOUT), "--num", "2", "--out", str(out)]) == 0


def collect_cmd(out, *extra):
    return [*CLI, "collect", "--num", "1", "--out", str(out), *extra]


def test_one_collect_at_a_time_per_out_and_no_dataset_replaced(tmp_path):
    """A second run into a held --out is refused at once; a finished dataset is never
    replaced by another shard; the first run's dataset is whole."""
    out = tmp_path / "out"
    env = {**os.environ, "MS_SKIP_ASSET_DOWNLOAD_PROMPT": "1"}
    # 60 demos (about 12 s of episodes here): the second run's start-up and refusal (2-3 s,
    # 10 s and more on a loaded machine: 30 demos were done before it once) must fall within
    # the first run's work
    first = subprocess.Popen(collect_cmd(out, "--num", "60"), env=env, text=True,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
    deadline = time.time() + 120
    while not list(out.glob(".collect-*")) and time.time() < deadline:
        time.sleep(0.1)
    assert list(out.glob(".collect-*")), "the first run is working"
    t = time.time()
    second = subprocess.run(collect_cmd(out, "--seed", "100"), env=env, capture_output=True,
                            text=True, timeout=120)  # fmt: skip
    assert second.returncode == 1 and time.time() - t < 30
    assert first.poll() is None, "refused while the first run works, not after it"
    assert "being written by another embodied-envs collect" in second.stdout
    stdout, _ = first.communicate(timeout=300)
    assert first.returncode == 0 and "default.json: 60 demonstrations" in stdout
    before = snapshot(out)
    shard = subprocess.run(collect_cmd(out, "--seed", "100"), env=env, capture_output=True,
                           text=True, timeout=300)  # fmt: skip
    assert shard.returncode == 1
    assert "already holds a dataset of" in shard.stdout and "episode seeds 0-59" in shard.stdout
    assert "merge_trajectory" in shard.stdout
    assert snapshot(out) == before, "the first dataset is untouched"


def test_a_killed_runs_work_folder_is_removed_by_the_next_run(tmp_path):
    out = tmp_path / "out"
    stale = out / ".collect-default.dead"
    stale.mkdir(parents=True)
    (stale / "part000.h5").write_bytes(b"half a file")
    env = {**os.environ, "MS_SKIP_ASSET_DOWNLOAD_PROMPT": "1"}
    res = subprocess.run(collect_cmd(out), env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    assert sorted(p.name for p in out.iterdir()) == ["default"]


@pytest.mark.parametrize("workers", ["1", "2"])
def test_a_worker_failing_before_its_loop_ends_collect_in_one_line(tmp_path, workers):
    """A config value ManiSkill refuses inside the worker's env: the command ends within
    seconds with one error line and exit 1, leaving no partial dataset."""
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("reward_mode: bogus\n")
    out = tmp_path / "out"
    env = {**os.environ, "MS_SKIP_ASSET_DOWNLOAD_PROMPT": "1"}
    env.pop("EMBODIED_ENVS_DEBUG", None)
    t = time.time()
    res = subprocess.run(collect_cmd(out, "--num", "2", "--workers", workers, "--config",
                                     str(cfg)), env=env, capture_output=True, text=True,
                         timeout=120)  # fmt: skip
    assert res.returncode == 1 and time.time() - t < 60
    lines = [x for x in res.stdout.splitlines() if x.startswith("error:")]
    assert len(lines) == 1 and "Unsupported reward mode: bogus" in lines[0], res.stdout
    assert "Traceback" not in res.stderr
    assert list(out.iterdir()) == [], "no dataset and no work folder left"
