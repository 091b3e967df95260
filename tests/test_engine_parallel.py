"""The evaluation helper process (streamid.engine.search.parallel): exact, never stalls, cleans up.

A real helper process is started (``python -m streamid.engine.search._evalhelper``) and
shares memory with the test; nothing is mocked.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from streamid.engine import CoEAConfig, Coevolution, EvalHelper, identify
from streamid.engine.settings import RIDGE
from benchmarks.engine_cases import reactor_data
from streamid.engine.search.batch import BatchEvaluator
from streamid.errors import StreamidError

pytestmark = pytest.mark.skipif(not EvalHelper.supported(), reason="the helper needs POSIX on x86-64")

CFG = CoEAConfig(neurons=10, generations=40, max_lag_y=4, max_lag_u=4)


@pytest.fixture(scope="module")
def helper():
    with EvalHelper() as h:
        yield h


@pytest.fixture(scope="module")
def data():
    ue, ye, _, _ = reactor_data(3, 300, 10)
    return ue, ye


def _same_run(a: Coevolution, b: Coevolution) -> None:
    assert a.history == b.history
    for name in ("X", "H", "fx", "fh", "best_x", "best_h"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.best_f == b.best_f and a.evaluations == b.evaluations


def _bound(run: Coevolution, timeout_s: float = 10.0) -> Coevolution:
    """``run`` once the helper has taken its data (the helper runs at idle priority: on a busy machine that
    can take longer than a short run lasts, and the run then never offers it a batch)."""
    deadline = time.monotonic() + timeout_s
    while not run._batch._usable() and time.monotonic() < deadline:
        time.sleep(0.001)
    return run


def test_a_run_with_the_helper_is_bitwise_the_run_without(helper, data):
    ue, ye = data
    before = helper.stats.offloaded + helper.stats.missed
    for seed in (0, 1):
        alone = Coevolution(ue, ye, CFG, np.random.default_rng(seed)).solve()
        both = _bound(Coevolution(ue, ye, CFG, np.random.default_rng(seed), helper=helper)).solve()
        _same_run(alone, both)
    assert helper.stats.offloaded + helper.stats.missed > before  # batches were offered to the helper


def test_the_faster_path_is_chosen_by_measuring(helper, data):
    ue, ye = data
    decided = helper.stats.chose_split + helper.stats.chose_local
    run = _bound(Coevolution(ue, ye, CFG, np.random.default_rng(3), helper=helper))
    run._batch.MAX_BACKOFF = 0  # a busy machine's misses must not skip the trial's batches in so short a run
    run.solve()
    assert run._batch.mode in ("split", "alone")  # 40 generations: the trial (6 + 6 batches) ended in a choice
    assert helper.stats.chose_split + helper.stats.chose_local == decided + 1
    # A helper that cannot answer (stopped) makes the split path slower: the caller then keeps evaluating alone.
    alone = Coevolution(ue, ye, CFG, np.random.default_rng(4)).solve()
    run = _bound(Coevolution(ue, ye, CFG, np.random.default_rng(4), helper=helper))
    os.kill(helper.pid, signal.SIGSTOP)
    try:
        run._batch.MAX_BACKOFF = 0  # every batch that is not skipped for a miss counts in the trial
        run.solve()
    finally:
        os.kill(helper.pid, signal.SIGCONT)
    _same_run(alone, run)
    assert run._batch.mode == "alone"


def test_the_helper_computes_exactly_what_the_local_evaluator_computes(helper, data):
    ue, ye = data
    run = Coevolution(ue, ye, CFG, np.random.default_rng(5), helper=helper)
    local = BatchEvaluator(run.R, run.target, CFG.neurons, CFG.population, RIDGE)
    binding = run._batch
    rng = np.random.default_rng(9)
    c, w = run._split(run.X[:10])
    per_member = rng.random((10, run.D)) < 0.4
    per_member[:, 0] = True
    for masks, shared in ((per_member, False), (np.broadcast_to(run.H[0], (10, run.D)), True)):
        got = binding.remote(masks, c, w, shared=shared, timeout_s=30.0)
        want = local.evaluate(masks, c, w, shared=shared)
        np.testing.assert_array_equal(got, want)
    with pytest.raises(Exception, match="1 to 10 members"):
        binding.remote(run.H, *run._split(run.X))


def test_a_stopped_helper_costs_nothing_but_time(helper, data):
    ue, ye = data
    alone = Coevolution(ue, ye, CFG, np.random.default_rng(2)).solve()
    run = Coevolution(ue, ye, CFG, np.random.default_rng(2), helper=helper)
    c, w = run._split(run.X[:2])
    run._batch.remote(run.H[:2], c, w, timeout_s=30.0)  # the helper holds this run's data
    missed = helper.stats.missed
    os.kill(helper.pid, signal.SIGSTOP)
    try:
        run.solve()
    finally:
        os.kill(helper.pid, signal.SIGCONT)
    _same_run(alone, run)
    assert helper.stats.missed > missed  # it was offered batches, missed them, the caller did them


def test_identify_with_a_helper_gives_the_same_model(helper, data):
    ue, ye = data
    a = identify(ue, ye, CFG, 4)
    b = identify(ue, ye, CFG, 4, helper=helper)
    assert a.model.to_json() == b.model.to_json()


def test_the_defaults_with_a_helper_give_the_same_model(helper, data):
    """With a helper the candidates' fits, free runs and the refinement also use threads: the same model."""
    from streamid.engine import DEFAULT

    ue, ye = data
    cfg = DEFAULT.replace(generations=15, max_lag_cap=0, max_lag_y=4, max_lag_u=4)
    a = identify(ue, ye, cfg, 2)
    b = identify(ue, ye, cfg, 2, helper=helper)
    assert a.model.to_json() == b.model.to_json() and a.model.metrics["refinement"] == b.model.metrics["refinement"]


