"""`collect --ray` and `eval --ray` on a real Ray cluster of two nodes on this machine
(``ray.cluster_utils.Cluster``, one CPU each), started by the tests: the same data as one local
worker, a killed worker, an interrupted driver resumed, a worker's error (a policy's, a
layout's, a policy's exit) as the local line; a dead address, and a cluster of one node that
wants a token, refused in one line."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import DEFAULT_LAYOUT, ROOT

ray = pytest.importorskip("ray")
from ray.cluster_utils import Cluster  # noqa: E402

CLI = [sys.executable, "-m", "embodied_envs.cli.main"]
NODE = dict(num_cpus=1, object_store_memory=128 * 2**20)  # two of these: the check's 2 CPUs
SEED = 700


@pytest.fixture(scope="module")
def cluster():
    c = Cluster(initialize_head=True, head_node_args=dict(NODE, include_dashboard=False))
    c.add_node(**NODE)
    c.wait_for_nodes()
    yield c.address
    c.shutdown()


def cli(args, cwd, address=None, **popen):
    """The command line, with ``RAY_ADDRESS`` naming the test's cluster (``--ray auto``)."""
    env = dict(os.environ, MS_SKIP_ASSET_DOWNLOAD_PROMPT="1", OMP_NUM_THREADS="1")
    if address is not None:
        env["RAY_ADDRESS"] = address
    if popen:
        return subprocess.Popen(CLI + args, cwd=cwd, env=env, **popen)
    return subprocess.run(CLI + args, cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=900)  # fmt: skip


def collect_args(out: Path, num: int, *extra) -> list[str]:
    return ["collect", "--num", str(num), "--seed", str(SEED), "--out", str(out), *extra]


def arrays(dataset: Path) -> dict[int, dict[str, np.ndarray]]:
    """Per episode seed: every array of its trajectory (actions, env states, success...)."""
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


def assert_same_episodes(got: Path, expected: Path, seeds) -> None:
    a, b = arrays(got), arrays(expected)
    for seed in seeds:
        assert a[seed].keys() == b[seed].keys(), seed
        for name in a[seed]:
            assert np.array_equal(a[seed][name], b[seed][name]), f"seed {seed}: {name}"


@pytest.fixture(scope="module")
def one_worker(tmp_path_factory):
    """The reference: ``collect --workers 1`` of the default layout, seeds 700-703."""
    out = tmp_path_factory.mktemp("local")
    res = cli(collect_args(out, 4, "--workers", "1"), out)
    assert res.returncode == 0, res.stdout + res.stderr
    return out / "default"


def test_collect_on_two_nodes_equals_one_local_worker(cluster, one_worker, tmp_path):
    res = cli(collect_args(tmp_path, 4, "--ray", "auto"), tmp_path, cluster)
    assert res.returncode == 0, res.stdout + res.stderr
    got = tmp_path / "default"
    meta, ref = (json.loads((d / "trajectory.json").read_text()) for d in (got, one_worker))
    assert meta == ref, "the same trajectory.json: env_info, episodes, seeds, scene record"
    assert [e["episode_seed"] for e in meta["episodes"]] == [700, 701, 702, 703]
    assert meta["env_info"]["env_kwargs"]["layout_file"] == str(DEFAULT_LAYOUT)
    assert_same_episodes(got, one_worker, range(700, 704))
    summary, ref_summary = (json.loads((d / "summary.json").read_text()) for d in (got, one_worker))
    differs = {k for k in summary if summary[k] != ref_summary[k]}
    assert differs <= {"wall_time_s", "workers", "nodes"}, differs
    # which nodes run the four episodes is Ray's scheduling: on a loaded machine one node took
    # all four (a fresh-clone CI run); the episodes are the same either way (above)
    assert 1 <= summary["nodes"] <= 2 and summary["workers"] >= 1
    assert "Ray workers on" in res.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["default"], "no work folder left"


