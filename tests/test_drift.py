"""Drift detection: the CUSUM against published average run lengths, the block monitor, the block levels, the
recalibration of a drifted champion, and the identifier's drift event on a simulated device whose gain changes at a
known time."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from streamid import OnlineIdentifier, StreamConfig
from streamid.model import Model
from streamid.model.regressors import Normalisation, Regressor
from streamid.online.drift import BlockLevels, Cusum, DriftMonitor, DriftSettings, block_levels, reference_monitor
from streamid.online.head import RETIRED_KEPT, OutputHead
from streamid.online.recalibrate import MAX_GAIN_CHANGE, recalibrate
from streamid.online.refresh import RefreshPolicy
from streamid.sim.drift import drift_start_ns, simulate_drift


def _run_lengths(k: float, h: float, shift: float, runs: int, seed: int) -> np.ndarray:
    """Values until the first signal of a fresh two-sided CUSUM, N(shift, 1) values, ``runs`` times."""
    rng = np.random.default_rng(seed)
    out = np.empty(runs)
    for r in range(runs):
        c, n = Cusum(k, h), 0
        while n < 100_000:  # bounded: the in-control mean is ~465
            n += 1
            if c.update(float(rng.normal(shift, 1.0))):
                break
        out[r] = n
    return out


@pytest.mark.parametrize(("h", "shift", "published"), [(5.0, 1.0, 10.4), (5.0, 2.0, 4.01), (4.0, 1.0, 8.38)])
def test_cusum_run_lengths_after_a_shift_are_the_published_ones(h: float, shift: float, published: float) -> None:
    """Montgomery, Introduction to Statistical Quality Control, Table 9.3 (k = 0.5): ARL after a shift of the mean."""
    rl = _run_lengths(0.5, h, shift, 4000, 1)
    se = rl.std() / np.sqrt(rl.size)
    assert abs(rl.mean() - published) < 4 * se + 0.02 * published


def test_cusum_in_control_run_length_is_the_published_two_sided_one() -> None:
    """Table 9.3: in-control ARL 465 for k = 0.5, h = 5 (Siegmund's approximation: 938 a side, 469 for both)."""
    rl = _run_lengths(0.5, 5.0, 0.0, 1500, 2)
    se = rl.std() / np.sqrt(rl.size)
    assert abs(rl.mean() - 465.0) < 4 * se + 0.03 * 465.0


def test_cusum_counts_back_to_the_change_and_validates_its_settings() -> None:
    c = Cusum(0.5, 5.0)
    assert [c.update(0.0) for _ in range(10)] == [0] * 10
    sides = [c.update(2.0) for _ in range(4)]  # +1.5 a value: 6 >= 5 after four
    assert sides == [0, 0, 0, 1] and c.run == 4 and c.upper == 0.0  # four values above zero, then reset
    assert [c.update(-3.0) for _ in range(2)][-1] == -1 and c.run == 2  # a fall: the lower side
    for bad in (0, -1.0, float("nan"), True):
        with pytest.raises(ValueError, match=r"CUSUM k must be a number > 0; got"):
            Cusum(k=bad)
    with pytest.raises(ValueError, match="CUSUM h must be a finite number > 0; got inf"):
        Cusum(h=float("inf"))


def _monitor(spread: float = 0.05) -> DriftMonitor:
    rng = np.random.default_rng(5)
    return DriftMonitor(DriftSettings(), 100, BlockLevels(rng.normal(0.0, spread, 40), np.ones(40), np.ones(40)))


def test_one_outlying_block_alone_never_raises_a_drift_but_a_sustained_change_does() -> None:
    mon = _monitor()
    glitch = [0.0] * 20 + [np.inf] + [0.0] * 20 + [-50.0] + [0.0] * 20  # a diverged run, then a collapse
    assert all(mon.block(v, 1.0, 1.0, i) is None for i, v in enumerate(glitch))
    hits = [mon.block(np.log(1.2), 1.0, 1.0, 100 + i) for i in range(10)]  # the output 20 % above the model from 100
    first = next(i for i, h in enumerate(hits) if h is not None)
    assert 2 <= first <= 4 and hits[first] == len(glitch) - 1  # it began after the last block with a zero sum
    low = [mon.block(np.log(0.8), 1.0, 1.0, 200 + i) for i in range(10)]  # and 20 % below: the other side
    assert any(h is not None for h in low)


def test_blocks_without_excitation_are_not_judged() -> None:
    mon = _monitor()
    assert all(mon.block(np.log(3.0), 0.2, 1.0, i) is None for i in range(50))  # rms 0.2 < 0.25 x the reference's 1
    assert mon.skipped == 50 and all(mon.block(np.nan, 1.0, 1.0, i) is None for i in range(5))
    assert mon.skipped == 55


def test_the_level_expected_follows_the_models_amplitude() -> None:
    """A model whose amplitude error grows with the drive: levels on the reference's line raise nothing, at any
    amplitude of its range, and a 20 % gain change on top of the line is found within 5 blocks; a reference that
    ignores the amplitude sees the line's swing as spread and misses it."""
    rng = np.random.default_rng(8)
    amp = np.exp(rng.uniform(-1.0, 1.0, 40))
    ref = BlockLevels(0.3 * np.log(amp) + rng.normal(0.0, 0.02, 40), np.ones(40), amp)
    mon = DriftMonitor(DriftSettings(), 100, ref)
    assert mon.slope == pytest.approx(0.3, abs=0.03) and 0.05 <= mon.spread < 0.08  # the floor (x persistence)
    a2 = np.exp(rng.uniform(-1.0, 1.0, 400))
    assert all(mon.block(0.3 * np.log(a) + rng.normal(0.0, 0.02), 1.0, a, i) is None for i, a in enumerate(a2))
    hits = [mon.block(0.3 * np.log(a) + np.log(1.2), 1.0, a, 1000 + i) for i, a in enumerate(a2[:10])]
    assert any(h is not None for h in hits[:5])
    flat = DriftMonitor(DriftSettings(), 100, BlockLevels(ref.level, ref.rms, np.ones(40)))  # ignoring amplitude
    assert flat.spread > 0.15
    assert all(flat.block(0.3 * np.log(a) + np.log(1.2), 1.0, 1.0, i) is None for i, a in enumerate(a2[:10]))


def test_residuals_in_runs_widen_the_spread() -> None:
    """Reference residuals that come in runs (autocorrelated) and a stream wider than its reference both widen the
    spread the test uses, so neither alone raises alarms."""
    rng = np.random.default_rng(9)
    runs = np.repeat(rng.normal(0.0, 0.1, 10), 4)  # ten runs of four equal blocks
    mon = DriftMonitor(DriftSettings(), 100, BlockLevels(runs, np.ones(40), np.ones(40)))
    assert mon.persistence > 1.5
    wide = _monitor(0.02)
    assert wide.current_spread() < 0.08
    for i, x in enumerate(rng.normal(0.0, 0.2, 40)):
        wide.block(float(x), 1.0, 1.0, i)
    assert wide.current_spread() > 0.15


def test_block_levels_are_those_of_short_free_runs() -> None:
    t, u, y = simulate_drift("piezo", 0.2, 0.1, 0.0, 3)  # no change: a plain record
    ident = OnlineIdentifier(StreamConfig(window_s=0.1, update_every_s=0.1), stream="p")
    ident.learn_many(t[:2001], u[:2001], y[:2001])
    ident.update_all()
    m = ident.model
    assert m is not None
    bl = block_levels(m, u[2000:3000, None], y[2000:3000], 100)
    L = m.max_lag
    sim = m.simulate(u[2000 : 2000 + L + 100, None], y[2000 : 2000 + L])[L:]  # the first block by hand
    yb = y[2000 + L : 2000 + L + 100]
    assert bl.level.shape == bl.rms.shape == bl.model_rms.shape == ((1000 - L) // 100,)
    assert bl.level[0] == pytest.approx(np.log(np.std(yb) / np.std(sim)))
    assert bl.rms[0] == pytest.approx(np.std(yb)) and bl.model_rms[0] == pytest.approx(np.std(sim))
    mon = reference_monitor(DriftSettings(), m, u[2000:3000, None], y[2000:3000], int(t[1] - t[0]))
    assert mon is not None and mon.block_samples == (1000 - L) // 8  # 0.5 s blocks cut to give 8 reference blocks
    assert reference_monitor(DriftSettings(), m, u[2000:2100, None], y[2000:2100], int(t[1] - t[0])) is None


def test_recalibration_recovers_a_gain_and_offset_change_exactly() -> None:
    t, u, y = simulate_drift("piezo", 0.2, 0.1, 0.0, 3)
    ident = OnlineIdentifier(StreamConfig(window_s=0.1, update_every_s=0.1), stream="p")
    ident.learn_many(t[:2001], u[:2001], y[:2001])
    ident.update_all()
    m = ident.model
    assert m is not None
    uu = u[2000:3000, None]
    own = m.simulate(uu, y[2000 : 2000 + m.max_lag])  # a device that is exactly the model...
    drifted = 1.3 * own - 0.7  # ...whose gain rose 30 % and offset moved
    r = recalibrate(m, uu, drifted)
    assert r is not None
    assert r.metrics["recalibrated_gain"] == pytest.approx(1.3, rel=1e-6)
    assert r.metrics["recalibrated_offset"] == pytest.approx(-0.7, abs=1e-6 * np.ptp(drifted))
    assert np.allclose(r.simulate(uu, drifted[: m.max_lag]), drifted, atol=1e-6 * np.ptp(drifted))
    assert np.array_equal(r.centres, m.centres) and np.array_equal(r.weights, m.weights)  # the same network
    # its band in the new scale: the same quantiles, the scale (output units) times the gain
    assert m.interval is not None and r.interval is not None and r.interval.quantiles == m.interval.quantiles
    assert r.interval.scale == pytest.approx(1.3 * m.interval.scale, rel=1e-6)
    b0, b1 = m.simulate(uu, own[: m.max_lag], interval=0.9), r.simulate(uu, drifted[: m.max_lag], interval=0.9)
    assert np.allclose(b1.upper - b1.lower, 1.3 * (b0.upper - b0.lower), rtol=1e-6, atol=1e-9 * np.ptp(drifted))
    assert recalibrate(m, uu, (MAX_GAIN_CHANGE + 0.5) * own) is None  # too large a change: identify anew
    assert recalibrate(m, uu, -own) is None
    assert recalibrate(dataclasses.replace(m), uu, np.full(1000, 2.0)) is None  # a constant output


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
    watch = st["models"]["x"]["drift_watch"]  # the current champion's watch, as the status shows it
    assert watch["h"] == DriftSettings().h and watch["blocks"] > 0 and 0 <= watch["cusum_up"] < watch["h"]
    assert watch["spread"] >= DriftSettings().min_spread


def test_a_replaced_champion_stays_watched_for_a_window_and_one_change_raises_one_event() -> None:
    """Simulated MR damper, +20 % at 30 s (seed 0, default settings): the champion of the change was replaced
    shortly before it, and the replaced champion's watch, kept for one window after its replacement, signals
    the change within 3 s.  Then every reference of the output is spent: one change, one event."""
    t, u, y = simulate_drift("mr_damper", 36.0, 30.0, 0.2, 0)
    change_ns = drift_start_ns("mr_damper", 30.0)
    cfg = StreamConfig(window_s=10.0, update_every_s=1.0)
    # every update a coevolution run (the sequence of champions this scenario was built on; refreshes, on by
    # default, change which champion serves at the change: tests/test_refresh.py)
    ident = OnlineIdentifier(cfg, stream="d", refresh=RefreshPolicy(enabled=False))
    drifts, replaced_seen = [], 0
    for k in range(0, t.size, 20):  # 0.1 s batches, identified as they come
        ident.learn_many(t[k : k + 20], u[k : k + 20], y[k : k + 20], inputs=["v"], outputs=["f"])
        drifts += [e for e in ident.drain_events() if e.kind == "drift"]
        ident.update_all()
        watched = ident.status()["models"].get("f", {}).get("drift_watch_replaced", [])
        assert len(watched) <= RETIRED_KEPT and all(0 < w["blocks_left"] <= 20 for w in watched)  # 10 s of 0.5 s
        replaced_seen = max(replaced_seen, len(watched))
    assert replaced_seen >= 1
    assert len(drifts) == 1 and drifts[0].t_ns is not None  # no false alarm before, one event for one change
    assert 0 <= drifts[0].t_ns - change_ns <= 3_000_000_000
    assert "(replaced, still watched)" in drifts[0].message
    st = ident.status()["models"]["f"]
    assert st["drifts"] == 1


def _model() -> Model:
    return Model((Regressor("y", 0, 1), Regressor("u", 0, 1)), np.zeros((2, 2)), np.ones(2), np.ones(2),
                 Normalisation((0.0,), (1.0,), 0.0, 1.0))


def test_a_spent_monitor_signals_no_more_and_is_not_kept_when_its_champion_is_replaced() -> None:
    mon = _monitor()
    for i in range(4):
        mon.block(0.5, 1.0, 1.0, i)
    mon.spend()
    assert all(mon.block(0.5, 1.0, 1.0, 10 + i) is None for i in range(50))  # the shift goes on: no new signal
    assert mon.summary()["spent"] is True and mon.summary()["blocks"] == 54
    head = OutputHead("y")
    head.new_champion(_model(), mon, window_samples=1000)
    head.new_champion(_model(), _monitor(), window_samples=1000)
    assert not head.retired  # spent: nothing left to watch for
    for _ in range(RETIRED_KEPT + 2):
        head.new_champion(_model(), _monitor(), window_samples=1000)
    assert len(head.retired) == RETIRED_KEPT
    assert all(w.blocks_left == -(-1000 // w.monitor.block_samples) for w in head.retired)


def test_a_replaced_champions_watch_needs_more_evidence_so_the_outputs_alarm_rate_stays_bounded() -> None:
    head = OutputHead("y")
    head.new_champion(_model(), _monitor(), window_samples=1000)
    head.new_champion(_model(), _monitor(), window_samples=1000)
    (w,) = head.retired
    s = DriftSettings()
    assert w.monitor.summary()["h"] == pytest.approx(s.h + np.log(1 + RETIRED_KEPT) / (2 * s.k))
    assert head.monitor is not None and head.monitor.summary()["h"] == s.h
    hits = [w.monitor.block(np.log(1.5), 1.0, 1.0, i) for i in range(4)]  # clipped at 3: +2 a block
    assert hits[:3] == [None] * 3 and hits[3] is not None  # 6 >= 5.5 signals the champion's test, 6.05 needs a 4th block


def test_a_new_champion_starts_with_the_spread_its_predecessor_saw_on_the_stream() -> None:
    old = _monitor()
    rng = np.random.default_rng(3)
    for i, v in enumerate(rng.normal(0.0, 0.2, 30)):  # the stream's blocks vary 4 x more than the reference did
        old.block(float(v), 1.0, 1.0, i)
    wide = old.current_spread()
    assert wide > 2 * 0.05  # twice the reference's
    head = OutputHead("y")
    head.new_champion(_model(), old, window_samples=1000)
    new = _monitor()
    assert new.current_spread() == pytest.approx(0.05, rel=0.3)  # a quiet reference window alone
    head.new_champion(_model(), new, window_samples=1000)
    assert new.current_spread() == pytest.approx(wide, rel=0.05)  # ... widened by what the stream showed
