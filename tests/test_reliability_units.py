"""Reliability fixes and checks at unit level (the Zenoh-level checks are in test_reliability_bad_input).

* u and y on different sample periods used to reset the stream at every batch,
  back and forth, forever (no window, no error): now the odd source is refused
  (``period_mismatch``) with a message, while a real period change -- every live
  source switching -- still goes through, and a source that went silent no
  longer vetoes one.
* an old batch received again after the ring moved past it used to be taken for
  a publisher restart (a full reset of a healthy stream): it is a duplicate.
* a batch renaming both its inputs and its outputs is one schema reset, not two.
* the status carries the last refusal's message (``last_bad``).
* identification is invariant to absurd but allowed scales of u and y (the
  engine normalises); a signal so small that its squares underflow float64 is
  dropped with a clear reason instead of a model with NaN metrics.
"""

from __future__ import annotations

import numpy as np
import pytest

from streamid.wire.codec import SampleBatch
from streamid.daemon.config import StreamConfig
from streamid.online.window import Window, WindowBuffer, WindowParams
from streamid.online.update import identify_window
from streamid.sim import get_device

P = 5_000_000
T0 = 10**12


def _b(kind: str, seq: int, k0: int, n: int, period: int = P, t0: int = T0, names: tuple[str, str] = ("v", "f")
       ) -> SampleBatch:
    k = np.arange(k0, k0 + n, dtype=float)
    ins = {names[0]: np.sin(0.1 * k)} if kind in ("samples", "u") else {}
    outs = {names[1]: np.cos(0.05 * k)} if kind in ("samples", "y") else {}
    return SampleBatch("s", seq, t0 + k0 * period, period, None, ins, outs)


def _wb() -> WindowBuffer:
    return WindowBuffer("s", WindowParams(window_samples=200, hop_samples=100))


def test_u_and_y_on_different_periods_are_refused_with_a_message() -> None:
    wb = _wb()
    for k in range(40):
        wb.append(_b("u", k, 50 * k, 50), source="u")
        wb.append(SampleBatch("s", k, T0 + 50 * k * P, 2 * P, None, {}, {"f": np.ones(25)}), source="y")
        assert wb.take() is None
    c = wb.counters()
    assert c["resets"] == {} and c["period_ns"] == P  # u came first and keeps the clock
    assert c["bad"] == {"period_mismatch": 40}
    assert c["last_bad"]["kind"] == "period_mismatch"
    assert c["last_bad"]["message"] == (
        "y batch seq 39 has period_ns=10000000 but u batches have period_ns=5000000; u and y must share one "
        "sample clock (refused until every source agrees)"
    )


def test_a_real_period_change_of_u_and_y_goes_through() -> None:
    wb = _wb()
    t, windows = T0, []
    for k in range(60):
        p = P if k < 30 else 2 * P
        wb.append(SampleBatch("s", k, t, p, None, {"v": np.sin(np.arange(50.0) + k)}, {}), source="u")
        wb.append(SampleBatch("s", k, t, p, None, {}, {"f": np.cos(np.arange(50.0) + k)}), source="y")
        t += 50 * p
        if (w := wb.take()) is not None:
            windows.append(w)
    c = wb.counters()
    assert c["resets"]["period"] == 1 and c["period_ns"] == 2 * P
    assert c["bad"] == {"period_mismatch": 1}  # u's first batch on the new clock, until y follows
    assert windows[-1].period_ns == 2 * P and windows[0].period_ns == P
    assert sum(w.period_ns == 2 * P for w in windows) == 13  # (29 * 50 - 200) // 100 + 1: one u batch lost


def test_a_silent_source_stops_vetoing() -> None:
    wb = _wb()
    for k in range(10):
        wb.append(_b("u", k, 50 * k, 50), source="u")
        wb.append(_b("y", k, 50 * k, 50), source="y")
    for k in range(10, 100):  # y's publisher is gone; u goes on alone on a new clock
        wb.append(_b("u", k, 0, 50, period=3 * P, t0=T0 + k * 50 * 3 * P), source="u")
    c = wb.counters()
    assert c["period_ns"] == 3 * P and c["resets"]["period"] == 1
    assert 1 <= c["bad"]["period_mismatch"] <= 64


