"""Policy evaluation: seeded episodes per layout, success with its interval, videos, a plot.

:func:`evaluate` runs a policy on ``episodes`` seeded episodes of every layout (seeds
``seed .. seed + episodes - 1``, the same for each layout), one task each of the episode
executor (``pipelines/runner.py``: this process, worker processes or Ray; one env per layout per
worker, reused across its episodes), and writes under ``out``:

- ``episodes.json``: per episode its layout, seed, success, fail, failure (``Episode.failure``:
  the stage and the conditions of success missed), steps, return and video;
- ``summary.json``: the success rate with its 95% Wilson interval overall and per layout, the
  fail rate, the failures counted by ``Episode.failure``, mean and median episode length and
  return;
- ``summary.png``: success per layout with its interval, and a histogram of episode lengths
  (drawn after ``summary.json`` is written: a plot that cannot be drawn is a warning);
- ``videos/<layout>_seed<seed>.mp4``, opt-in (``video="none"`` by default): with ``"all"`` or
  ``"fail"`` the first ``video_episodes`` episodes of each entry of ``layouts`` are filmed (a
  filmed episode costs ~50x an unfilmed one on the CPU), and of those ``"all"`` keeps every
  one, ``"fail"`` the unsuccessful ones; hybrid frames when the layout has a splat, the
  simulator's otherwise. Unfilmed episodes cost ~1.1x a bare gym loop
  (``tools/bench/bench_eval.py``).

An entry of ``layouts`` may be a layout set: each of its episodes runs in the layout its seed
draws (a reconfiguration), and ``per_layout`` reports every layout drawn.

Each episode is kept in ``OUT/.resume-eval/`` as it arrives: a run interrupted and started
again with the same ``--out`` and settings keeps them and runs the rest. Each file is written
under a temporary name and renamed when complete. An episode ends on
ManiSkill's ``terminated`` (``success`` or ``fail``) or at the env's episode limit; its
success is ``evaluate()["success"]`` at its end, as ``collect`` grades demonstrations.

Policies: :mod:`embodied_envs.pipelines.policies`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import statistics
import tempfile
import warnings
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym

from embodied_envs.paths import atomic_output
from embodied_envs.pipelines.episodes import Episode, expert, film_mode, run_episode, write_video
from embodied_envs.pipelines.executor import cached
from embodied_envs.pipelines.policies import EvalError, Policy, load_policy, policy_driver
from embodied_envs.pipelines.runner import executor_for, resume_store, run_episodes
from embodied_envs.registration import CONTROL_FREQ, ENV_ID
from embodied_envs.workers import WorkerError, started

VIDEO_CHOICES = ("all", "fail", "none")
WILSON_Z = 1.959963984540054  # two-sided 95% normal quantile


@dataclass(frozen=True)
class EvalPlan:
    """What to evaluate.

    Attributes:
        policy: ``expert``, ``random``, ``zero`` or ``module:factory``.
        layouts: layout files (absolute), or layout sets (tuples of files: each episode's seed
            draws its layout, a reconfiguration).
        episodes: seeded episodes per entry of ``layouts``.
        seed: the first episode seed.
        obs_mode: the env's observation mode (what the policy sees).
        control_mode: the env's control mode (None: the env's default; ``expert``:
            ``pd_joint_pos``).
        video: which filmed episodes are kept: ``all``, ``fail`` (unsuccessful ones) or
            ``none`` (nothing is filmed).
        video_episodes: the first episodes of each entry of ``layouts`` (seeds ``seed`` ..
            ``seed + video_episodes - 1``) that are filmed; later ones are not rendered.
        workers: processes (1: in this process); with ``ray``, the episodes running at once
            (0: the cluster's CPUs).
        env_kwargs: further ``gym.make`` keywords (``--config`` files).
        ray: None: on this machine; else on Ray (``pipelines/on_ray.py``): ``local`` (a Ray
            started for the run), ``auto`` or a cluster's address.
    """

    policy: str
    layouts: tuple[str | tuple[str, ...], ...]
    episodes: int
    seed: int = 0
    obs_mode: str = "state"
    control_mode: str | None = None
    video: str = "none"  # opt-in: a filmed episode costs ~50x an unfilmed one on the CPU
    video_episodes: int = 2
    workers: int = 1
    env_kwargs: dict = field(default_factory=dict)
    ray: str | None = None

    def env_make_kwargs(self, layout: str | tuple[str, ...], render: bool) -> dict:
        control = "pd_joint_pos" if self.policy == "expert" else self.control_mode
        layout_file = layout if isinstance(layout, str) else list(layout)
        kwargs = dict(self.env_kwargs, layout_file=layout_file, obs_mode=self.obs_mode)
        if control is not None:
            kwargs["control_mode"] = control
        if render:
            kwargs["render_mode"] = film_mode(layout)
        return kwargs | dict(sim_backend="physx_cpu")

    @property
    def renders(self) -> bool:
        """Whether any episode is filmed (the env then has a render mode)."""
        return self.video != "none" and self.video_episodes > 0

    def filmed(self, seed: int) -> bool:
        """Whether the episode of ``seed`` is filmed (the first ``video_episodes`` seeds)."""
        return self.renders and seed - self.seed < self.video_episodes

    def tasks(self) -> list[tuple[str | tuple[str, ...], int]]:
        return [(lay, self.seed + k) for lay in self.layouts for k in range(self.episodes)]

    def files(self) -> list[str]:
        """Every layout file the plan may use, in order."""
        return list(dict.fromkeys(f for x in self.layouts for f in _entry_files(x)))


def _entry_files(entry: str | tuple[str, ...]) -> tuple[str, ...]:
    return (entry,) if isinstance(entry, str) else tuple(entry)


def wilson_interval(successes: int, n: int, z: float = WILSON_Z) -> tuple[float, float]:
    """The Wilson score interval of a binomial proportion (95% by default); (0, 1) for n = 0.

    It holds the rate ``successes / n`` (exactly 0 below for no success, 1 above for all):
    rounding alone would put the bound a few ulps past the rate (e.g. 0/3, 10/10)."""
    if n == 0:
        return (0.0, 1.0)
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return (min(p, max(0.0, centre - half)), max(p, min(1.0, centre + half)))


def episode_json(episode: Episode) -> dict:
    """An episode as ``episodes.json`` holds it."""
    return dict(layout=episode.layout, seed=episode.seed, instruction=episode.instruction,
                success=episode.success, fail=episode.fail, failure=episode.failure,
                steps=episode.steps, video=episode.video,
                **{"return": episode.episode_return})  # fmt: skip


# --- episodes -----------------------------------------------------------------------------
class EpisodeRunner:
    """One process's envs (one per layout, made on first use) and the policy."""

    def __init__(self, plan: EvalPlan):
        self.plan = plan
        self.envs: dict[str, object] = {}
        self.policies: dict[str, Policy | None] = {}

    def env(self, layout: str | tuple[str, ...]):
        if layout not in self.envs:
            env = gym.make(ENV_ID, **self.plan.env_make_kwargs(layout, self.plan.renders))
            self.envs[layout] = env
            self.policies[layout] = load_policy(self.plan.policy, env)
            started()
        return self.envs[layout]

    def run(self, layout: str | tuple[str, ...], seed: int, video_dir: Path | None) -> Episode:
        env = self.env(layout)
        policy = self.policies[layout]
        filmed = self.plan.filmed(seed)
        drive = expert if policy is None else policy_driver(policy, self.plan.policy)
        episode = run_episode(env, seed, drive, film_every=1 if filmed else 0)
        keep = self.plan.video == "all" or not episode.success  # filmed: "all" or "fail"
        if filmed and keep and video_dir is not None:
            path = video_dir / f"{Path(episode.layout).stem}_seed{seed}.mp4"
            write_video(path, episode.frames, CONTROL_FREQ)
            episode.video = path.name
        episode.frames = []  # written: not sent back from a worker
        return episode

    def close(self) -> None:
        for env in self.envs.values():
            env.close()
        self.envs.clear()


# --- the task -----------------------------------------------------------------------------
def _eval_episode(plan: EvalPlan, layout, seed: int):
    """In a worker process (of this machine or Ray's): the episode of ``seed`` in ``layout``,
    and its video's bytes when one was kept."""
    runner = cached("eval", plan, lambda: EpisodeRunner(plan), EpisodeRunner.close)
    with tempfile.TemporaryDirectory(prefix="embodied-envs-seed-") as tmp:
        episode = runner.run(layout, seed, Path(tmp))
        files = {episode.video: (Path(tmp) / episode.video).read_bytes()} if episode.video else {}
    return episode, files


def policy_file(spec: str) -> Path | None:
    """The file a ``--policy`` value names (``file.py:factory``, a TorchScript file), if any."""
    name = spec.rpartition(":")[0] if ":" in spec else spec
    path = Path(name)
    return path.resolve() if name.endswith((".py", ".pt", ".ts")) and path.is_file() else None


def _run(plan: EvalPlan, out: Path, progress, on_resume):
    """``plan``'s episodes by its executor, kept in the run's resume store: (each one's store
    folder, the episode) in task order, the store, and (workers, nodes).

    Raises:
        Exception: what an episode raised in a worker, naming the ``--policy`` value as given.
    """
    file = policy_file(plan.policy)
    sent = plan
    if file is not None:  # the policy's file named absolutely: it travels with a Ray job
        sent = dataclasses.replace(plan, policy=plan.policy.replace(
            plan.policy.rpartition(":")[0] or plan.policy, str(file), 1))  # fmt: skip
    files = [file] if file is not None else []
    store = resume_store(out, "eval", plan, plan.layouts, files)
    executor = executor_for(plan.ray, plan.workers, plan.layouts, files)
    tasks = [(f"{k:06d}", (sent, *task)) for k, task in enumerate(plan.tasks())]
    try:
        episodes = run_episodes(executor, store, _eval_episode, tasks, progress,
                                on_resume=on_resume)  # fmt: skip
    except WorkerError as e:
        raise EvalError(f"evaluation stopped: {e}") from None
    except Exception as e:  # the policy named as the user gave it
        if sent is not plan:
            e.args = tuple(a.replace(sent.policy, plan.policy) if isinstance(a, str) else a
                           for a in e.args)  # fmt: skip
        raise
    ran = (executor.ran.workers, executor.ran.nodes)
    return [(store.path(key), episodes[key]) for key, _ in tasks], store, ran


# --- the whole evaluation ------------------------------------------------------------------
def summarize(plan: EvalPlan, results: list[Episode]) -> dict:
    """Success rate with its 95% Wilson interval, overall and per layout, and lengths."""

    def block(rs: list[Episode]) -> dict:
        n, k = len(rs), sum(r.success for r in rs)
        steps = [r.steps for r in rs] or [0]
        return {
            "episodes": n,
            "successes": k,
            "success_rate": k / n if n else 0.0,
            "success_ci95": list(wilson_interval(k, n)),
            "fail_rate": sum(r.fail for r in rs) / n if n else 0.0,
            "failures": dict(Counter(r.failure for r in rs if r.failure)),  # Episode.failure
            "steps_mean": statistics.fmean(steps),
            "steps_median": statistics.median(steps),
            "return_mean": statistics.fmean([r.episode_return for r in rs] or [0.0]),
        }

    return {
        "env_id": ENV_ID,
        "policy": plan.policy,
        "obs_mode": plan.obs_mode,
        "control_mode": "pd_joint_pos" if plan.policy == "expert" else plan.control_mode,
        "seeds": [plan.seed, plan.seed + plan.episodes - 1],
        **block(results),
        "per_layout": {
            lay: block([r for r in results if r.layout == lay])
            for lay in plan.files()
            if any(r.layout == lay for r in results) or lay in plan.layouts
        },
    }


def plot_summary(summary: dict, results: list[Episode], path: Path) -> None:
    """Success per layout with its interval, and the histogram of episode lengths."""
    # matplotlib (0.2 s to import) only where a summary is plotted, not for `--help`
    import matplotlib

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt  # after choosing the backend

    per = summary["per_layout"]
    names = [Path(lay).stem for lay in per]
    rates = [b["success_rate"] for b in per.values()]
    # error bars are lengths: never negative, whatever the interval's rounding
    lo = [max(0.0, b["success_rate"] - b["success_ci95"][0]) for b in per.values()]
    hi = [max(0.0, b["success_ci95"][1] - b["success_rate"]) for b in per.values()]
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    left.bar(names, rates, yerr=[lo, hi], capsize=6, color="tab:blue")
    left.set_ylim(0, 1.05)
    left.set_ylabel("success rate (95% Wilson interval)")
    left.set_title(f"{summary['policy']}: {summary['success_rate']:.0%} overall")
    left.tick_params(axis="x", labelrotation=30)
    right.hist([r.steps for r in results], bins=20, color="tab:gray")
    right.set_xlabel("episode length (control steps)")
    right.set_ylabel("episodes")
    fig.tight_layout()
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)


