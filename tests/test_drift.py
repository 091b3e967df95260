"""Drift detection: the Page-Hinkley test against river's published example, the block monitor, and the
identifier's drift event on a simulated device whose gain changes at a known time."""

from __future__ import annotations

import random

import numpy as np
import pytest

from streamid import OnlineIdentifier, StreamConfig
from streamid.online.drift import DriftMonitor, DriftSettings, PageHinkley, block_errors
from streamid.sim.drift import drift_start_ns, simulate_drift


def test_page_hinkley_reproduces_rivers_documented_example() -> None:
    """river.drift.PageHinkley's docstring: two distributions, 'Change detected at index 1006, input value: 5'."""
    rng = random.Random(12345)
    data = rng.choices([0, 1], k=1000) + rng.choices(range(4, 8), k=1000)
    ph = PageHinkley()
    hits = [(i, v) for i, v in enumerate(data) if ph.update(v)]
    assert hits[0] == (1006, 5)


def test_page_hinkley_is_quiet_on_a_stationary_sequence_and_validates_its_settings() -> None:
    rng = np.random.default_rng(0)
    ph = DriftSettings().detector()
    assert not any(ph.update(float(x)) for x in rng.normal(0.0, 0.3, 20_000))
    with pytest.raises(ValueError, match="threshold must be a number > 0; got 0"):
        PageHinkley(threshold=0)


def test_one_outlying_block_alone_never_raises_a_drift_but_a_sustained_rise_does() -> None:
    s = DriftSettings()
    mon = DriftMonitor(s, 50)
    levels = [1.0] * 20 + [1e6] + [1.0] * 20  # a glitch: one block a million times worse
    assert all(mon.block(v, i) is None for i, v in enumerate(levels))
    hits = [mon.block(np.e ** 2, 100 + i) for i in range(10)]  # the error level x7.4 from block 100 on
    first = next(i for i, h in enumerate(hits) if h is not None)
    assert 2 <= first <= 4 and hits[first] == 40  # at least three blocks; it began after the last quiet block


def test_block_errors_are_those_of_short_free_runs() -> None:
    t, u, y = simulate_drift("piezo", 0.2, 0.1, 0.0, 3)  # no change: a plain record
    ident = OnlineIdentifier(StreamConfig(window_s=0.1, update_every_s=0.1), stream="p")
    ident.learn_many(t[:2001], u[:2001], y[:2001])
    ident.update_all()
    m = ident.model
    assert m is not None
    e = block_errors(m, u[2000:3000, None], y[2000:3000], 100)
    L = m.max_lag
    sim = m.simulate(u[2000 : 2000 + L + 100, None], y[2000 : 2000 + L])  # the first block by hand
    assert e.shape == ((1000 - L) // 100,) and e[0] == pytest.approx(np.mean((y[2000 + L : 2000 + L + 100] - sim[L:]) ** 2))


def test_a_gain_change_of_the_simulated_piezo_raises_a_drift_and_a_new_champion_follows() -> None:
    t, u, y = simulate_drift("piezo", 6.0, 3.0, 0.2, 0)
    change_ns = drift_start_ns("piezo", 3.0)
    # a window every 2 s: the champion is judged rarely, so the drift test (every 0.15 s block) must see it first
    ident = OnlineIdentifier(StreamConfig(window_s=0.5, update_every_s=2.0), stream="p")
    drifts, champions = [], []
    for k in range(0, t.size, 2000):  # 0.1 s batches, identified as they come
        ident.learn_many(t[k : k + 2000], u[k : k + 2000], y[k : k + 2000], inputs=["v"], outputs=["x"])
        drifts += [e for e in ident.drain_events() if e.kind == "drift"]
        champions += [up for up in ident.update_all() if up.accepted]
    assert drifts and all(e.t_ns is not None and e.t_ns >= change_ns for e in drifts)  # no false alarm before
    assert drifts[0].t_ns - change_ns <= 1_000_000_000  # type: ignore[operator]
    after = [up for up in champions if up.window.t_end_ns > drifts[0].t_ns]  # type: ignore[operator]
    assert after and after[0].window.t_end_ns - change_ns <= 5_000_000_000
    assert after[0].outcome.generations == 100 and after[0].window.t0_ns >= change_ns - 200_000_000  # escalated, cut
    st = ident.status()
    assert st["drifts"] == len(drifts) and st["models"]["x"]["drifts"] == len(drifts)
