"""A controller's side of streamid: the served model, run sample by sample on the live samples.

It subscribes to a stream's accepted models (``ModelSubscriber``) and to its samples, feeds every
sample to a :class:`streamid.Predictor`, and swaps each new model in between two samples.  A
model-predictive controller would call ``predictor.forecast(u_plan)`` for its candidate inputs; this
example instead checks, as the samples arrive, what such a forecast was worth: a second predictor runs
``horizon_s`` behind, and once the horizon's inputs are known it forecasts them and compares with the
outputs measured.  Every ``report_s`` of stream time it prints the served version, the one-step
error, the horizon forecasts' R² and the signals beyond the model's estimation range::

    python examples/controller.py --connect tcp/127.0.0.1:7447 --stream mr_damper --seconds 30

(start a daemon and a replay first: ``streamid daemon`` and ``streamid replay mr_damper --rate 4``) prints::

    t     14.60 s  v1    force_N: one-step rms 3.038, 0.2 s forecasts 4, R2 0.9811, beyond range: -

It also prints what the stream's status says bears on trusting the model (``on_event``: a ``drift``,
the served model no longer fitting the incoming data, until a new champion is swapped in; ``degraded``,
``healthy``)::

    mr_damper DRIFT on force_N: the served model v3 no longer fits the incoming data (change estimated at ...

``--json`` prints one JSON object per report, and each event as its ``streamid.status-event/1``
document.  Samples on the stream's ``samples`` key are used (not the split ``u``/``y`` keys).
"""

from __future__ import annotations

import argparse
import json
import queue
import sys
import time
from collections import deque
from typing import Any

import numpy as np

from streamid import Predictor
from streamid.commands.zenoh_flags import add_connection_flags, settings_from_args
from streamid.transport import Bus, ZenohSettings
from streamid.transport.client import ModelSubscriber
from streamid.transport.updates import ModelUpdate
from streamid.errors import CodecError
from streamid.wire.codec import SampleBatch, decode
from streamid.wire.status_events import StatusEvent


class Checker:
    """A live predictor, and one ``horizon`` samples behind whose forecasts are judged once the outputs arrive."""

    def __init__(self, horizon: int) -> None:
        self.horizon = horizon
        self.live: Predictor | None = None
        self.behind: Predictor | None = None
        self.version = 0
        self.delayed: deque[tuple[np.ndarray, float]] = deque(maxlen=horizon)
        self.count = 0
        self.osa_err: list[float] = []
        self.sse = 0.0  # of the forecasts judged since the last report ...
        self.judged: list[np.ndarray] = []  # ... and the outputs they were judged on

    def swap(self, up: ModelUpdate) -> None:
        if self.live is None or self.behind is None:
            self.live, self.behind = Predictor(up.model), Predictor(up.model)
        else:
            self.live.swap(up.model)
            self.behind.swap(up.model)
        self.version = up.version

    def sample(self, u: np.ndarray, y: float) -> None:
        if self.live is None or self.behind is None:
            return
        if self.live.ready:
            self.osa_err.append(y - self.live.predict_one())
        self.live.learn_one(u, y)
        if len(self.delayed) == self.horizon:
            self.count += 1
            if self.behind.ready and self.count % self.horizon == 0:  # one forecast per horizon, back to back
                plan = np.array([d[0] for d in self.delayed])
                measured = np.array([d[1] for d in self.delayed])
                got = self.behind.forecast(plan)  # from `horizon` samples ago, for the inputs that then came
                self.sse += float(np.sum((measured - got) ** 2))
                self.judged.append(measured)
            self.behind.learn_one(*self.delayed[0])
        self.delayed.append((u, y))

    def report(self, t_s: float) -> dict[str, Any]:
        """The figures since the last report: one-step RMS error, and the forecasts' R² (their squared errors
        summed over the outputs' spread about the period's mean)."""
        y = np.concatenate(self.judged) if self.judged else np.empty(0)
        sst = float(np.sum((y - y.mean()) ** 2)) if y.size else 0.0
        out = {"t_s": round(t_s, 3), "version": self.version,
               "output": self.live.model.output_name if self.live is not None else None,
               "osa_rms": float(np.sqrt(np.mean(np.square(self.osa_err)))) if self.osa_err else None,
               "forecasts": len(self.judged), "forecast_r2": 1.0 - self.sse / sst if sst > 0 else None,
               "beyond_range": list(self.live.beyond_range()) if self.live is not None else []}
        self.osa_err, self.sse, self.judged = [], 0.0, []
        return out


