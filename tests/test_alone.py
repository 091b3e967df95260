"""The lock that lets some tests run alone when the suite runs in several processes (tests/alone.py).

flock locks held through separate open files conflict even within one process, so threads stand in for
the workers here.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from alone import ALONE_MODULES, FIRST_MODULE, Holder, is_alone, machine, run_order

WAIT_S = 1.0  # for a thread to reach its flock call (ordering, not a measurement)


def _enter(lock_dir: Path, name: str, alone: bool, order: list[str], hold: threading.Event | None = None,
           entered: threading.Event | None = None) -> threading.Thread:
    def run() -> None:
        with machine(lock_dir, alone=alone):
            order.append(f"in {name}")
            if entered is not None:
                entered.set()
            if hold is not None:
                assert hold.wait(30)
            order.append(f"out {name}")

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def test_an_alone_test_waits_for_the_running_ones_and_keeps_the_next_ones_out(tmp_path: Path) -> None:
    order: list[str] = []
    release, a_in = threading.Event(), threading.Event()
    a = _enter(tmp_path, "a", False, order, release, a_in)
    assert a_in.wait(30)
    b = _enter(tmp_path, "b", True, order)  # alone: waits for a
    time.sleep(WAIT_S)
    c = _enter(tmp_path, "c", False, order)  # a shared one after it: waits behind b, not beside a
    time.sleep(WAIT_S)
    assert order == ["in a"]
    release.set()
    for t in (a, b, c):
        t.join(30)
    assert order == ["in a", "out a", "in b", "out b", "in c", "out c"]


def test_ordinary_tests_run_side_by_side(tmp_path: Path) -> None:
    order: list[str] = []
    release, a_in, b_in = threading.Event(), threading.Event(), threading.Event()
    a = _enter(tmp_path, "a", False, order, release, a_in)
    b = _enter(tmp_path, "b", False, order, release, b_in)
    assert a_in.wait(30) and b_in.wait(30)  # both inside at once
    release.set()
    a.join(30)
    b.join(30)
    assert sorted(order[:2]) == ["in a", "in b"]


def test_the_modules_named_alone_exist_and_a_marker_makes_a_test_alone(request: pytest.FixtureRequest) -> None:
    here = Path(__file__).parent
    assert all((here / f"{m}.py").is_file() for m in ALONE_MODULES), sorted(ALONE_MODULES)
    assert FIRST_MODULE in ALONE_MODULES and run_order(request.node) == 2  # this module: after the alone ones
    assert not is_alone(request.node)
    request.node.add_marker(pytest.mark.alone)
    assert is_alone(request.node)


def test_a_run_of_alone_tests_keeps_the_machine_until_its_last(tmp_path: Path) -> None:
    """Between two alone tests of a module the other worker's test waits; it goes in after the last one."""
    order: list[str] = []
    holder = Holder(tmp_path)
    holder.before(True)
    order.append("in first")
    holder.after(True, next_alone=True)  # the next test runs alone too: the lock is kept
    c = _enter(tmp_path, "c", False, order)
    time.sleep(WAIT_S)
    holder.before(True)
    order.append("in second")
    time.sleep(WAIT_S)
    holder.after(True, next_alone=False)
    c.join(30)
    assert order == ["in first", "in second", "in c", "out c"]
    holder.before(False)  # an ordinary test beside another ordinary one
    d = _enter(tmp_path, "d", False, order)
    d.join(30)
    holder.after(False, next_alone=True)
    assert order[-2:] == ["in d", "out d"]
