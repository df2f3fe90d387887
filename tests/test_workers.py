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