def evaluate(
    plan: EvalPlan, out: Path, progress: Callable | None = None, on_resume: Callable | None = None
) -> dict:
    """Run the evaluation and write its files under ``out`` (see the module docstring).

    Args:
        plan: what to evaluate.
        out: the output folder.
        progress: optional callable taking each episode (for a progress bar).
        on_resume: optional callable taking the number of episodes an interrupted run of the
            same settings kept in ``out`` (``OUT/.resume-eval/``) and that folder, when it
            kept any: this run keeps them and runs the rest.

    Returns:
        The summary (also ``out/summary.json``).

    Raises:
        EvalError: the policy cannot be used, a worker died, or ``out`` holds an earlier
            evaluation.
        ResumeError: ``out`` holds an interrupted evaluation of other settings.
    """
    out = Path(out)
    if (out / "summary.json").exists():
        raise EvalError(
            f"{out} holds an earlier evaluation (summary.json). Fix: choose another --out, or "
            "remove that folder"
        )
    out.mkdir(parents=True, exist_ok=True)
    entries, store, ran = _run(plan, out, progress, on_resume)
    for folder, r in entries:  # the kept videos, from the store
        if r.video is not None:
            (out / "videos").mkdir(exist_ok=True)
            with atomic_output(out / "videos" / r.video) as tmp:
                tmp.write_bytes((folder / r.video).read_bytes())
    results = [r for _, r in entries]
    order = {lay: i for i, lay in enumerate(plan.files())}
    results.sort(key=lambda r: (order[r.layout], r.seed))
    summary = summarize(plan, results) | dict(workers=ran[0], nodes=ran[1])
    with atomic_output(out / "episodes.json") as tmp:
        tmp.write_text(json.dumps([episode_json(r) for r in results], indent=2))
    with atomic_output(out / "summary.json") as tmp:  # its presence marks a complete run
        tmp.write_text(json.dumps(summary, indent=2))
    store.remove()  # complete: nothing to resume
    try:  # the summary is written: a plot that cannot be drawn must not lose it
        plot_summary(summary, results, out / "summary.png")
    except Exception as e:  # matplotlib's, whatever they are: one line
        warnings.warn(f"{out / 'summary.png'} not drawn: {type(e).__name__}: {e}", stacklevel=2)
    return summary
