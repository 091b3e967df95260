"""``streamid router``: a real router process; two client-mode sessions meet only through it."""

from __future__ import annotations

import signal
import socket
import subprocess
import threading
import time

from conftest import STREAMID, endpoint
from streamid.transport import Bus, ZenohSettings


def test_clients_talk_through_the_router_process_and_it_stops_on_sigint() -> None:
    ep = endpoint()
    proc = subprocess.Popen([*STREAMID, "router", "--listen", ep], stderr=subprocess.PIPE, text=True)
    try:
        client = ZenohSettings(mode="client", connect=(ep,))
        got: list[bytes] = []
        arrived = threading.Event()

        def on_sample(key: str, payload: bytes) -> None:
            got.append(payload)
            if len(got) == 50:
                arrived.set()

        port = int(ep.rsplit(":", 1)[1])
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:  # a client-mode session needs the router up
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
                break
            except OSError:
                time.sleep(0.05)
        with Bus(client) as sub_bus, Bus(client) as pub_bus:
            sub_bus.subscribe("streamid/r/samples", on_sample)
            pub = pub_bus.publisher("streamid/r/samples")
            deadline = time.monotonic() + 15.0
            while not pub.has_subscribers() and time.monotonic() < deadline:
                time.sleep(0.05)
            assert pub.has_subscribers(), "subscriber never became visible through the router"
            for i in range(50):
                pub.put(i.to_bytes(4, "little"))
            assert arrived.wait(10.0), f"only {len(got)} of 50 messages crossed the router"
        assert [int.from_bytes(p, "little") for p in got] == list(range(50))
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 0
        assert "router mode" in proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
