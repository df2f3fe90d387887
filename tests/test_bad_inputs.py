"""The bad-input corpus (tests/data/bad_inputs, made by tools/make/make_bad_inputs.py).

Every case fails at construction, before any simulation object exists, with the promised error
type and words; ``layout validate`` reports file problems with exit code 1; nothing is written
beside the inputs. The read-only case must work and write nothing.
"""

import json
import os
import stat

import gymnasium as gym
import numpy as np
import pytest
from conftest import DATA, ROOT, snapshot

import embodied_envs  # noqa: F401
from embodied_envs.cli.main import main as cli
from embodied_envs.layout import LayoutError, PlacementError
from embodied_envs.splat import SplatFileError

CORPUS = ROOT / "tests" / "data" / "bad_inputs"
CASES = sorted(p for p in CORPUS.iterdir() if (p / "case.json").is_file())
ERRORS = {
    "LayoutError": LayoutError,
    "PlacementError": PlacementError,
    "SplatFileError": SplatFileError,
    "ValueError": ValueError,
}


def spec(case):
    return json.loads((case / "case.json").read_text())


BAD = [c for c in CASES if spec(c)["error"]]


def test_corpus_covers_at_least_20_cases():
    assert len(BAD) >= 20
    assert all(spec(c)["error"] in ERRORS and spec(c)["words"] for c in BAD)


@pytest.fixture
def no_simulation(monkeypatch):
    from mani_skill.envs.sapien_env import BaseEnv

    def refuse(*args, **kwargs):
        raise AssertionError("the simulation was started before the bad input was reported")

    monkeypatch.setattr(BaseEnv, "__init__", refuse)


@pytest.fixture
def untouched():
    """Asserts afterwards that neither the corpus nor the shipped data changed."""
    folders = [CORPUS, DATA / "assets", DATA / "layouts"]
    before = [snapshot(f) for f in folders]
    yield
    assert [snapshot(f) for f in folders] == before


@pytest.mark.parametrize("case", BAD, ids=[c.name for c in BAD])
def test_env_rejects_bad_input_before_simulation(case, no_simulation, untouched):
    s = spec(case)
    with pytest.raises(ERRORS[s["error"]]) as e:
        gym.make("PickEmbodiedGen-v1", layout_file=str(case / "layout.json"), **s["env_kwargs"])
    assert type(e.value) is ERRORS[s["error"]]
    for word in s["words"]:
        assert word in str(e.value), f"{word!r} not in: {e.value}"


VALIDATED = [c for c in BAD if spec(c)["validate"]]


@pytest.mark.parametrize("case", VALIDATED, ids=[c.name for c in VALIDATED])
def test_layout_validate_reports_it_with_exit_code_1(case, capsys, untouched):
    code = cli(["layout", "validate", str(case / "layout.json")])
    out = capsys.readouterr().out
    assert code == 1
    assert out.startswith(f"FAIL {case / 'layout.json'}")
    for word in spec(case)["words"]:
        assert word in out, f"{word!r} not in: {out}"


def test_read_only_layout_folder_works_and_nothing_is_written_there(tmp_path, untouched):
    case = CORPUS / "read_only_folder"
    layout = case / "layout.json"
    mode = case.stat().st_mode
    os.chmod(case, stat.S_IRUSR | stat.S_IXUSR | stat.S_IRGRP | stat.S_IXGRP)
    os.chmod(layout, stat.S_IRUSR | stat.S_IRGRP)
    try:
        assert cli(["layout", "validate", str(layout)]) == 0
        out = tmp_path / "variants"
        assert cli(["layout", "generate", str(layout), "--num", "2", "--out", str(out)]) == 0
        assert len(list(out.glob("*.json"))) == 2
        env = gym.make("PickEmbodiedGen-v1", layout_file=str(layout), num_envs=1)
        try:
            env.reset(seed=1)
            for _ in range(5):
                obs, reward, *_ = env.step(np.zeros(env.action_space.shape, np.float32))
            assert np.isfinite(float(reward))
            env.reset(seed=2, options=dict(reconfigure=True))
        finally:
            env.close()
    finally:
        os.chmod(layout, stat.S_IRUSR | stat.S_IWUSR | stat.S_IRGRP)
        os.chmod(case, mode)
    assert sorted(p.name for p in case.iterdir()) == ["case.json", "layout.json"]
