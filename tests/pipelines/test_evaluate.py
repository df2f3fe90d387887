"""`embodied-envs eval`: policies on seeded episodes, summaries with intervals, clear errors."""

import json

import pytest
from conftest import DEFAULT_LAYOUT, LAYOUTS

from embodied_envs.cli.main import main
from embodied_envs.layout import load_layout
from embodied_envs.pipelines import evaluate as evaluate_module
from embodied_envs.pipelines.evaluate import (
    Episode,
    EvalError,
    EvalPlan,
    evaluate,
    plot_summary,
    summarize,
    wilson_interval,
)

POLICIES = '''
import numpy as np
import torch


class Still(torch.nn.Module):
    """A torch module: the zero action of the right shape, batched."""

    def __init__(self, dim):
        super().__init__()
        self.dim = dim

    def forward(self, obs):
        return torch.zeros((obs.shape[0], self.dim))


def module_policy(env):
    return Still(env.action_space.shape[0])


def wrong_shape():
    return lambda obs: np.zeros(3, np.float32)


def nan_after_two(env):
    steps = []

    def act(obs):
        steps.append(1)
        a = np.zeros(env.action_space.shape, np.float32)
        return a if len(steps) <= 2 else a * np.nan

    return act


def raises_at_three(env):
    steps = []

    def act(obs):
        steps.append(1)
        if len(steps) > 3:
            raise ValueError("weights not loaded")
        return np.zeros(env.action_space.shape, np.float32)

    return act


class ResetRaises:
    def __call__(self, obs):
        return np.zeros(8, np.float32)

    def reset(self, seed):
        raise KeyError(seed)


def returns_none():
    return lambda obs: None
'''


@pytest.fixture(scope="module")
def policies(tmp_path_factory):
    folder = tmp_path_factory.mktemp("policies")
    (folder / "user_policies.py").write_text(POLICIES)
    return folder / "user_policies.py"


def plan(policy, **kw):
    kw.setdefault("layouts", (str(DEFAULT_LAYOUT),))
    kw.setdefault("episodes", 2)
    kw.setdefault("video", "none")
    kw.setdefault("env_kwargs", dict(max_episode_steps=15))
    return EvalPlan(policy=policy, **kw)


@pytest.mark.parametrize(
    "k, n, lo, hi",
    [(0, 10, 0.0, 0.2775), (5, 10, 0.2366, 0.7634), (10, 10, 0.7225, 1.0), (1, 1, 0.2065, 1.0)],
)
def test_wilson_interval_of_known_counts(k, n, lo, hi):
    got = wilson_interval(k, n)
    assert got == pytest.approx((lo, hi), abs=1e-4)


def test_zero_and_random_finish_without_success_and_random_is_seeded(tmp_path):
    zero = evaluate(plan("zero"), tmp_path / "zero")
    assert zero["successes"] == 0 and zero["episodes"] == 2
    assert zero["success_ci95"] == pytest.approx(list(wilson_interval(0, 2)))
    assert zero["steps_median"] == 15
    episodes = json.loads((tmp_path / "zero" / "episodes.json").read_text())
    assert [(e["seed"], e["success"], e["steps"]) for e in episodes] == [
        (0, False, 15),
        (1, False, 15),
    ]
    graded = load_layout(DEFAULT_LAYOUT).instruction  # the sentence the grade was read from
    assert [e["instruction"] for e in episodes] == [graded, graded]
    assert (tmp_path / "zero" / "summary.png").stat().st_size > 1000
    a = evaluate(plan("random", seed=7), tmp_path / "a")
    evaluate(plan("random", seed=7), tmp_path / "b")
    ra = json.loads((tmp_path / "a" / "episodes.json").read_text())
    rb = json.loads((tmp_path / "b" / "episodes.json").read_text())
    assert a["successes"] == 0 and [e["seed"] for e in ra] == [7, 8]
    assert [e["return"] for e in ra] == [e["return"] for e in rb], "the same seeds, the same run"
    assert ra[0]["return"] != ra[1]["return"]
    with pytest.raises(EvalError, match="holds an earlier evaluation"):
        evaluate(plan("zero"), tmp_path / "zero")


@pytest.mark.parametrize("layout", LAYOUTS, ids=[p.stem for p in LAYOUTS])
def test_expert_gives_the_successes_collect_gives_on_the_same_seeds(tmp_path, layout):
    from embodied_envs.pipelines.collect import CollectPlan, collect

    collected = collect(CollectPlan(layout=str(layout), num=2, seed=5), tmp_path)
    meta = json.loads((tmp_path / layout.stem / "trajectory.json").read_text())
    s = evaluate(plan("expert", layouts=(str(layout),), seed=5, env_kwargs={}), tmp_path / "e")
    episodes = json.loads((tmp_path / "e" / "episodes.json").read_text())
    assert [e["success"] for e in episodes] == [e["success"] for e in meta["episodes"]]
    assert [e["steps"] for e in episodes] == [e["elapsed_steps"] for e in meta["episodes"]]
    assert [e["instruction"] for e in episodes] == [e["instruction"] for e in meta["episodes"]]
    assert s["successes"] == collected.successes == 2, "the expert solves these seeds"
    assert s["per_layout"][str(layout)]["success_rate"] == 1.0


def test_a_torch_module_policy_runs_and_is_graded(tmp_path, policies):
    s = evaluate(plan(f"{policies}:module_policy", episodes=1), tmp_path)
    assert s["episodes"] == 1 and s["successes"] == 0 and s["steps_mean"] == 15


