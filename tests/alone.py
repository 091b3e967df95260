"""Tests that need the machine to themselves, when the suite runs in several processes (pytest-xdist).

The suite runs in two worker processes (``-n 2`` in ``pyproject.toml``): most of its time is real
sessions, processes and files waiting on each other, and about one core is used on average (measured:
565 s of CPU in 582 s of wall time without the load test).  Some tests measure time or bind fixed
things, and would measure the other worker instead:

* latencies, real-time replay timing or a load's backlog (``test_load``, the attack plans of
  ``test_daemon_bounds``, ``test_reliability_*``, ...);
* network namespaces of fixed names (the several-hosts tests; the README's recipe in namespaces, whose
  port is the printed 7447 inside them).

Those are marked ``alone`` (by module in :data:`ALONE_MODULES`, or ``@pytest.mark.alone``).  Around
each test (its setup, so a module's fixture too, its call and its teardown) a worker holds a lock on a
file shared by the run's workers: *shared* for any test, *exclusive* for one marked ``alone``, which
so runs with no other test beside it.  A turnstile file taken first keeps a waiting ``alone`` test
from being overtaken by the other worker's next tests (writer preference); :class:`Holder` keeps the
exclusive lock across consecutive ``alone`` tests (a module's).  In one process (``-n 0``,
``-p no:xdist``) there is nothing to lock.
"""

from __future__ import annotations

import fcntl
import os
import tempfile
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import pytest

#: test modules (file stems) whose every test runs alone (see the module docstring for why)
ALONE_MODULES = frozenset({
    "test_load",  # two minutes of nine streams into one daemon: the backlog and memory are measured
    "test_demo",  # the README's first command: the 20 kHz piezo in real time
    "test_daemon_bounds",  # timed attack plans: the healthy stream's latency per phase
    "test_daemon_faults",  # a timed fault plan
    "test_reliability_bad_input",  # a timed plan of every bad input at once
    "test_reliability_faults",  # kills and restarts at planned moments
    # test_record_replay: only its real-time 20 kHz replay timing test (marked there); its CLI and byte-exact
    # tests measure no time
    "test_rrd_files",  # a SIGKILLed writer loses at most 1 s
    # test_multihost: only its network-namespace tests (marked there: namespaces of fixed names); its loopback
    # recipe binds fresh ports and checks the sockets of its own processes, as test_readme's loopback recipe does
    "test_engine_parallel",  # the faster of two evaluation paths is chosen by timing them
    "test_daemon_helper",  # the helper runs under SCHED_IDLE: beside another test it gets no CPU, never offered work
})

#: the ``alone`` module run first: its 30 s warm-up (not measured) absorbs what a fresh install does first
#: (numba compiling the engine's loops into its cache), which would otherwise fall into another one's timed plan
FIRST_MODULE = "test_load"


def run_order(item: pytest.Item) -> int:
    """The group of ``item`` in the suite's order: 0 the first module, 1 the other ``alone`` modules, 2 the rest.

    With ``--dist loadfile`` (and ``--no-loadscope-reorder``) the workers get the modules in this order: the
    ``alone`` modules run one after the other while the other worker waits for them, then the shared modules on
    both workers.  Scattered among the shared modules, each ``alone`` module first waited, its worker idle, for
    the test running beside it to end.
    """
    stem = item.path.stem
    return 0 if stem == FIRST_MODULE else 1 if stem in ALONE_MODULES else 2


#: the environment variable naming the run's lock directory (set by the controller, inherited by the workers)
LOCK_DIR_ENV = "STREAMID_TEST_LOCK_DIR"


def is_alone(item: pytest.Item) -> bool:
    """Whether ``item`` must run with no other test beside it."""
    return item.get_closest_marker("alone") is not None or item.path.stem in ALONE_MODULES


@contextmanager
def machine(lock_dir: Path, *, alone: bool) -> Iterator[None]:
    """Hold the run's lock: exclusive if ``alone``, else shared (a readers-writer lock with a turnstile)."""
    with open(lock_dir / "turnstile", "a+b") as gate, open(lock_dir / "tests", "a+b") as tests:
        fcntl.flock(gate, fcntl.LOCK_EX)
        try:
            fcntl.flock(tests, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        finally:
            if not alone:
                fcntl.flock(gate, fcntl.LOCK_UN)
        try:
            yield
        finally:
            fcntl.flock(tests, fcntl.LOCK_UN)
            if alone:
                fcntl.flock(gate, fcntl.LOCK_UN)


class Holder:
    """A worker's hold on the run's lock, test by test, kept across a run of consecutive ``alone`` tests.

    Released between two ``alone`` tests, the lock would let the other worker slip one of its tests in, and
    the next ``alone`` test would wait for it: its time would be spent with one worker idle, once per
    ``alone`` test (111 of them).  With ``--dist loadfile`` a module's tests come to one worker in a row, so
    an ``alone`` module keeps the machine from its first test to its last.
    """

    def __init__(self, lock_dir: Path) -> None:
        self.lock_dir = lock_dir
        self._held: ExitStack | None = None

    def before(self, alone: bool) -> None:
        """Before a test: take the lock (exclusive if ``alone``) unless the run of ``alone`` tests holds it."""
        if self._held is None:
            held = ExitStack()
            held.enter_context(machine(self.lock_dir, alone=alone))
            self._held = held

    def after(self, alone: bool, next_alone: bool) -> None:
        """After a test: keep the lock if this test and the next both run alone, else give it back."""
        if not (alone and next_alone) and self._held is not None:
            self._held.close()
            self._held = None


def lock_dir_for_run(config: pytest.Config) -> Path | None:
    """In the controller of a run with workers: make the lock directory and name it to the workers."""
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return None
    path = Path(tempfile.mkdtemp(prefix="streamid-tests-lock-"))
    os.environ[LOCK_DIR_ENV] = str(path)
    return path


def worker_lock_dir(config: pytest.Config) -> Path | None:
    """In a worker: the run's lock directory (None in a run without workers)."""
    if not hasattr(config, "workerinput"):
        return None
    value = os.environ.get(LOCK_DIR_ENV)
    return Path(value) if value else None
