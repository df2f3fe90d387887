"""tools/recipes/train_bc.py: a state BC policy trained on collected demos, saved as
TorchScript, that `embodied-envs eval --policy FILE.pt` runs."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import DEFAULT_LAYOUT

from embodied_envs.cli.main import main
from embodied_envs.pipelines.collect import CollectPlan, collect

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools" / "recipes"))
import train_bc  # noqa: E402


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    out = tmp_path_factory.mktemp("bc_demos")
    collect(CollectPlan(layout=str(DEFAULT_LAYOUT), num=2, seed=3, obs_mode="state"), out)
    return out / DEFAULT_LAYOUT.stem / "trajectory.h5"


def test_the_policy_fits_its_demos_and_eval_runs_it(demos, tmp_path, capsys):
    out = tmp_path / "bc"
    train_bc.main(["--demos", str(demos), "--out", str(out), "--iters", "3000", "--seed", "1"])
    info = json.loads((out / "train.json").read_text())
    assert info["control_mode"] == "pd_joint_pos" and info["act_dim"] == 8
    assert info["env_id"] == "embodied_envs:PickEmbodiedGen-v1"
    obs, actions, _ = train_bc.load_pairs(demos, -1)
    assert info["pairs"] == len(obs) > 100
    policy = torch.jit.load(str(out / "policy.pt"))
    with torch.no_grad():
        pred = policy(torch.from_numpy(obs)).numpy()
    # two demos are learnt almost by heart: joint targets within a few hundredths of a radian
    assert np.abs(pred - actions)[:, :7].mean() < 0.03, np.abs(pred - actions).mean(0)
    assert (pred >= actions.min(0) - 1e-6).all() and (pred <= actions.max(0) + 1e-6).all()
    code = main(["eval", "--policy", str(out / "policy.pt"), "--control-mode", "pd_joint_pos",
                 "--episodes", "1", "--seed", "3", "--max-episode-steps", "20", "--video", "none",
                 "--out", str(tmp_path / "ev")])  # fmt: skip
    assert code == 0, capsys.readouterr().out
    episodes = json.loads((tmp_path / "ev" / "episodes.json").read_text())
    assert episodes[0]["steps"] == 20 and episodes[0]["seed"] == 3


def test_a_file_that_is_not_torchscript_is_one_line(tmp_path, capsys):
    bad = tmp_path / "weights.pt"
    torch.save({"w": torch.zeros(3)}, bad)
    code = main(["eval", "--policy", str(bad), "--episodes", "1", "--max-episode-steps", "5",
                 "--video", "none", "--out", str(tmp_path / "ev")])  # fmt: skip
    lines = [x for x in capsys.readouterr().out.splitlines() if x.startswith("error:")]
    assert code == 1 and len(lines) == 1
    assert "not a TorchScript module" in lines[0] and "torch.jit.save" in lines[0]
