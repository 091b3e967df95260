"""The publishing side of tests/test_daemon_bounds.py, in its own process (so the test process's RSS is the daemon's).

``python tests/bounds_peer.py ENDPOINT PLAN_JSON``: a healthy stream (the simulated MR damper,
20-sample batches in real time) for ``plan["seconds"]``, and at the planned times the attacks:
``wide_refused`` (batches of 2,000 channels), ``wide`` (batches within the channel bound, in real
time), ``payloads`` (junk payloads of the given sizes on the given keys).  Prints one JSON line.
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
    B = 20
    rng = np.random.default_rng(0)
    sent = {"healthy": 0, "wide_refused": 0, "wide": 0, "payloads": 0}
    with Bus(ZenohSettings(connect=(ep,))) as bus:
        healthy = bus.publisher("streamid/healthy/samples")
        wide = bus.publisher("streamid/wide/samples")
        if not (healthy.wait_for_subscribers(10.0) and wide.wait_for_subscribers(10.0)):
            sys.exit("no daemon subscribed")
        t0 = time.monotonic()
        k = wk = 0
        done_refused = done_payloads = False
        while (now := time.monotonic() - t0) < seconds:
            while k * B * period / 1e9 <= now and (k + 1) * B <= len(y):  # healthy, real time
                i = k * B
                healthy.put(encode(SampleBatch("healthy", k, i * period, period, None,
                                               {"v": u[i:i + B]}, {"f": y[i:i + B]})))
                k += 1
                sent["healthy"] += 1
            a, b = plan["wide_from_s"], plan["wide_to_s"]
            if a <= now < b and not done_refused:  # the attack: 10 batches x 100 samples x 2,000 channels
                for j in range(10):
                    ins = {f"u{c}": rng.standard_normal(100) for c in range(1999)}
                    wide.put(encode(SampleBatch("wide", 1_000_000 + j, j * 100 * period, period, None, ins,
                                                {"y": rng.standard_normal(100)})))
                    sent["wide_refused"] += 1
                done_refused = True
            n_wide = plan["wide_channels"] - 1
            while a <= now < b and a + wk * 100 * period / 1e9 <= now:  # within the bound, in real time
                ins = {f"u{c}": rng.standard_normal(100) for c in range(n_wide)}
                wide.put(encode(SampleBatch("wide", wk, (wk * 100) * period, period, None, ins,
                                            {"y": rng.standard_normal(100)})))
                wk += 1
                sent["wide"] += 1
            if now >= plan["payloads_at_s"] and not done_payloads:
                for key, size in plan["payloads"]:
                    bus.put(key, bytes(size))
                    sent["payloads"] += 1
                done_payloads = True
            time.sleep(0.002)
    print(json.dumps(sent))


if __name__ == "__main__":
    from streamid.commands.main import leave

    main()
    leave(0)  # as the streamid command leaves (streamid.commands.main.console_main: why)
