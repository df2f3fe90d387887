"""A layout in EmbodiedGen's exact form (its layout designer's relation: task_desc ending
", robot franka.", the free task category in relation["task"], robot, background, context,
manipulated_objs, distractor_objs, in its order) goes through every command unchanged:
`layout validate`, `gym.make`, `layout generate`, `demo` and `collect`, with the expert's
success and the sentence recorded as the instruction."""

import json
import os
import subprocess
import sys

import gymnasium as gym
import pytest

from embodied_envs.cli.main import main

CLI = [sys.executable, "-m", "embodied_envs.cli.main"]
ENV = {**os.environ, "MS_SKIP_ASSET_DOWNLOAD_PROMPT": "1"}
SENTENCE = "Pick up the mug from the table and put it on the tray, robot franka."
SEED = 0  # the expert puts the mug on the tray at this seed (tests/envs/test_tasks.py too)


@pytest.fixture
def eg_layout(scene_copy):
    """place_tray's scene with its relation rewritten as EmbodiedGen writes it."""
    data = json.loads((scene_copy / "layouts" / "place_tray.json").read_text())
    old = data["relation"]
    data["relation"] = {
        "task_desc": SENTENCE, "task": "pick and place", "robot": "franka",
        "background": old["background"], "context": "table", "manipulated_objs": ["mug"],
        "distractor_objs": ["tray", "can", "bowl"],
    }  # fmt: skip
    path = scene_copy / "layouts" / "eg_pick_and_place.json"
    path.write_text(json.dumps(data, indent=4))
    return path


def run(args, cwd):
    res = subprocess.run(CLI + args, cwd=cwd, env=ENV, capture_output=True, text=True,
                         timeout=900)  # fmt: skip
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    return res


def test_an_embodiedgen_layout_validates_makes_generates_demos_and_collects(
    eg_layout, tmp_path, capsys
):
    assert main(["layout", "validate", str(eg_layout)]) == 0
    assert "eg_pick_and_place.json  task: place [mug] on tray" in capsys.readouterr().out

    env = gym.make("PickEmbodiedGen-v1", layout_file=str(eg_layout), obs_mode="state")
    try:
        env.reset(seed=SEED)
        u = env.unwrapped
        assert [t.describe() for t in u.tasks] == ["place [mug] on tray"]
        assert u.instructions == [SENTENCE]  # the sentence the grade was read from
    finally:
        env.close()

    out = tmp_path / "generated"
    assert main(["layout", "generate", str(eg_layout), "--num", "1", "--seed", "0",
                 "--out", str(out)]) == 0  # fmt: skip
    (written,) = out.glob("*.json")
    relation = json.loads(written.read_text())["relation"]
    assert relation["task"] == "pick and place" and relation["task_desc"] == SENTENCE
    assert list(relation) == list(json.loads(eg_layout.read_text())["relation"])

    demo = tmp_path / "demo"
    run(["demo", "--layout", str(eg_layout), "--seed", str(SEED), "--out", str(demo),
         "--render-mode", "rgb_array", "--frame-every", "50", "--image-hw", "32", "32"],
        tmp_path)  # fmt: skip
    (env0,) = json.loads((demo / "summary.json").read_text())["episodes"][0]["envs"]
    assert env0["success"] is True, env0

    run(["collect", "--layout", str(eg_layout), "--num", "1", "--seed", str(SEED),
         "--out", str(tmp_path / "data")], tmp_path)  # fmt: skip
    meta = json.loads((tmp_path / "data" / "eg_pick_and_place" / "trajectory.json").read_text())
    (episode,) = meta["episodes"]
    assert episode["success"] is True and episode["instruction"] == SENTENCE
