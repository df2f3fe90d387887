"""The package installed from a wheel, without the source tree: its data and every command.

The wheel is built from a copy of the checkout, installed with ``--no-deps`` into a fresh
virtual environment that sees this one's dependencies (a ``.pth`` line, so the editable
install's import hook is not run there), and used from a folder outside the checkout.
"""

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from conftest import ROOT

IGNORED = shutil.ignore_patterns(".venv", ".git", "outputs", "build", "*.egg-info", "__pycache__")


def sh(args, cwd, timeout=300):
    env = {**os.environ, "MS_SKIP_ASSET_DOWNLOAD_PROMPT": "1"}
    env.pop("PYTHONPATH", None)
    res = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert res.returncode == 0, f"{args}\n{res.stdout}\n{res.stderr}"
    return res.stdout


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    shutil.copytree(ROOT, src, symlinks=True, ignore=IGNORED)
    sh([sys.executable, "-m", "pip", "wheel", ".", "--no-deps", "--no-build-isolation",
        "-q", "-w", str(tmp / "dist")], src)  # fmt: skip
    shutil.rmtree(src)  # nothing of the source tree is left to find
    venv = tmp / "venv"
    sh([sys.executable, "-m", "venv", "--without-pip", str(venv)], tmp)
    py = venv / "bin" / "python"
    site = Path(sh([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                   tmp).strip())  # fmt: skip
    (site / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    wheel = next((tmp / "dist").glob("embodied_envs-*.whl"))
    sh([sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps", "--no-index",
        "-q", str(wheel)], tmp)  # fmt: skip
    work = tmp / "elsewhere"
    work.mkdir()
    return py, venv / "bin" / "embodied-envs", site, work


def test_the_installed_package_makes_the_default_env_with_its_own_data(installed):
    py, _, site, work = installed
    code = (
        "import gymnasium as gym, embodied_envs, json\n"
        "from embodied_envs.paths import default_layout\n"
        "env = gym.make('PickEmbodiedGen-v1', render_mode='hybrid')\n"
        "env.reset(seed=0)\n"
        "frame = env.render()\n"
        "print(json.dumps(dict(pkg=embodied_envs.__file__, layout=str(default_layout()),\n"
        "    shape=list(frame.shape), mean=float(frame.float().mean()))))\n"
    )
    out = json.loads(sh([str(py), "-c", code], work).strip().splitlines()[-1])
    assert out["pkg"].startswith(str(site)), "the wheel's package, not the source tree"
    assert out["layout"].startswith(str(site)) and Path(out["layout"]).is_file()
    assert out["shape"] == [1, 256, 256, 3] and out["mean"] > 60, "the room is drawn"


def test_every_command_runs_from_another_folder(installed):
    py, cli, site, work = installed
    layout = site / "embodied_envs" / "data" / "layouts" / "default.json"
    ply = site / "embodied_envs" / "data" / "assets" / "background" / "gs_model.ply"
    assert sh([str(cli), "layout", "validate", str(layout)], work).startswith("ok ")
    sh([str(cli), "layout", "generate", str(layout), "--num", "2", "--out", "gen"], work)
    assert len(list((work / "gen").glob("*.json"))) == 2
    sh([str(cli), "layout", "preview", str(layout), "--out", "preview.png"], work)
    sh([str(cli), "splat", "render", str(ply), "--eye", "0", "1.3", "0", "--target", "2", "1",
        "-1", "--up", "0", "1", "0", "--width", "64", "--height", "48", "--out", "room.png"],
       work)  # fmt: skip
    assert (work / "preview.png").is_file() and (work / "room.png").is_file()
    sh([str(cli), "demo", "--episodes", "1", "--out", "demo"], work)  # the default layout
    assert (work / "demo" / "summary.json").is_file()
    sh([str(cli), "collect", "--num", "1", "--out", "demos"], work)
    traj = work / "demos" / "default" / "trajectory.h5"
    assert traj.is_file()
    sh([str(cli), "replay", "--traj-path", str(traj), "-o", "state", "--save-traj"], work)
    assert list((work / "demos" / "default").glob("trajectory.state.*.h5"))
    out = sh([str(cli), "eval", "--policy", "zero", "--episodes", "1", "--max-episode-steps",
              "3", "--video", "none", "--out", "eval"], work)  # fmt: skip
    assert "zero: 0/1 successful" in out
