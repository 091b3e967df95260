"""The bounded queue of pending windows (``max_pending_windows``): pure numpy, no transport.

Same ground truth as tests/test_window.py: sample k has u = fu(k), y = fy(k).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from streamid.wire.codec import SampleBatch
from streamid.daemon.config import StreamConfig, config_from_mapping
from streamid.online.pending import PendingWindows, due_windows
from streamid.online.window import Window, WindowBuffer, WindowParams
from streamid.errors import ConfigError

P = 1_000_000  # 1 kHz
T0 = 5_000_000_000


def fu(k: np.ndarray) -> np.ndarray:
    return np.sin(0.013 * k) + 1e-3 * k


def fy(k: np.ndarray) -> np.ndarray:
    return np.cos(0.007 * k) - 2e-3 * k


def batch(seq: int, k0: int, n: int, period: int = P) -> SampleBatch:
    k = np.arange(k0, k0 + n)
    return SampleBatch("s", seq, T0 + k0 * period, period, None, {"u": fu(k)}, {"y": fy(k)})


def check_window(w: Window) -> np.ndarray:
    """Assert the window holds the true signal on a contiguous grid; return its k."""
    assert w.u.shape == (w.n, 1) and w.y.shape == (w.n, 1)
    k = (w.t0_ns - T0) // w.period_ns + np.arange(w.n)
    np.testing.assert_array_equal(w.u[:, 0], fu(k))
    np.testing.assert_array_equal(w.y[:, 0], fy(k))
    return k


def make(window: int, hop: int, **kw: object) -> WindowBuffer:
    return WindowBuffer("s", WindowParams(window_samples=window, hop_samples=hop, **kw))  # type: ignore[arg-type]


def _take_all(wb):  # type: ignore[no-untyped-def]
    out = []
    for _ in range(10_000):
        w = wb.take()
        if w is None:
            return out
        out.append(w)
    raise AssertionError("the queue never emptied")


def test_queue_keeps_the_newest_windows_in_order_up_to_its_bound() -> None:
    wb = make(100, 50, max_pending_windows=5)
    for i in range(40):  # 400 samples: windows end at 100, 150, ..., 400 -> 7 closed
        wb.append(batch(i, 10 * i, 10))
    c = wb.counters()
    assert c["windows_closed"] == 7 and c["pending_windows"] == 5 and c["windows_coalesced"] == 2
    # the five overlapping windows share their samples: 100 + 4 x 50 of them held, once
    assert c["pending_bytes"] == (100 + 4 * 50) * 2 * 8 == c["pending_bytes_peak"]
    assert c["pending_bytes_max"] == 5 * 100 * 2 * 8  # the bound: five windows, whatever their overlap
    assert c["pending_windows_peak"] == 5
    got = _take_all(wb)
    assert [int(check_window(w)[-1]) + 1 for w in got] == [200, 250, 300, 350, 400]  # oldest first
    assert [w.coalesced_before for w in got] == [2, 0, 0, 0, 0]
    assert [w.number for w in got] == sorted(w.number for w in got)
    c = wb.counters()
    assert c["pending_windows"] == 0 and c["pending_bytes"] == 0 and c["pending"] is False


def test_a_bound_of_one_coalesces_to_the_newest() -> None:
    wb = make(100, 50, max_pending_windows=1)
    for i in range(40):
        wb.append(batch(i, 10 * i, 10))
    c = wb.counters()
    assert c["max_pending_windows"] == 1 and c["pending_windows"] == 1 and c["windows_coalesced"] == 6
    (w,) = _take_all(wb)
    assert int(check_window(w)[-1]) == 399 and w.coalesced_before == 6


def test_one_batch_closing_many_windows_queues_those_still_held() -> None:
    wb = make(100, 10, max_pending_windows=50)  # ring: 100 + 10 + slack 100 = 210 samples
    wb.append(batch(0, 0, 99))
    wb.append(batch(1, 99, 201))  # windows end at 100, 110, ..., 300: 21 closed by one batch
    got = _take_all(wb)
    ends = [int(check_window(w)[-1]) + 1 for w in got]
    assert ends == list(range(190, 301, 10))  # [90, 300) is still in the ring; older ones were overwritten
    c = wb.counters()
    assert c["windows_closed"] == 21 and c["windows_coalesced"] == 21 - len(ends) == 9
    assert got[0].coalesced_before == 9


def test_an_endless_stream_never_taken_holds_at_most_the_bound() -> None:
    wb = make(100, 10, max_pending_windows=8)
    ring = None
    for i in range(3000):
        wb.append(batch(i, 25 * i, 25))
        if i == 10:
            ring = wb._ring  # noqa: SLF001 - the preallocated ring is never replaced
        if i % 500 == 0:
            assert wb.counters()["pending_windows"] <= 8
    assert wb._ring is ring  # noqa: SLF001
    c = wb.counters()
    assert c["pending_windows"] == 8 and c["pending_bytes"] == (100 + 7 * 10) * 2 * 8  # one span of samples
    assert c["pending_bytes_max"] == 8 * 100 * 2 * 8
    assert c["windows_closed"] == c["windows_coalesced"] + 8
    assert c["pending_windows_peak"] == 8 and c["pending_bytes_peak"] == c["pending_bytes"]
    got = _take_all(wb)
    assert len(got) == 8 and int(check_window(got[-1])[-1]) == 3000 * 25 - 1


def test_a_reset_keeps_the_closed_windows_of_the_old_epoch() -> None:
    """A period change starts a new epoch; the windows that closed before it are complete data and are still
    identified, oldest first, each with its own period and epoch (bad input loses nothing)."""
    wb = make(100, 50, max_pending_windows=4)
    for i in range(20):
        wb.append(batch(i, 10 * i, 10))
    assert wb.counters()["pending_windows"] == 3
    wb.append(SampleBatch("s", 99, T0 + 200 * P, 2 * P, None, {"u": np.ones(10)}, {"y": np.ones(10)}))  # new period
    c = wb.counters()
    assert c["pending_windows"] == 3 and c["resets"] == {"period": 1} and c["windows_coalesced"] == 0
    old = _take_all(wb)
    assert [w.period_ns for w in old] == [P] * 3 and len({w.epoch for w in old}) == 1
    assert [w.number for w in old] == sorted(w.number for w in old)
    for j in range(1, 12):  # the new epoch's windows follow, on the new period
        wb.append(SampleBatch("s", 99 + j, T0 + 200 * P + 20 * j * P, 2 * P, None, {"u": np.ones(10)}, {"y": np.ones(10)}))
    new = _take_all(wb)
    assert new and all(w.period_ns == 2 * P and w.epoch > old[0].epoch for w in new)


@pytest.mark.parametrize("bad", [0, 1001, -3, True, 2.0, "4"])
def test_max_pending_windows_is_validated(bad: object) -> None:
    with pytest.raises(ConfigError, match=r"max_pending_windows must be an integer in \[1, 1000\]"):
        StreamConfig(max_pending_windows=bad)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="max_pending_windows"):
        config_from_mapping({"defaults": {"max_pending_windows": bad}})


def test_max_pending_windows_from_toml_and_print_config() -> None:
    cfg = config_from_mapping({"defaults": {"window_s": 4.0}, "streams": {"mr": {"max_pending_windows": 16}}})
    assert cfg.defaults.max_pending_windows == 1000 and cfg.defaults.max_pending_bytes == 64 * 2**20
    assert cfg.for_stream("mr").max_pending_windows == 16
    assert cfg.for_stream("mr").window_params().max_pending_windows == 16
    assert cfg.for_stream("mr").to_dict()["max_pending_windows"] == 16


def test_pending_windows_refuses_a_bad_limit() -> None:
    with pytest.raises(ValueError, match="limit"):
        PendingWindows(0)


@settings(max_examples=300, deadline=None)
@given(nc=st.integers(0, 500), extra=st.integers(0, 400), hop=st.integers(1, 60), w=st.integers(2, 80),
       back=st.integers(0, 200), limit=st.integers(1, 20))
def test_due_windows_matches_a_direct_enumeration(nc: int, extra: int, hop: int, w: int, back: int, limit: int) -> None:
    complete, start = nc + extra, max(0, nc - w - back)
    n, keep = due_windows(nc, complete, hop, w, start, limit)
    ends = list(range(nc, complete + 1, hop))
    held = [e for e in ends if e - w >= start][-limit:]
    assert n == len(ends) and [e for _, e in keep] == held
    assert all(ends[i] == e for i, e in keep)


@settings(max_examples=80, deadline=None)
@given(sizes=st.lists(st.integers(1, 120), min_size=1, max_size=60), limit=st.integers(1, 12),
       take_every=st.integers(1, 7))
def test_property_queue_accounting_and_true_windows(sizes: list[int], limit: int, take_every: int) -> None:
    wb = make(30, 7, max_pending_windows=limit)
    k, taken, last_end = 0, 0, -1
    for i, n in enumerate(sizes):
        wb.append(batch(i, k, n))
        k += n
        assert wb.counters()["pending_windows"] <= limit
        if i % take_every == 0:
            for win in _take_all(wb):
                end = int(check_window(win)[-1])
                assert end > last_end  # in time order, never twice
                last_end = end
                taken += 1
    c = wb.counters()
    assert c.get("windows_closed", 0) == taken + c.get("windows_coalesced", 0) + c["pending_windows"]
    held = set()  # the samples of the windows still waiting: each held once
    for win in _take_all(wb):
        held.update(int(k) for k in check_window(win))
    assert c["pending_bytes"] == len(held) * 2 * 8


def _feed(wb: WindowBuffer, n_batches: int, speed: float | None) -> None:
    """100-sample batches (0.1 s at 1 kHz) arriving at ``speed`` x real time (None: no clock given)."""
    for i in range(n_batches):
        now = 0 if speed is None else int(1e9 + i * 100 * P / speed)
        wb.append(batch(i, i * 100, 100), now_ns=now)


@pytest.mark.parametrize("speed", [None, 2.0, 1000.0])
def test_stream_time_faster_than_the_clock_queues_every_window_in_order(speed: float | None) -> None:
    wb = make(500, 100, max_pending_windows=1000)  # a window closes every 100 samples (the StreamConfig default bound)
    _feed(wb, 40, speed)
    wins = _take_all(wb)
    c = wb.counters()
    assert len(wins) == c["windows_closed"] == 36 and c.get("windows_coalesced", 0) == 0 and not c["live"]
    ends = [int(check_window(w)[-1]) for w in wins]
    assert ends == list(range(499, 4000, 100))


def test_a_live_stream_that_falls_behind_keeps_its_backlog_in_order() -> None:
    wb = make(500, 100, max_pending_windows=1000)  # max_pending_s: the default, 120 s
    _feed(wb, 40, 1.0)
    c = wb.counters()
    assert c["live"] and c["pending_windows"] == c["windows_closed"] == 36 and c.get("windows_coalesced", 0) == 0
    assert c["pending_span_s"] == pytest.approx(3.5) and c["max_pending_s"] == 120.0
    assert c["pending_bytes"] == 4000 * 2 * 8  # 36 windows of 500 samples every 100: the 4,000 samples, once
    assert [int(check_window(w)[-1]) for w in _take_all(wb)] == list(range(499, 4000, 100))


def test_a_live_backlog_is_bounded_in_stream_time() -> None:
    """Past max_pending_s of stream time behind the newest window, a live stream's oldest waiting windows are
    dropped (coalesced, counted); a replay (stream time faster than the clock) is not bound by it."""
    wb = make(500, 100, max_pending_windows=1000, max_pending_s=1.0)
    _feed(wb, 40, 1.0)
    c = wb.counters()
    assert c["pending_windows"] == 11 and c["windows_coalesced"] == 25 and c["pending_span_s"] == pytest.approx(1.0)
    got = _take_all(wb)
    assert [int(check_window(w)[-1]) for w in got] == list(range(2999, 4000, 100)) and got[0].coalesced_before == 25
    fast = make(500, 100, max_pending_windows=1000, max_pending_s=1.0)
    _feed(fast, 40, 1000.0)
    assert fast.counters()["pending_windows"] == 36


def test_max_pending_s_zero_keeps_only_a_live_streams_newest_window() -> None:
    wb = make(500, 100, max_pending_windows=1000, max_pending_s=0.0)
    _feed(wb, 40, 1.0)
    c = wb.counters()
    assert c["live"] and c["pending_windows"] == 1 and c["windows_coalesced"] == c["windows_closed"] - 1
    assert int(check_window(_take_all(wb)[0])[-1]) == 3999  # the newest


@pytest.mark.parametrize("bad", [-1.0, float("nan"), float("inf"), 90000.0, "5", True])
def test_max_pending_s_is_validated(bad: object) -> None:
    with pytest.raises(ConfigError, match=r"max_pending_s must be a number of seconds in \[0, 86400\]"):
        StreamConfig(max_pending_s=bad)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="max_pending_s"):
        config_from_mapping({"defaults": {"max_pending_s": bad}})
    assert config_from_mapping({"streams": {"a": {"max_pending_s": 30}}}).for_stream("a").max_pending_s == 30


def test_the_byte_bound_drops_the_oldest_waiting_windows() -> None:
    wb = make(500, 100, max_pending_windows=1000, max_pending_bytes=5 * 500 * 2 * 8)  # five windows of 500 samples x 2 signals
    _feed(wb, 40, None)
    c = wb.counters()
    # the windows share their samples: 500 + 20 x 100 <= 2,500 samples fit the bytes of five whole windows
    assert c["pending_windows"] == 21 and c["pending_bytes_peak"] <= 5 * 500 * 16 == c["pending_bytes_max"]
    assert c["pending_bytes"] == 2500 * 16
    assert c["windows_coalesced"] == 15 and int(check_window(_take_all(wb)[0])[-1]) == 1999


def test_max_pending_bytes_is_validated() -> None:
    with pytest.raises(ConfigError, match=r"max_pending_bytes must be an integer number of bytes >= 1; got 0"):
        StreamConfig(max_pending_bytes=0)