def test_free_runs_in_threads_are_the_same_to_the_bit():
    from streamid.threads import thread_map
    from streamid.model.freerun import free_run
    from streamid.model.regressors import Regressor

    rng = np.random.default_rng(0)
    regs = (Regressor("y", 0, 1), Regressor("y", 0, 2), Regressor("u", 0, 1), Regressor("u", 1, 2))
    C, M = 5, 6
    args = (regs, rng.uniform(-1, 1, (C, M, 4)), rng.uniform(0.5, 1.5, (C, M)), rng.normal(0, 0.3, (C, M)),
            rng.uniform(-1, 1, (200, 2)), rng.uniform(-1, 1, (C, 2)), rng.normal(0, 0.1, (C, 5)))
    one = free_run(*args)
    for threads in (2, 3, 8):
        assert np.array_equal(free_run(*args, threads=threads), one)
    assert thread_map(lambda x: x * x, list(range(7)), 3) == [x * x for x in range(7)]  # in the items' order


def test_close_ends_the_process_and_removes_its_files():
    h = EvalHelper()
    ue, ye, _, _ = reactor_data(1, 200, 10)
    Coevolution(ue, ye, CFG.replace(generations=5), 0, helper=h).solve()
    folder = os.path.dirname(h._ctl_path)
    assert os.path.isdir(folder)
    h.close()
    assert h._proc.poll() is not None
    assert not os.path.exists(folder)
    with pytest.raises(StreamidError, match="closed"):
        h.bind(np.zeros((30, 2)), np.zeros(30), 2, 20, 1e-10, BatchEvaluator(np.zeros((30, 2)), np.zeros(30), 2, 20))
    h.close()  # twice is fine


def test_ctrl_c_in_the_terminal_leaves_the_helper_to_its_owner():
    """SIGINT reaches every process of a terminal's group: the helper keeps working, says nothing, and ends on close."""
    h = EvalHelper()
    try:
        os.kill(h.pid, signal.SIGINT)
        time.sleep(0.5)
        assert h._proc.poll() is None
        ue, ye, _, _ = reactor_data(1, 200, 10)
        co = Coevolution(ue, ye, CFG.replace(generations=5), 0, helper=h).solve()
        assert np.isfinite(co.best_f)
    finally:
        h.close()
    assert h._proc.poll() is not None


def test_the_helper_goes_away_with_a_killed_owner():
    code = (
        "import os, sys\n"
        "from streamid.engine import EvalHelper\n"
        "h = EvalHelper()\n"
        "folder = os.path.dirname(h._ctl_path)\n"
        "open(os.path.join(folder, 'data-99'), 'wb').close()  # as a bind() cut short: its path never written\n"
        "print(h.pid, folder, flush=True)\n"
        "sys.stdin.read()\n"
    )
    owner = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        pid_s, folder = owner.stdout.readline().split()
        pid = int(pid_s)
        assert os.path.isdir(folder)
        owner.kill()
        owner.wait(timeout=10)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and (_alive(pid) or os.path.exists(folder)):
            time.sleep(0.05)
        assert not _alive(pid), "the helper outlived its owner"
        assert not os.path.exists(folder), "the helper left its shared files behind"
    finally:
        if owner.poll() is None:
            owner.kill()


def test_the_helper_goes_away_with_an_owner_killed_while_it_starts():
    """The owner gone before the helper has even imported: it must not take init for its owner (a helper left this
    way spun on its pipe's end-of-file for 38 minutes: a daemon killed during its start, 2026-11-26)."""
    code = (
        "import os\n"
        "from streamid.engine import EvalHelper\n"
        "h = EvalHelper(wait=False)\n"
        "print(h.pid, os.path.dirname(h._ctl_path), flush=True)\n"
        "os._exit(0)  # no close(): as a SIGKILL\n"
    )
    owner = subprocess.run([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, timeout=60, check=True)
    pid_s, folder = owner.stdout.split()
    pid = int(pid_s)
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and (_alive(pid) or os.path.exists(folder)):
        time.sleep(0.05)
    assert not _alive(pid), "the helper outlived its owner"
    assert not os.path.exists(folder), "the helper left its shared files behind"


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_uniforms_drawn_ahead_by_the_helper_are_the_generators_next_numbers(helper, data):
    ue, ye = data
    run = Coevolution(ue, ye, CFG, np.random.default_rng(6), helper=helper)
    binding = run._batch
    c, w = run._split(run.X[:2])
    binding.remote(run.H[:2], c, w, timeout_s=30.0)  # bound
    rng = np.random.default_rng(123)
    twin = np.random.default_rng(123)
    for count in (5000, 20000):
        binding.request_uniforms(rng, count)
        deadline = time.monotonic() + 30
        got = None
        while got is None and time.monotonic() < deadline:
            time.sleep(0.002)
            d = binding._draw
            got = binding.take_uniforms(rng, count)
            if got is None:
                binding._draw = d  # not ready yet: keep the request
        assert got is not None, "the helper did not draw ahead within 30 s"
        np.testing.assert_array_equal(got, twin.random(count))
        assert rng.random() == twin.random()  # and the generator went on exactly past them
    # Someone drew from the generator after the request: the block is refused, nothing is skipped.
    binding.request_uniforms(rng, 1000)
    time.sleep(0.2)
    rng.random()
    twin.random()
    assert binding.take_uniforms(rng, 1000) is None
    assert rng.random() == twin.random()
    # Only PCG64 (numpy's default) is drawn ahead.
    other = np.random.Generator(np.random.Philox(1))
    binding.request_uniforms(other, 100)
    assert binding._draw is None