def running_tasks() -> list[int]:
    """Ray worker processes running a task of ours (Ray names them ``ray::_task``)."""
    found = []
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and (proc / "cmdline").read_bytes().startswith(b"ray::_task"):
                found.append(int(proc.name))
        except OSError:
            continue
    return found


def arrived(out: Path) -> list[Path]:
    return sorted((out / ".resume-default").glob("seed_*"))


def wait_for(condition, seconds: float = 600) -> None:
    deadline = time.time() + seconds
    while not condition():
        assert time.time() < deadline, "timed out"
        time.sleep(0.2)


@pytest.mark.slow  # 2-4 minutes on the shared 2-core machine (CI runs it)
def test_a_worker_killed_mid_run_costs_a_retry_not_the_run(cluster, one_worker, tmp_path):
    proc = cli(collect_args(tmp_path, 8, "--ray", "auto"), tmp_path, cluster,
               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)  # fmt: skip
    wait_for(lambda: len(arrived(tmp_path)) >= 1 and running_tasks())
    victim = running_tasks()[0]
    os.kill(victim, signal.SIGKILL)  # mid-episode: workers run their next seed at once
    output, _ = proc.communicate(timeout=900)
    assert proc.returncode == 0, output
    meta = json.loads((tmp_path / "default" / "trajectory.json").read_text())
    assert [e["episode_seed"] for e in meta["episodes"]] == list(range(700, 708)), "each once"
    assert_same_episodes(tmp_path / "default", one_worker, range(700, 704))


