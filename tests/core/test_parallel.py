"""The task engine (tendonkit.parallel): same values whatever the engine, failures contained."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tendonkit.errors import OptionError, SimulationError
from tendonkit.manager import identifiers
from tendonkit.parallel import engine_name, map_tasks, pow_task, run_tasks


def fails_on_three(shared: int, payload: int) -> int:
    if payload == 3:
        raise ValueError("three is refused")
    return payload + shared


def dies_once(shared: str, payload: int) -> int:
    """Kills its own worker process the first time it meets payload 2 (a crash in native code)."""
    marker = Path(shared) / f"died-{payload}"
    if payload == 2 and not marker.exists():
        marker.touch()
        os._exit(9)
    return payload * 10


def always_dies(shared: None, payload: int) -> int:
    if payload == 1:
        os._exit(9)
    return payload


def test_serial_and_process_pool_give_the_same_values():
    serial = map_tasks(pow_task, list(range(7)), shared=20, jobs=1)
    pool = map_tasks(pow_task, list(range(7)), shared=20, jobs=2)
    assert serial == pool == [k**3 for k in range(7)]
    assert engine_name(1, None) == "serial" and engine_name(2, None) == "processes"
    assert engine_name(2, "local") == "dask"


def test_an_exception_is_the_tasks_outcome_and_the_others_go_on():
    outs = sorted(
        run_tasks(fails_on_three, list(range(5)), shared=100, jobs=2), key=lambda o: o.index
    )
    assert [o.value for o in outs] == [100, 101, 102, None, 104]
    assert outs[3].error == "ValueError: three is refused"
    assert all(o.attempts == 1 for o in outs)
    with pytest.raises(SimulationError, match="Task 3 of 5 failed: ValueError: three is refused"):
        map_tasks(fails_on_three, list(range(5)), shared=100, jobs=1)


def test_a_dead_worker_loses_only_its_task_which_is_retried(tmp_path):
    outs = sorted(
        run_tasks(dies_once, list(range(6)), shared=str(tmp_path), jobs=2), key=lambda o: o.index
    )
    assert [o.value for o in outs] == [0, 10, 20, 30, 40, 50]
    assert [o.attempts for o in outs] == [1, 1, 2, 1, 1, 1]
    # the dead worker was replaced: three processes ran tasks, a fresh one ran the retry
    assert len({o.worker for o in outs}) == 3
    assert outs[2].worker not in {o.worker for o in outs[:2]}


def test_a_task_whose_workers_keep_dying_is_given_up_after_its_retries():
    outs = sorted(run_tasks(always_dies, [0, 1, 2], jobs=2, retries=1), key=lambda o: o.index)
    assert [o.value for o in outs] == [0, None, 2]
    assert outs[1].attempts == 2 and outs[1].error.startswith("WorkerDied")


def sleeps_on_one(shared: None, payload: int) -> int:
    if payload == 1:
        import time

        time.sleep(60)
    return payload


def test_a_task_that_hangs_is_stopped_at_its_timeout_and_the_others_finish():
    outs = sorted(run_tasks(sleeps_on_one, [0, 1, 2], jobs=2, timeout=3.0), key=lambda o: o.index)
    assert [o.value for o in outs] == [0, None, 2]
    assert outs[1].error.startswith("Timeout: the task ran longer than 3 s")


def _slow_to_load() -> SlowToLoad:
    import time

    time.sleep(4.0)  # a worker's start-up on a loaded machine: imports, the shared data
    return SlowToLoad()


class SlowToLoad:
    """Shared data whose unpickling in each fresh worker takes 4 s."""

    def __reduce__(self) -> tuple:
        return (_slow_to_load, ())


def test_a_workers_start_up_does_not_count_against_its_tasks_timeout():
    # the timeout is the task's: a worker that takes 4 s to start still runs 0 and 2 within 3 s
    # (before, the clock started when the task was queued, and every task timed out)
    outs = sorted(
        run_tasks(sleeps_on_one, [0, 1, 2], shared=SlowToLoad(), jobs=2, timeout=3.0),
        key=lambda o: o.index,
    )
    assert [o.value for o in outs] == [0, None, 2]
    assert outs[1].error.startswith("Timeout: the task ran longer than 3 s")


def test_a_worker_that_does_not_start_in_time_is_replaced_not_timed_out(monkeypatch):
    import tendonkit.parallel as parallel

    # the start-up allowance is the master's: 1 s against a 4 s start-up, no retry left (two
    # jobs: one job runs the tasks in this process)
    monkeypatch.setattr(parallel, "STARTUP_ALLOWANCE_S", 1.0)
    outs = list(
        run_tasks(sleeps_on_one, [0, 2], shared=SlowToLoad(), jobs=2, timeout=30.0, retries=0)
    )
    assert [o.value for o in outs] == [None, None]
    assert all(o.error.startswith("WorkerDied") for o in outs), [o.error for o in outs]


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"jobs": 0}, "jobs must be a whole number >= 1"),
        ({"retries": -1}, "retries must be a whole number >= 0"),
        ({"scheduler": " "}, "scheduler must be 'local' or an address"),
        ({"scheduler": "lcoal"}, "neither 'local' nor an address such as tcp://host:8786"),
    ],
)
def test_bad_options_are_reported(kwargs, needle):
    with pytest.raises(OptionError, match=needle):
        list(run_tasks(pow_task, [1], **kwargs))


def test_the_sweeps_inside_tendonkit_give_the_same_model_on_workers(small_data):
    """ARX's automatic structure and SINDYc's threshold sweep: jobs=2 gives the jobs=1 model."""
    _, data, _ = small_data
    reg = identifiers()
    for method, opts in (("arx", {"na": "auto", "nb": "auto", "max_order": 4}), ("sindyc", {})):
        one = reg.get(method).create(**opts, jobs=1).identify(data)
        two = reg.get(method).create(**opts, jobs=2).identify(data)
        assert one.to_dict()["representation"] == two.to_dict()["representation"], method
    with pytest.raises(OptionError, match="jobs must be an integer >= 1"):
        reg.get("arx").create(jobs=0)