def report_line(r: dict[str, Any], horizon_s: float) -> str:
    """One report as a line of text (``--json`` prints ``r`` itself)."""
    def num(v: float | None, form: str) -> str:
        return "-" if v is None else format(v, form)

    return (f"t {r['t_s']:9.2f} s  v{r['version']:<4d} {r['output']}: one-step rms {num(r['osa_rms'], '.4g')}, "
            f"{horizon_s:g} s forecasts {r['forecasts']}, R2 {num(r['forecast_r2'], '.4f')}, beyond range: "
            f"{', '.join(r['beyond_range']) or '-'}")


def main(settings: ZenohSettings, stream: str, *, output: str | None = None, horizon_s: float = 0.2,
         report_s: float = 1.0, seconds: float = 30.0, as_json: bool = False) -> int:
    """Follow ``stream``'s served model (of ``output``; default: the first model's) for ``seconds`` of wall time;
    0 if any forecast was judged, else 1."""
    events: queue.Queue[tuple[str, Any]] = queue.Queue(maxsize=10_000)  # Zenoh threads -> this loop, bounded

    def put(item: tuple[str, Any]) -> None:  # on a Zenoh thread: never block it
        try:
            events.put_nowait(item)
        except queue.Full:
            dropped[0] += 1

    dropped = [0]
    follow = [output]  # None: the first model's output

    def on_model(up: ModelUpdate) -> None:
        if follow[0] is None:
            follow[0] = up.output
        if up.output == follow[0]:
            put(("model", up))

    checker: Checker | None = None
    pending: list[ModelUpdate] = []
    judged, next_report_ns = 0, None
    with Bus(settings) as bus, ModelSubscriber(bus, stream, on_model, on_event=lambda ev: put(("event", ev))):
        bus.subscribe(f"streamid/{stream}/samples", lambda _k, p: put(("samples", p)))
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            try:
                kind, item = events.get(timeout=0.2)
            except queue.Empty:
                continue
            if kind == "model":
                pending.append(item)  # swapped in before the next batch's samples
                continue
            if kind == "event":  # a controller would hold back on a drifted model until the next one
                ev: StatusEvent = item
                print(json.dumps(ev.to_dict()) if as_json else ev.text(), flush=True)
                continue
            try:
                batch: SampleBatch = decode(item)
            except CodecError as e:
                print(f"skipped a batch that is not a sample batch: {e}", file=sys.stderr)
                continue
            for up in pending:
                if checker is None:
                    checker = Checker(max(1, round(horizon_s * 1e9 / max(1, batch.period_ns))))
                checker.swap(up)
            pending = []
            if checker is None or checker.live is None:
                continue
            m = checker.live.model
            if m.output_name not in batch.outputs or any(n not in batch.inputs for n in m.input_names):
                continue
            u = np.column_stack([batch.inputs[n] for n in m.input_names])
            y = batch.outputs[m.output_name]
            t = batch.times_ns()
            for k in range(len(y)):
                checker.sample(u[k], float(y[k]))
                if next_report_ns is None:
                    next_report_ns = int(t[k]) + int(report_s * 1e9)
                elif t[k] >= next_report_ns:
                    r = checker.report(t[k] / 1e9)
                    judged += r["forecasts"]
                    next_report_ns += int(report_s * 1e9)
                    if as_json:
                        print(json.dumps(r), flush=True)
                    else:
                        print(report_line(r, horizon_s), flush=True)
    if dropped[0]:
        print(f"{dropped[0]} messages dropped: this loop fell behind (the queue holds 10,000)", file=sys.stderr)
    return 0 if judged else 1


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_connection_flags(parser, default_connect=("tcp/127.0.0.1:7447",))
    parser.add_argument("--stream", required=True)
    parser.add_argument("--output", default=None, help="the output to follow (default: every model of the stream)")
    parser.add_argument("--horizon-s", type=float, default=0.2)
    parser.add_argument("--report-s", type=float, default=1.0)
    parser.add_argument("--seconds", type=float, default=30.0, help="wall time to run")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    sys.exit(main(settings_from_args(args), args.stream, output=args.output, horizon_s=args.horizon_s,
                  report_s=args.report_s, seconds=args.seconds, as_json=args.json))