@pytest.mark.slow  # 2-4 minutes on the shared 2-core machine (CI runs it)
def test_an_interrupted_driver_resumes_with_the_same_out(cluster, one_worker, tmp_path):
    args = collect_args(tmp_path, 4, "--ray", "auto")
    proc = cli(args, tmp_path, cluster, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wait_for(lambda: len(arrived(tmp_path)) >= 2)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    kept = arrived(tmp_path)[0]  # marked: the next run keeps it rather than running it again
    record = json.loads((kept / "episode.json").read_text())
    (kept / "episode.json").write_text(json.dumps(dict(record, instruction="first run's")))
    res = cli(args, tmp_path, cluster)
    assert res.returncode == 0, res.stdout + res.stderr
    meta = json.loads((tmp_path / "default" / "trajectory.json").read_text())
    assert [e["episode_seed"] for e in meta["episodes"]] == [700, 701, 702, 703]
    marked = [e["episode_seed"] for e in meta["episodes"] if e["instruction"] == "first run's"]
    assert marked == [record["seed"]], "what the first run received is kept"
    assert_same_episodes(tmp_path / "default", one_worker, range(700, 704))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["default"], "the store is removed"


def test_eval_on_ray_writes_the_local_summary(cluster, tmp_path):
    args = ["eval", "--policy", "zero", "--episodes", "4", "--max-episode-steps", "20"]
    local = cli([*args, "--out", str(tmp_path / "local")], tmp_path)
    res = cli([*args, "--ray", "auto", "--out", str(tmp_path / "ray")], tmp_path, cluster)
    assert local.returncode == 0 and res.returncode == 0, res.stdout + res.stderr
    a, b = (json.loads((tmp_path / d / "episodes.json").read_text()) for d in ("ray", "local"))
    assert a == b and [e["seed"] for e in a] == [0, 1, 2, 3]
    summary, ref = (json.loads((tmp_path / d / "summary.json").read_text())
                    for d in ("ray", "local"))  # fmt: skip
    assert {k for k in summary if summary[k] != ref[k]} <= {"workers", "nodes"}
    assert summary["episodes"] == 4 and summary["nodes"] == 2


POLICY = '''
def make(env):
    def act(obs):
        raise ValueError("weights not loaded")
    return act
'''


def test_a_policy_raising_on_a_worker_is_the_local_one_line_error(cluster, tmp_path):
    (tmp_path / "bad.py").write_text(POLICY)
    args = ["eval", "--policy", "bad.py:make", "--episodes", "1", "--max-episode-steps", "5"]
    local = cli([*args, "--out", "local"], tmp_path)
    res = cli([*args, "--ray", "auto", "--out", "ray"], tmp_path, cluster)
    assert local.returncode == res.returncode == 1
    line = [ln for ln in local.stdout.splitlines() if ln.startswith("error:")]
    assert line == [
        "error: --policy bad.py:make: the policy raised ValueError: weights not loaded at step "
        "0 of episode seed 0 (default.json)"
    ]
    assert [ln for ln in res.stdout.splitlines() if ln.startswith("error:")] == line


# the driver checks this layout and passes it; its objects cannot be placed this far from the
# robot, which only the env's construction on a worker finds (the bad-input corpus's case)
FAR_REACH = {"placement_limits": {"reach_min": 1.7, "reach_max": 1.95}}


def test_a_layout_error_on_a_worker_is_the_local_one_line_error(cluster, tmp_path):
    layout = ROOT / "tests" / "data" / "bad_inputs" / "objects_cannot_be_placed" / "layout.json"
    (tmp_path / "far.json").write_text(json.dumps(FAR_REACH))
    args = ["collect", "--layout", str(layout), "--config", "far.json", "--num", "1"]
    local = cli([*args, "--workers", "1", "--out", "local"], tmp_path)
    res = cli([*args, "--ray", "auto", "--out", "ray"], tmp_path, cluster)
    assert local.returncode == res.returncode == 1, res.stdout + res.stderr
    line = [ln for ln in local.stdout.splitlines() if ln.startswith("error:")]
    assert len(line) == 1 and line[0].startswith(
        f"error: collecting layout.json failed: PlacementError: {layout}: cannot place \"can\""
    ), line
    assert [ln for ln in res.stdout.splitlines() if ln.startswith("error:")] == line
    # no dataset, and no resume store: no episode arrived (the same code path on either)
    assert list((tmp_path / "local").iterdir()) == list((tmp_path / "ray").iterdir()) == []


def test_paths_map_whole_folder_names_both_ways():
    from embodied_envs.cluster import Paths
    from embodied_envs.pipelines.episodes import Episode

    paths = Paths((("/data/scene", "/tmp/n/0"), ("/data/scene/policies", "/tmp/n/1")))
    episode = Episode("/data/scene/layouts/a.json", 3, True, False, 10, 1.0,
                      plan_failures=["/data/scenery/x: /data/scene/policies/p.py"])  # fmt: skip
    node = paths.to_node(episode)
    assert node.layout == "/tmp/n/0/layouts/a.json" and node.seed == 3
    assert node.plan_failures == ["/data/scenery/x: /tmp/n/1/p.py"], "whole names, longest first"
    assert paths.to_driver(node) == episode
    assert paths.to_node({"/data/scene": ("/data/scene",)}) == {"/tmp/n/0": ("/tmp/n/0",)}


WARMED = "xml.dom.minidom"  # a module no task of this test imports itself


def test_a_local_rays_workers_import_the_episodes_module_while_the_driver_starts():
    """``start_early``'s warm-up: the worker that then runs the episode has the module
    imported before the task arrives (the same process, kept by Ray)."""
    from embodied_envs.cluster import ray_session, start_early

    def _imported(name: str = WARMED) -> tuple[bool, int]:  # travels by value to the worker
        import os
        import sys

        return name in sys.modules, os.getpid()

    start_early(None, 1, warm=(WARMED,))
    with ray_session(None, 1):
        remote = ray.remote(num_cpus=1)(_imported)
        results = ray.get([remote.remote() for _ in range(3)])
    assert [warm for warm, _ in results] == [True] * 3
    assert len({pid for _, pid in results}) == 1, "one worker process, reused"


@pytest.mark.parametrize("cpus, workers, expected", [(2, 2, 4), (2, 0, 4), (1, 1, 2), (16, 2, 2)])
def test_tasks_queue_ahead_only_where_the_cluster_would_not_run_them(monkeypatch, cpus, workers,
                                                                     expected):  # fmt: skip
    """Two tasks per worker where they queue (a worker starts its next at once); on a larger
    cluster ``--workers`` caps the episodes running, so none ahead."""
    from types import SimpleNamespace

    from embodied_envs.pipelines import on_ray

    monkeypatch.setattr(on_ray, "cluster_cpus", lambda: cpus)
    assert on_ray.in_flight(SimpleNamespace(workers=workers)) == expected


@pytest.mark.parametrize("how", ["--ray", "RAY_ADDRESS"])
def test_a_dead_address_is_one_line_within_30_s(tmp_path, how):
    dead = "127.0.0.1:1"  # nothing listens on port 1
    args = collect_args(tmp_path, 1, "--ray", *([dead] if how == "--ray" else []))
    env = dict(os.environ, MS_SKIP_ASSET_DOWNLOAD_PROMPT="1")
    env.pop("RAY_ADDRESS", None)
    if how == "RAY_ADDRESS":
        env["RAY_ADDRESS"] = dead
    t0 = time.monotonic()
    res = subprocess.run(CLI + args, cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=60)  # fmt: skip
    assert time.monotonic() - t0 < 30
    assert res.returncode == 1
    named = f"--ray {dead}" if how == "--ray" else f"--ray (RAY_ADDRESS={dead})"
    assert res.stderr.startswith(f"error: {named}: no Ray cluster reachable at {dead}")
    assert res.stderr.count("\n") == 1, res.stderr



@pytest.mark.parametrize("address", ["myhost", "localhost:notaport", ":6379"])
def test_an_address_that_is_not_host_port_is_one_line_before_ray_starts(monkeypatch, address):
    """Not Ray's ValueError traceback, seconds later."""
    from embodied_envs.cluster import ClusterError
    from embodied_envs.pipelines.on_ray import check_address

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    with pytest.raises(ClusterError) as e:
        check_address(address)
    assert str(e.value) == (
        f"--ray {address}: {address!r} is not a Ray cluster's address (host:port, "
        "ray://host:port or auto). Fix: give its head's address, e.g. --ray 10.0.0.1:6379"
    )
    monkeypatch.setenv("RAY_ADDRESS", address)
    with pytest.raises(ClusterError, match=rf"^--ray auto \(RAY_ADDRESS={address}\): '"):
        check_address("auto")

EXITING = """
import os
import sys
def make(env):
    def act(obs):
        {call}
    return act
"""


@pytest.mark.parametrize("call, did", [
    ('sys.exit("no weights here")', "raised SystemExit: no weights here"),
    ("os._exit(3)", "called os._exit(3)"),
])  # fmt: skip
def test_a_policy_ending_its_process_on_a_worker_is_its_one_line_error(cluster, tmp_path, call,
                                                                       did):  # fmt: skip
    """Not a worker lost and retried: the policy's call, as the local run names it (os._exit
    would end the worker process: it raises in the policy's code, policies.policy_code)."""
    (tmp_path / "quits.py").write_text(EXITING.format(call=call))
    args = ["eval", "--policy", "quits.py:make", "--episodes", "1", "--max-episode-steps", "5"]
    local = cli([*args, "--out", "local"], tmp_path)
    res = cli([*args, "--ray", "auto", "--out", "ray"], tmp_path, cluster)
    assert local.returncode == res.returncode == 1, res.stdout + res.stderr
    line = [ln for ln in local.stdout.splitlines() if ln.startswith("error:")]
    assert line == [
        f"error: --policy quits.py:make: the policy {did} at step 0 of episode seed 0 "
        "(default.json)"
    ]
    assert [ln for ln in res.stdout.splitlines() if ln.startswith("error:")] == line
    assert "lost" not in res.stdout + res.stderr


def test_a_tasks_sys_exit_comes_back_as_itself_not_as_a_lost_worker():
    """Ray would end the worker process of a task raising SystemExit and run it again; the
    task carries it back (``cluster.TaskExit``) and the driver raises it as a local run does.
    Ray's own (``ray_terminate_msg``: the worker told to stop) goes on."""
    from types import SimpleNamespace

    from embodied_envs.cluster import Paths, TaskExit, _task

    bundle = SimpleNamespace(unpacked=lambda: Paths(()))
    with pytest.raises(TaskExit) as carried:
        _task(sys.exit, bundle, ("no weights here",))
    exit_ = carried.value.rebuilt()
    assert type(exit_) is SystemExit and exit_.code == "no weights here"

    def stopped():
        e = SystemExit(1)
        e.ray_terminate_msg = "The process receives a SIGTERM."
        raise e

    with pytest.raises(SystemExit):
        _task(stopped, bundle, ())


TOKEN = "a" * 64  # the token cluster's: Ray's are 64 hex digits
TOKEN_CLUSTER = """
import sys
from ray.cluster_utils import Cluster
c = Cluster(initialize_head=True, head_node_args=dict(num_cpus=1, include_dashboard=False,
            object_store_memory=128 * 2**20))
print(c.address, flush=True)
sys.stdin.read()  # up until the test closes it (or ends)
c.shutdown()
"""


@pytest.fixture(scope="module")
def token_cluster():
    """A Ray of one node that wants a token (``RAY_AUTH_MODE=token``), in a process of its own:
    this one's Ray settings stay as they are."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("RAY_AUTH", "RAY_ADDRESS"))}
    env.update(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=TOKEN)
    proc = subprocess.Popen([sys.executable, "-c", TOKEN_CLUSTER], env=env, text=True,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE)  # fmt: skip
    address = proc.stdout.readline().strip()
    assert address, "the token cluster did not start"
    yield address
    proc.stdin.close()
    proc.wait(timeout=120)


TOKEN_FIX = (
    "Fix: give this machine the cluster's token (`ray get-auth-token` on its head) in "
    "RAY_AUTH_TOKEN or ~/.ray/auth_token, with RAY_AUTH_MODE=token"
)
REFUSED = "Ray: Authentication token is missing or incorrect"  # Ray 2.60's words


@pytest.mark.parametrize("sent", ["a wrong token", "no token", "no token here"])
def test_a_cluster_refusing_the_token_is_one_line_saying_so(token_cluster, tmp_path, sent):
    """The cluster is up: not "no running Ray cluster there"."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("RAY_AUTH", "RAY_ADDRESS"))}
    env.update(MS_SKIP_ASSET_DOWNLOAD_PROMPT="1", OMP_NUM_THREADS="1")
    env["RAY_gcs_server_port_wait_time_s"] = "2"  # Ray's tries at connecting (20 s: 20 tries)
    if sent == "a wrong token":
        env.update(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN="b" * 64)
    elif sent == "no token here":
        env.update(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN_PATH=str(tmp_path / "no_token"))
    t0 = time.monotonic()
    res = subprocess.run(CLI + collect_args(tmp_path, 1, "--ray", token_cluster), cwd=tmp_path,
                         env=env, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert time.monotonic() - t0 < 30
    assert res.returncode == 1, res.stdout + res.stderr
    where = f"error: --ray {token_cluster}:"
    line = {
        "a wrong token": f"{where} the Ray cluster there refused this machine's authentication "
        f"token (from RAY_AUTH_TOKEN; {REFUSED}). {TOKEN_FIX}",
        "no token": f"{where} the Ray cluster there requires an authentication token and this "
        f"machine sent none (RAY_AUTH_MODE is not token here; {REFUSED}). {TOKEN_FIX}",
        "no token here": f"{where} this machine has no authentication token to send "
        "(RAY_AUTH_MODE=token; Ray: RAY_AUTH_TOKEN_PATH is set but file cannot be opened or is "
        f"empty: {tmp_path / 'no_token'}). {TOKEN_FIX}",
    }[sent]
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert errors == [line], res.stderr
    assert res.stderr.endswith(line + "\n") and "Traceback" not in res.stderr
