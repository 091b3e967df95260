"""Unit tests of the daemon's window buffer (pure numpy, no transport).

The ground truth everywhere: sample k of the stream has u = fu(k), y = fy(k),
so every window handed out must equal those functions at its own times, whatever
was lost, duplicated, reordered or re-chunked on the way.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from streamid.wire.codec import SampleBatch
from streamid.online.window import Window, WindowBuffer, WindowParams
from streamid.errors import ConfigError

P = 1_000_000  # 1 kHz
T0 = 5_000_000_000  # the stream's clock does not start at zero


def fu(k: np.ndarray) -> np.ndarray:
    return np.sin(0.013 * k) + 1e-3 * k


def fy(k: np.ndarray) -> np.ndarray:
    return np.cos(0.007 * k) - 2e-3 * k


def batch(seq: int, k0: int, n: int, kind: str = "samples", period: int = P, t0: int = T0) -> SampleBatch:
    k = np.arange(k0, k0 + n)
    ins = {"u": fu(k)} if kind in ("samples", "u") else {}
    outs = {"y": fy(k)} if kind in ("samples", "y") else {}
    return SampleBatch("s", seq, t0 + k0 * period, period, None, ins, outs)


def check_window(w: Window, period: int = P, t0: int = T0) -> np.ndarray:
    """Assert the window holds the true signal on a contiguous grid; return its k."""
    assert w.u.shape == (w.n, 1) and w.y.shape == (w.n, 1)
    assert w.u.flags.c_contiguous and w.y.flags.c_contiguous
    assert w.period_ns == period
    assert (w.t0_ns - t0) % period == 0
    k = (w.t0_ns - t0) // period + np.arange(w.n)
    np.testing.assert_array_equal(w.u[:, 0], fu(k))
    np.testing.assert_array_equal(w.y[:, 0], fy(k))
    np.testing.assert_array_equal(w.times_ns(), t0 + k * period)
    return k


def make(window: int = 100, hop: int = 50, **kw: object) -> WindowBuffer:
    return WindowBuffer("s", WindowParams(window_samples=window, hop_samples=hop, **kw))  # type: ignore[arg-type]


def test_contiguous_stream_windows_hold_the_newest_samples() -> None:
    wb = make(100, 50)
    got = []
    for i in range(20):
        wb.append(batch(i, 10 * i, 10))
        w = wb.take()
        if w is not None:
            got.append(w)
    assert [w.number for w in got] == [1, 2, 3]
    ends = [int(check_window(w)[-1]) for w in got]
    assert ends == [99, 149, 199]
    assert all(w.n == 100 and w.input_names == ("u",) and w.output_names == ("y",) for w in got)
    c = wb.counters()
    assert c["samples_in"] == 200 and c["bad_total"] == 0 and c["windows_coalesced"] == 0
    assert c["gaps"] if "gaps" in c else True
    assert "gaps" not in c


def test_hop_in_seconds_and_window_in_seconds() -> None:
    wb = WindowBuffer("s", WindowParams(window_s=0.2, hop_s=0.1))
    for i in range(30):
        wb.append(batch(i, 10 * i, 10))
    w = wb.take()
    assert w is not None and w.n == 200
    assert wb.lengths[:2] == (200, 100)
    assert int(check_window(w)[-1]) == 299


def test_untaken_windows_coalesce_and_memory_stays_flat() -> None:
    wb = make(100, 10)
    ring_before = None
    for i in range(2000):
        wb.append(batch(i, 25 * i, 25))
        if i == 10:
            ring_before = wb._ring  # noqa: SLF001 - the preallocated ring must never be replaced
    assert wb._ring is ring_before  # noqa: SLF001
    c = wb.counters()
    assert c["windows_closed"] == (2000 * 25 - 100) // 10 + 1
    assert c["windows_coalesced"] == c["windows_closed"] - 1  # only the newest survives
    w = wb.take()
    assert w is not None and int(check_window(w)[-1]) == 2000 * 25 - 1
    assert w.coalesced_before == c["windows_coalesced"]
    assert wb.take() is None
    assert c["buffered_samples"] <= wb.lengths[2]


def test_one_huge_batch_larger_than_the_ring() -> None:
    wb = make(100, 30)
    wb.append(batch(0, 0, 5000))
    w = wb.take()
    assert w is not None
    k = check_window(w)
    assert k[-1] == 4999 - (4999 - 99) % 30  # newest hop boundary
    assert wb.counters()["samples_discarded"] > 0


def test_gap_restarts_the_window_and_no_window_spans_it() -> None:
    wb = make(100, 50)
    windows = []
    for i in range(15):
        wb.append(batch(i, 10 * i, 10))
        if (w := wb.take()) is not None:
            windows.append(w)
    # publisher stops 37 samples, then comes back (its sequence number continues)
    for i in range(15, 40):
        wb.append(batch(i, 10 * i + 37, 10))
        if (w := wb.take()) is not None:
            windows.append(w)
    c = wb.counters()
    assert c["gaps"] == 1 and c["gap_samples"] == 37
    assert c["resets"] == {"gap": 1}
    for w in windows:
        k = check_window(w)
        assert not (k[0] < 187 <= k[-1]), "a window spans the gap"
    after = [w for w in windows if check_window(w)[0] >= 187]
    assert after and int(check_window(after[0])[0]) == 187  # restarted at the first sample after the gap
    assert any(e.kind == "gap" for e in wb.drain_events())


def test_duplicate_and_out_of_order_batches_are_dropped_and_counted() -> None:
    wb = make(100, 50)
    for i in range(8):
        wb.append(batch(i, 10 * i, 10))
    assert wb.append(batch(7, 70, 10)) == 0  # same batch again
    assert wb.append(batch(5, 50, 10)) == 0  # an old batch, seq seen
    assert wb.append(batch(99, 30, 10)) == 0  # old times, never seen seq: out of order
    for i in range(8, 20):
        wb.append(batch(i, 10 * i, 10))
    c = wb.counters()
    assert c["bad"] == {"duplicate": 2, "out_of_order": 1}
    assert c["samples_in"] == 200 and "gaps" not in c
    w = wb.take()
    assert w is not None and int(check_window(w)[-1]) == 199


def test_partial_overlap_is_trimmed() -> None:
    wb = make(100, 50)
    wb.append(batch(0, 0, 60))
    assert wb.append(batch(1, 40, 60)) == 40  # 20 samples already held
    w = wb.take()
    assert w is not None and int(check_window(w)[-1]) == 99
    assert wb.counters()["overlap_samples"] == 20


def test_period_change_resets_with_new_epoch() -> None:
    wb = make(100, 50)
    for i in range(12):
        wb.append(batch(i, 10 * i, 10))
    first = wb.take()
    assert first is not None
    q = 2 * P
    t0b = T0 + 120 * P
    for i in range(12):
        wb.append(batch(100 + i, 10 * i, 10, period=q, t0=t0b))
    w = wb.take()
    assert w is not None and w.epoch != first.epoch
    check_window(w, period=q, t0=t0b)
    c = wb.counters()
    assert c["resets"] == {"period": 1} and c["period_ns"] == q


def test_publisher_restart_with_earlier_clock_restarts_the_stream() -> None:
    wb = make(100, 50)
    for i in range(100):
        wb.append(batch(i, 10 * i, 10))
    wb.take()
    for i in range(15):  # the device restarted: seq and clock from zero again
        wb.append(batch(i, 10 * i, 10))
    c = wb.counters()
    assert c["resets"].get("restart") == 1
    w = wb.take()
    assert w is not None
    assert int(check_window(w)[-1]) == 149


@pytest.mark.parametrize("bad_value", [np.nan, np.inf, -np.inf, 1e200])
def test_nonfinite_and_absurd_values_are_refused(bad_value: float) -> None:
    wb = make(50, 50)
    for i in range(3):
        wb.append(batch(i, 10 * i, 10))
    b = batch(3, 30, 10)
    u = b.inputs["u"].copy()
    u[4] = bad_value
    assert wb.append(SampleBatch("s", 3, b.t0_ns, P, None, {"u": u}, dict(b.outputs))) == 0
    kind = "magnitude" if np.isfinite(bad_value) else "nonfinite"
    assert wb.counters()["bad"] == {kind: 1}
    for i in range(4, 20):
        wb.append(batch(i, 10 * i, 10))
    w = wb.take()
    assert w is not None
    k = check_window(w)
    assert k[0] >= 40  # nothing before the refused batch is joined across the hole
    assert np.isfinite(w.u).all()


def test_separate_u_and_y_keys_are_aligned_by_time() -> None:
    wb = make(100, 50)
    # u in chunks of 7, y in chunks of 13, u runs ahead
    ku = ky = 0
    seq_u = seq_y = 0
    windows = []
    while ky < 400:
        wb.append(batch(seq_u, ku, 7, kind="u"), source="u")
        ku += 7
        seq_u += 1
        if ku - ky > 30:
            wb.append(batch(seq_y, ky, 13, kind="y"), source="y")
            ky += 13
            seq_y += 1
        if (w := wb.take()) is not None:
            windows.append(w)
    assert len(windows) >= 5
    for w in windows:
        check_window(w)
    c = wb.counters()
    assert c["bad_total"] == 0 and "unaligned" not in c


def test_y_before_u_and_y_lagging_too_far() -> None:
    wb = make(50, 25, align_slack_samples=40)
    wb.append(batch(0, 0, 20, kind="y"), source="y")
    for i in range(20):  # u runs 200 samples ahead of y: y is declared unaligned
        wb.append(batch(i, 10 * i, 10, kind="u"), source="u")
    assert wb.counters()["unaligned"] >= 1
    assert wb.take() is None
    for j in range(1, 30):  # y catches up late; stale y samples are discarded
        wb.append(batch(j, 20 * j, 20, kind="y"), source="y")
    for i in range(20, 60):
        wb.append(batch(i, 10 * i, 10, kind="u"), source="u")
    for i in range(60, 80):  # then both arrive in step
        wb.append(batch(i, 10 * i, 10, kind="u"), source="u")
        wb.append(batch(i, 10 * i, 10, kind="y"), source="y")
    w = wb.take()
    assert w is not None
    check_window(w)


def test_explicit_jittered_timestamps_and_gap_inside_a_batch() -> None:
    wb = make(60, 30)
    rng = np.random.default_rng(0)
    k = np.concatenate([np.arange(0, 100), np.arange(130, 250)])
    t = T0 + k * P + rng.integers(-P // 5, P // 5, size=k.size)
    t[0] = T0
    b = SampleBatch("s", 0, int(t[0]), 0, t.astype(np.int64), {"u": fu(k)}, {"y": fy(k)})
    wb.append(b)
    c = wb.counters()
    assert abs(c["period_ns"] - P) < P * 1e-3  # estimated from the time stamps
    assert c["gaps"] == 1 and c["gap_samples"] == 30
    w = wb.take()
    assert w is not None
    np.testing.assert_array_equal(w.u[:, 0], fu(np.arange(190, 250)))
    np.testing.assert_array_equal(w.y[:, 0], fy(np.arange(190, 250)))


def test_schema_change_resets_and_missing_configured_signal_is_refused() -> None:
    wb = make(30, 30)
    wb.append(batch(0, 0, 40))
    w1 = wb.take()
    k = np.arange(40, 80)
    wb.append(SampleBatch("s", 1, T0 + 40 * P, P, None, {"v": fu(k)}, {"y": fy(k)}))
    c = wb.counters()
    assert c["resets"] == {"schema": 1} and c["inputs"] == ["v"]
    w2 = wb.take()
    assert w1 is not None and w2 is not None and w2.epoch != w1.epoch and w2.input_names == ("v",)

    fixed = make(30, 30, inputs=("b", "a"), outputs=("y",))
    k = np.arange(40)
    fixed.append(SampleBatch("s", 0, T0, P, None, {"a": fu(k), "b": fy(k), "extra": k * 1.0}, {"y": fy(k)}))
    w = fixed.take()
    assert w is not None and w.input_names == ("b", "a") and w.u.shape == (30, 2)
    np.testing.assert_array_equal(w.u[:, 1], fu(k[:30]))  # closed at sample 30
    assert fixed.append(SampleBatch("s", 1, T0 + 40 * P, P, None, {"a": fu(k)}, {"y": fy(k)})) == 0
    assert fixed.counters()["bad"] == {"missing_signal": 1}


def test_bad_period_and_oversized_window_are_refused() -> None:
    wb = WindowBuffer("s", WindowParams(window_s=10.0, hop_s=1.0, max_window_samples=1000))
    assert wb.append(batch(0, 0, 10, period=1000)) == 0  # 10 s at 1 us = 1e7 samples
    t = np.array([T0], dtype=np.int64)
    one = SampleBatch("s", 1, T0, 0, t, {"u": np.ones(1)}, {"y": np.ones(1)})
    assert wb.append(one) == 0  # irregular single sample: no period to estimate
    assert wb.counters()["bad"] == {"period": 2}


def test_window_params_are_validated() -> None:
    with pytest.raises(ConfigError, match="window_s"):
        WindowParams(window_s=1.0, window_samples=10)
    with pytest.raises(ConfigError, match="hop_samples"):
        WindowParams(hop_samples=0)
    with pytest.raises(ConfigError, match="window_s.*-1"):
        WindowParams(window_s=-1.0)
    with pytest.raises(ConfigError, match="inputs"):
        WindowParams(inputs=("a", "a"))
    assert WindowParams().samples(5_000_000) == (2000, 200)  # defaults: 10 s window, 1 s hop


def test_a_closing_window_is_an_event_with_the_callers_clock() -> None:
    wb = WindowBuffer("s", WindowParams(window_samples=20, hop_samples=20))
    wb.append(batch(0, 0, 19), now_ns=111)
    assert not wb.has_pending and [e.kind for e in wb.drain_events()] == []
    wb.append(batch(1, 19, 1), now_ns=222)
    ev = wb.drain_events()
    assert [e.kind for e in ev] == ["window.closed"] and ev[0].received_ns == 222 and ev[0].t_ns == T0 + 19 * P
    w = wb.take()
    assert w is not None and w.received_ns == 222 and wb.pending_windows == 0


# -- property: whatever happens on the way, windows hold the truth ---------------------------
_ops = st.lists(
    st.tuples(
        st.sampled_from(["next", "next", "next", "dup", "old", "gap", "u_only", "y_only", "nan"]),
        st.integers(1, 40),
    ),
    min_size=5,
    max_size=150,
)


@settings(max_examples=150, deadline=None)
@given(ops=_ops, window=st.integers(2, 30), hop=st.integers(1, 20))
def test_property_windows_always_hold_true_contiguous_samples(
    ops: list[tuple[str, int]], window: int, hop: int
) -> None:
    wb = make(window, hop)
    k = 0
    ku = ky = 0
    seq = 0
    sent: list[SampleBatch] = []
    for op, n in ops:
        seq += 1
        if op == "next":
            ku = ky = k = max(ku, ky)
            b = batch(seq, k, n)
            wb.append(b)
            sent.append(b)
            k += n
            ku = ky = k
        elif op == "dup" and sent:
            wb.append(sent[-1])
        elif op == "old" and sent:
            wb.append(sent[len(sent) // 2])
        elif op == "gap":
            ku = ky = max(ku, ky) + n
        elif op == "u_only":
            wb.append(batch(seq, ku, n, kind="u"), source="u")
            ku += n
        elif op == "y_only":
            wb.append(batch(seq, ky, n, kind="y"), source="y")
            ky += n
        elif op == "nan":
            b = batch(seq, max(ku, ky), n)
            bad = dict(b.outputs)
            bad["y"] = bad["y"].copy()
            bad["y"][0] = np.nan
            wb.append(SampleBatch("s", seq, b.t0_ns, P, None, dict(b.inputs), bad))
        w = wb.take()
        if w is not None:
            assert w.n == window
            check_window(w)
    c = wb.counters()
    assert c["buffered_samples"] <= wb.lengths[2]
