"""The commands' process runner: order, progress, failures and dead workers."""

import os
import signal
import time

import pytest

from embodied_envs.workers import WorkerError, report, run


def square(x):
    report(("start", x))
    return x * x


def fail_on(x, bad):
    if x == bad:
        raise ValueError(f"task {x} is bad")
    time.sleep(0.2)
    return x


def die_on(x, bad):
    if x == bad:
        os.kill(os.getpid(), signal.SIGKILL)  # as the OOM killer does
    time.sleep(0.2)
    return x


@pytest.mark.parametrize("workers", [1, 2])
def test_results_in_task_order_with_progress(workers):
    got, progress = [], []
    out = run(square, [(k,) for k in range(7)], workers, on_result=got.append,
              on_progress=progress.append)  # fmt: skip
    assert out == [k * k for k in range(7)]
    assert sorted(got) == sorted(out)
    assert sorted(progress) == [("start", k) for k in range(7)]


def test_a_failing_task_stops_the_run_with_its_own_error():
    t = time.perf_counter()
    with pytest.raises(ValueError, match="task 3 is bad"):
        run(fail_on, [(k, 3) for k in range(40)], 2)
    assert time.perf_counter() - t < 8, "the others are stopped, not waited for"


def test_a_killed_worker_is_noticed_within_seconds():
    t = time.perf_counter()
    with pytest.raises(WorkerError, match="worker process died"):
        run(die_on, [(k, 2) for k in range(6)], 2)
    assert time.perf_counter() - t < 8


def test_in_process_tasks_raise_directly():
    with pytest.raises(ValueError, match="task 0 is bad"):
        run(fail_on, [(0, 0)], 1)


def test_start_up_runs_without_the_collector_until_started():
    """A command's start-up runs with the garbage collector off; ``started()`` sets aside
    what is alive then (frozen out of every later collection) and turns it on again, once.
    Without ``start_up()`` (library use, worker processes) ``started()`` changes nothing."""
    import gc

    from embodied_envs.workers import start_up, started

    gc.unfreeze()  # what earlier commands run in this process set aside
    frozen = gc.get_freeze_count()
    try:
        started()  # no start-up: nothing happens
        assert gc.isenabled() and gc.get_freeze_count() == frozen == 0
        start_up()
        assert not gc.isenabled()
        alive = [object() for _ in range(1000)]
        held = [[k] for k in range(1000)]  # tracked by the collector (containers)
        gc.collect()  # forced during the start-up (ManiSkill's, building a scene)
        assert gc.get_freeze_count() >= frozen + len(held), "set aside, not walked"
        started()
        assert not any(f.__module__ == "embodied_envs.workers" for f in gc.callbacks)
        assert gc.isenabled() and gc.get_freeze_count() >= frozen + len(alive)
        count = gc.get_freeze_count()
        started()  # once only: nothing more set aside (what was, may be freed meanwhile)
        assert gc.isenabled() and gc.get_freeze_count() <= count
    finally:
        gc.enable()
        gc.unfreeze()


def test_the_cli_turns_the_collector_off_only_for_commands_that_build_envs(monkeypatch):
    """``collect``, ``demo`` and ``eval`` start up without the collector (their tasks call
    ``started()``); the other commands never turn it off; after any command, failed ones
    included, it is on."""
    import gc

    from embodied_envs import workers
    from embodied_envs.cli import main as cli

    parser = cli.build_parser()
    for argv, builds in (
        (["collect"], True),
        (["demo"], True),
        (["eval", "--policy", "zero"], True),
        (["layout", "validate", "x.json"], False),
        (
            [
                "splat",
                "render",
                "x.ply",
                "--eye",
                "1",
                "0",
                "1",
                "--target",
                "0",
                "0",
                "0",
                "--out",
                "o.png",
            ],
            False,
        ),
    ):
        args, _ = parser.parse_known_args(argv)
        assert getattr(args, "builds_env", False) is builds, argv
    offs = []
    monkeypatch.setattr(cli, "start_up", lambda: offs.append(1) or workers.start_up())
    try:
        assert cli.main(["layout", "validate", "missing.json"]) == 1
        assert not offs and gc.isenabled()
        assert cli.main(["collect", "--layout", "missing.json", "--out", "/nonexistent/x"]) != 0
        assert offs and gc.isenabled()
    finally:
        gc.enable()
        gc.unfreeze()