@pytest.mark.parametrize(
    "spec, message",
    [
        ("{file}:wrong_shape", "returned an action of shape (3,) at step 0 of episode seed 0"),
        (
            "{file}:nan_after_two",
            "non-finite action (NaN or inf) at step 2 of episode seed 0 "
            "(default.json); expected finite values of shape (8,)",
        ),
        (
            "{file}:raises_at_three",
            ":raises_at_three: the policy raised ValueError: weights "
            "not loaded at step 3 of episode seed 0 (default.json)",
        ),
        (
            "{file}:ResetRaises",
            ":ResetRaises: reset(seed) raised KeyError: 0 at step 0 of episode seed 0",
        ),
        (
            "{file}:returns_none",
            "returned an action of shape () at step 0 of episode seed 0 "
            "(default.json); the env's action space is (8,)",
        ),
        ("no_such_module_here:make", "cannot import 'no_such_module_here'"),
        ("{file}:missing", "has no attribute 'missing'"),
        ("noplace", "neither a built-in"),
    ],
)
def test_broken_policies_give_one_clear_line(tmp_path, policies, capsys, spec, message):
    spec = spec.format(file=policies)
    code = main(["eval", "--policy", spec, "--episodes", "1", "--max-episode-steps", "5",
                 "--video", "none", "--out", str(tmp_path / "out")])  # fmt: skip
    captured = capsys.readouterr()
    out = captured.out
    # no traceback: the message is on stdout's one line only (stderr may hold ManiSkill's logs)
    assert code == 1 and "Traceback" not in out and message not in captured.err
    line = [x for x in out.splitlines() if x.startswith("error:")]
    assert len(line) == 1 and message in line[0], out
    assert not (tmp_path / "out" / "summary.json").exists()


def test_cli_workers_videos_and_the_error_from_a_worker(tmp_path, policies, capsys):
    args = ["eval", "--episodes", "2", "--max-episode-steps", "4", "--workers", "2"]
    code = main([*args, "--policy", "zero", "--video", "all", "--out", str(tmp_path / "ok")])
    assert code == 0
    out = capsys.readouterr().out
    assert "zero: 0/2 successful" in out
    videos = sorted(p.name for p in (tmp_path / "ok" / "videos").iterdir())
    assert videos == ["default_seed0.mp4", "default_seed1.mp4"]
    import imageio.v3 as iio

    frames = iio.imread(tmp_path / "ok" / "videos" / videos[0])
    assert len(frames) == 5 and frames.shape[1:] == (256, 256, 3)  # reset + 4 steps
    assert frames[0].mean() > 60, "hybrid frames: the room, not the simulator's black"
    code = main([*args, "--policy", f"{policies}:wrong_shape", "--out", str(tmp_path / "bad")])
    assert code == 1 and "returned an action of shape (3,)" in capsys.readouterr().out


@pytest.mark.parametrize("n", [1, 2, 3, 6, 7, 10, 13, 25])
def test_every_count_of_successes_gives_a_summary_and_a_plot(tmp_path, n):
    """0/n and n/n for the counts whose interval bounds rounded past the rate (0/3, 10/10):
    the interval holds the rate exactly and the plot's error bars are not negative."""
    p = plan("zero", episodes=n)
    for k in (0, n // 2, n):
        results = [Episode(p.layouts[0], s, s < k, False, 5 + s, 0.5) for s in range(n)]
        summary = summarize(p, results)
        lo, hi = summary["success_ci95"]
        assert summary["successes"] == k and summary["success_rate"] == k / n
        assert lo <= k / n <= hi and (lo == 0.0) == (k == 0) and (hi == 1.0) == (k == n)
        assert summary["steps_median"] == 5 + (n - 1) / 2
        png = tmp_path / f"{n}_{k}.png"
        plot_summary(summary, results, png)
        assert png.stat().st_size > 1000


def test_zero_policy_from_the_cli_writes_its_summary_and_no_video_by_default(tmp_path, capsys):
    out = tmp_path / "zero"
    code = main(["eval", "--policy", "zero", "--episodes", "3", "--max-episode-steps", "3",
                 "--out", str(out)])  # fmt: skip
    assert code == 0, capsys.readouterr()
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["episodes"], summary["successes"], summary["success_rate"]) == (3, 0, 0.0)
    assert summary["success_ci95"] == [0.0, pytest.approx(0.5615, abs=1e-4)]
    assert "zero: 0/3 successful (0%, 95% interval 0%-56%)" in capsys.readouterr().out
    assert (out / "summary.png").is_file() and not (out / "videos").exists(), "opt-in videos"
    with pytest.raises(SystemExit):
        main(["eval", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "videos are opt-in" in help_text and "film only the first N episodes" in help_text


def test_one_episode_keeps_its_summary_when_the_plot_fails(tmp_path, monkeypatch):
    def broken_plot(*args):
        raise RuntimeError("no fonts")

    monkeypatch.setattr(evaluate_module, "plot_summary", broken_plot)
    with pytest.warns(UserWarning, match="summary.png not drawn: RuntimeError: no fonts"):
        s = evaluate(plan("zero", episodes=1, env_kwargs=dict(max_episode_steps=4)), tmp_path)
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    assert on_disk == s and s["episodes"] == 1 and s["steps_median"] == 4
    assert s["success_ci95"] == [0.0, pytest.approx(0.7935, abs=1e-4)]


def test_only_the_first_video_episodes_are_filmed(tmp_path):
    p = plan("zero", episodes=3, video="all", video_episodes=1,
             env_kwargs=dict(max_episode_steps=2))  # fmt: skip
    assert [p.filmed(seed) for seed in (0, 1, 2)] == [True, False, False]
    evaluate(p, tmp_path)
    episodes = json.loads((tmp_path / "episodes.json").read_text())
    assert [e["video"] for e in episodes] == ["default_seed0.mp4", None, None]
    assert sorted(x.name for x in (tmp_path / "videos").iterdir()) == ["default_seed0.mp4"]