def test_an_old_batch_received_again_is_a_duplicate_not_a_restart() -> None:
    wb = _wb()
    for k in range(60):
        wb.append(_b("samples", k, 50 * k, 50))
    assert wb.take() is not None
    wb.append(_b("samples", 5, 250, 50))  # 2750 samples back: far beyond the 500-sample ring
    wb.append(_b("samples", 59, 2950, 50))  # and the newest one again
    c = wb.counters()
    assert c["bad"] == {"duplicate": 2} and c["resets"] == {}
    assert c["last_bad"]["message"] == "samples: batch seq 59 was already received"
    for k in range(60, 64):
        wb.append(_b("samples", k, 50 * k, 50))
    w = wb.take()
    assert w is not None and w.t0_ns == T0 + (64 * 50 - 200) * P  # the stream went on, unbroken


def test_a_restarted_publisher_still_restarts_the_stream() -> None:
    wb = _wb()
    for k in range(100):
        wb.append(_b("samples", k, 50 * k, 50))
    for k in range(10):  # seq and clock from zero again
        wb.append(_b("samples", k, 50 * k, 50, t0=T0 - 10**9))
    c = wb.counters()
    assert c["resets"].get("restart") == 1 and c["bad"] == {}


def test_renaming_inputs_and_outputs_is_one_schema_reset() -> None:
    wb = _wb()
    for k in range(10):
        wb.append(_b("samples", k, 50 * k, 50))
    wb.append(_b("samples", 10, 500, 50, names=("v2", "f2")))
    c = wb.counters()
    assert c["resets"] == {"schema": 1} and c["inputs"] == ["v2"] and c["outputs"] == ["f2"]
    ev = [e.message for e in wb.drain_events() if e.kind == "reset.schema"]
    assert ev == ["s: signals changed from ['v'] to ['v2'] and ['f'] to ['f2']"]


SMALL = StreamConfig(window_s=1.0, update_every_s=0.5, cold_generations=30, warm_generations=10, neurons=5,
                     max_lag_y=3, max_lag_u=3)


def _scaled_window(su: float, sy: float) -> Window:
    dev = get_device("mr_damper")
    _, u, y = dev.simulate_seconds(1.5, seed=0)
    return Window("s", 1, 1, 0, dev.period_ns, ("v",), ("f",), u[:200, None] * su, y[:200, None] * sy, 0, 0)


def test_identification_is_invariant_to_absurd_but_allowed_scales() -> None:
    ref = identify_window(_scaled_window(1.0, 1.0), SMALL, version=1)
    assert ref.kind == "identified" and ref.summary is not None
    for su, sy in ((1e-8, 1e8), (1e6, 1e-6), (1e-50, 1e11)):
        out = identify_window(_scaled_window(su, sy), SMALL, version=1)
        assert out.kind == "identified" and out.summary is not None, (su, sy, out.reason)
        for k, v in ref.summary.metrics.items():
            assert out.summary.metrics[k] == pytest.approx(v, rel=1e-6, abs=1e-9), (su, sy, k)


@pytest.mark.parametrize(("su", "sy", "name"), [(1.0, 1e-300, "output 'f'"), (1e-100, 1.0, "input 'v'")])
def test_signal_too_small_for_float64_is_dropped_with_the_reason(su: float, sy: float, name: str) -> None:
    out = identify_window(_scaled_window(su, sy), SMALL, version=1)
    assert out.kind == "dropped" and out.code == "constant_signal"
    assert f"{name} spans only" in out.reason and "less than 1e-60: too small for float64" in out.reason


def test_output_constant_over_the_validation_part_is_dropped_with_the_reason() -> None:
    w = _scaled_window(1.0, 1.0)
    y = w.y.copy()
    y[-60:] = 3.0  # the newest 30 %: the held-out part
    out = identify_window(Window("s", 1, 1, 0, w.period_ns, ("v",), ("f",), w.u, y, 0, 0), SMALL, version=1)
    assert out.kind == "dropped" and out.reason.startswith("output 'f' is constant over the validation part (3)")
