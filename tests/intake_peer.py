"""The publishing side of tests/test_fair_intake.py, in its own process.

``python tests/intake_peer.py ENDPOINT PLAN_JSON``: the simulated MR damper on ``streamid/damper/samples``
(20-sample batches, real time, 200 Hz) for ``plan["seconds"]``, and ``plan["small"]`` small publishers on
``streamid/small<i>/samples``, each putting 1-sample batches at ``plan["rate_hz"]`` (in bursts every 10 ms),
from ``plan["small_from_s"]`` on.  Prints one JSON line: what was sent.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

from streamid.sim import get_device
from streamid.transport import Bus, ZenohSettings
from streamid.wire.codec import SampleBatch, encode


def main() -> None:
    ep, plan = sys.argv[1], json.loads(sys.argv[2])
    dev = get_device("mr_damper")
    period = dev.period_ns
    seconds = float(plan["seconds"])
    _, u, y = dev.simulate_seconds(seconds + 1.0, seed=3)
    small_n, rate, small_from = int(plan["small"]), float(plan["rate_hz"]), float(plan["small_from_s"])
    small_period = int(1e9 / rate)
    B = 20
    rng = np.random.default_rng(0)
    sent = {"damper": 0, "small": 0}
    with Bus(ZenohSettings(mode="client", connect=(ep,))) as bus:
        damper = bus.publisher("streamid/damper/samples")
        smalls = [bus.publisher(f"streamid/small{i}/samples", block=False) for i in range(small_n)]
        if not damper.wait_for_subscribers(20.0):
            sys.exit("no daemon subscribed")
        # one payload per small stream and sequence number, made ahead (the publisher's time goes to putting)
        xs = rng.standard_normal(4096)
        t0 = time.monotonic()
        k = 0
        ks = 0
        while (now := time.monotonic() - t0) < seconds:
            while k * B * period / 1e9 <= now and (k + 1) * B <= len(y):  # the damper, real time
                i = k * B
                damper.put(encode(SampleBatch("damper", k, i * period, period, None,
                                              {"velocity": u[i:i + B]}, {"force": y[i:i + B]})))
                k += 1
                sent["damper"] += 1
            while now >= small_from and small_from + ks / rate <= now:  # every small stream, one sample each
                x = xs[ks % len(xs)]
                for i, pub in enumerate(smalls):
                    pub.put(encode(SampleBatch(f"small{i}", ks, ks * small_period, small_period, None,
                                               {"u": np.array([x])}, {"y": np.array([0.5 * x + 0.01 * i])})))
                sent["small"] += small_n
                ks += 1
            time.sleep(0.002)
    print(json.dumps(sent), flush=True)


if __name__ == "__main__":
    main()
