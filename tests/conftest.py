import copy
import json
import os
import shutil
from pathlib import Path

import pytest

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "embodied_envs" / "data"  # the shipped data (./layouts and ./assets link here)
# the shipped pick layouts: the per-layout tests written for the pick task run on these; the
# place and move layouts are tested in tests/envs/test_tasks.py
TASK_LAYOUTS = ("place_box", "place_bowl", "place_tray", "place_two", "move_left")
# the layouts of other robots than the Panda: tested with their robot (tests/solvers/test_hands.py)
ROBOT_LAYOUTS = ("so100_block", "koch_block")
LAYOUTS = sorted(
    p for p in (DATA / "layouts").glob("*.json") if p.stem not in TASK_LAYOUTS + ROBOT_LAYOUTS
)
DEFAULT_LAYOUT = DATA / "layouts" / "default.json"
# the normalised dense reward's largest fall between two steps of an expert episode: below a
# whole stage's weight (1/4 of pick's reward; 1/6 of a mover's share: 1/12 with two movers), so
# losing a stage shows; the smooth terms (settle, static, distances) move less at its speeds
REWARD_FALL_TOL = 0.05


@pytest.fixture
def layout_dict():
    return json.loads(DEFAULT_LAYOUT.read_text())


@pytest.fixture
def scene_copy(tmp_path):
    """A copy of the shipped layouts and assets in a temporary folder (same relative layout)."""
    shutil.copytree(DATA / "assets", tmp_path / "assets")
    shutil.copytree(DATA / "layouts", tmp_path / "layouts")
    return tmp_path


def write_layout(folder: Path, data: dict, name: str = "layout.json") -> Path:
    path = folder / name
    path.write_text(json.dumps(data))
    return path


def snapshot(folder: Path) -> dict:
    """Every file under a folder with its size and mtime, to prove nothing was written."""
    return {
        str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
    }


def deep(d):
    return copy.deepcopy(d)


def per_layout_env(layouts: list[Path] = LAYOUTS, **kwargs):
    """A module-scoped fixture: one ``PickEmbodiedGen-v1`` env per layout (default: every
    shipped one)."""

    @pytest.fixture(scope="module", params=layouts, ids=[p.stem for p in layouts])
    def fixture(request):
        import gymnasium as gym

        import embodied_envs  # noqa: F401

        env = gym.make("PickEmbodiedGen-v1", layout_file=str(request.param), **kwargs)
        yield env
        env.close()

    return fixture


def make_unreadable(path: Path, monkeypatch) -> None:
    """Make a file unreadable to this process: mode 000, and, where the tests run as root (who
    reads any file), ``open`` refusing it as the kernel refuses other users."""
    import builtins
    import errno

    os.chmod(path, 0)
    if os.geteuid() != 0:
        return
    real_open, target = builtins.open, os.path.realpath(path)

    def guarded(file, *args, **kwargs):
        if isinstance(file, str | os.PathLike) and os.path.realpath(file) == target:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), os.fspath(file))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", guarded)


def panda_planner():
    """mplib's planner of ManiSkill's Panda to its TCP (``panda_hand_tcp``), its base at the
    origin: what the expert plans with, without an env."""
    # mplib and ManiSkill's robot classes: for the solver tests that use them only
    import mplib
    from mani_skill.agents.robots import Panda

    mp = mplib.Planner(urdf=Panda.urdf_path, srdf=Panda.urdf_path.replace(".urdf", ".srdf"),
                       move_group="panda_hand_tcp")  # fmt: skip
    mp.set_base_pose([0, 0, 0, 1, 0, 0, 0])
    return mp


def solve_watching_close(layout: Path, seed: int, look) -> tuple:
    """The expert on ``layout``'s episode ``seed`` (``pd_joint_pos``), ``look(solver)`` called
    right before and right after each gentle close of the jaw: ``(env, solver, [(before,
    after) per close])``."""
    import gymnasium as gym

    import embodied_envs  # noqa: F401
    from embodied_envs.solvers import PickPlaceSolver

    env = gym.make("PickEmbodiedGen-v1", layout_file=str(layout), control_mode="pd_joint_pos")
    env.reset(seed=seed)
    solver, seen = PickPlaceSolver(env, seed=seed), []
    gentle = solver._close_gently

    def watched(envs):
        before = look(solver)
        gentle(envs)
        seen.append((before, look(solver)))

    solver._close_gently = watched
    solver.solve()
    return env, solver, seen


# The slow lane: the test files whose tests took 10.5 s or more together on the 2-core machine
# (`pytest -n auto --dist loadfile --durations=0`), with their module fixtures. The quick lane,
# `bash tools/test.sh -m "not slow"`, runs the rest in under two minutes; CI runs both.
SLOW_FILES = {
    "tests/cli/test_collect.py", "tests/pipelines/test_ray.py", "tests/envs/test_layout_sets.py",
    "tests/test_wheel.py", "tests/layout/test_episode.py", "tests/cli/test_faults.py",
    "tests/datasets/test_joint_actions.py", "tests/pipelines/test_evaluate.py",
    "tests/envs/test_reliability.py", "tests/pipelines/test_runner.py",
    "tests/envs/test_robots.py", "tests/envs/test_hybrid.py", "tests/cli/test_cli.py",
    "tests/envs/test_vector.py", "tests/datasets/test_recorder.py",
    "tests/pipelines/test_visual_policy.py", "tests/solvers/test_modes.py",
    "tests/envs/test_rooms.py", "tests/test_structure.py", "tests/envs/test_pick_env.py",
    "tests/cli/test_embodiedgen_layout.py", "tests/datasets/test_ee_actions.py",
    "tests/layout/test_collision.py", "tests/envs/test_hollows.py",
}  # fmt: skip


def pytest_collection_modifyitems(config, items):
    slow = pytest.mark.slow
    for item in items:
        if Path(item.path).resolve().relative_to(ROOT).as_posix() in SLOW_FILES:
            item.add_marker(slow)


@pytest.fixture
def fresh(monkeypatch, tmp_path):
    """An empty collision cache, decompositions allowed, this process's memory of them
    cleared (tests of layout/collision.py and layout/hollow.py)."""
    from embodied_envs.layout import collision as col  # the tests that ask for it only

    monkeypatch.setenv(col.CACHE_ENV, str(tmp_path / "cache"))
    monkeypatch.delenv(col.OPT_OUT_ENV, raising=False)
    col._convex_collision.cache_clear()
    col._WARNED.clear()
    yield tmp_path / "cache" / "collision"
    col._convex_collision.cache_clear()
