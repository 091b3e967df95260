"""The model client: an endpoint string is enough, and "no daemon" is told apart from "no model yet".

Real Zenoh sessions on loopback (explicit tcp/127.0.0.1 endpoints, multicast off); the model is
served by a real queryable with a real model-update document.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from conftest import endpoint
from streamid.model import Model
from streamid.model.regressors import Normalisation, Regressor
from streamid.errors import ConfigError, NoDaemonError, NoModelYetError
from streamid.transport import Bus, ZenohSettings
from streamid.transport.client import ModelSubscriber, latest_model
from streamid.wire.documents import encode_json, model_update_message


def _model() -> Model:
    rng = np.random.default_rng(0)
    return Model(
        regressors=(Regressor("y", 0, 1), Regressor("u", 0, 1), Regressor("u", 0, 2)),
        centres=rng.uniform(-1, 1, (3, 3)), widths=np.ones(3), weights=rng.normal(size=3),
        normalisation=Normalisation((-1.0,), (1.0,), -2.0, 2.0), input_names=("volt",), output_name="um",
    )


def _update(version: int) -> bytes:
    now = time.time_ns()
    return encode_json(model_update_message(
        stream="piezo", version=version, model=_model().to_dict(), window={"n_samples": 100},
        metrics={"r2_osa_val": 0.99, "r2_fr_val": 0.95}, warm=False, generations=10, identification_s=0.1,
        window_closed_unix_ns=now, published_unix_ns=now,
    ))


def test_nothing_listening_is_no_daemon_naming_the_endpoint() -> None:
    ep = endpoint()
    with pytest.raises(NoDaemonError, match=f"no daemon reachable at {ep}"):
        latest_model(ep, "piezo", timeout_s=0.3)
    assert latest_model(ep, "piezo", timeout_s=0.3, default=None) is None


def test_a_reachable_network_without_the_model_is_no_model_yet() -> None:
    ep = endpoint()
    with Bus(ZenohSettings(listen=(ep,))):
        with pytest.raises(NoModelYetError, match="no model of stream 'piezo' yet at " + ep):
            latest_model(ep, "piezo", timeout_s=0.5)


def test_endpoint_string_gets_the_model_and_subscribes() -> None:
    ep = endpoint()
    with Bus(ZenohSettings(listen=(ep,))) as server:
        server.queryable("streamid/piezo/model", lambda _key: _update(3))
        up = latest_model(ep, "piezo", timeout_s=3.0)
        assert up is not None and up.version == 3
        assert up.model.lags_text() == "um(t-1) volt(t-1,t-2)"
        got: list[int] = []
        with ModelSubscriber(ep, "piezo", lambda u: got.append(u.version), latest_timeout_s=2.0) as sub:
            pub = server.publisher("streamid/piezo/model")
            pub.wait_for_subscribers(5.0)
            pub.put(_update(4))
            assert sub.wait_for_version(4, timeout_s=5.0) is not None
        assert got[-1] == 4 and 3 in got
    with pytest.raises(ConfigError, match="Zenoh locator"):
        latest_model("127.0.0.1:7447", "piezo")
    with pytest.raises(ConfigError, match="endpoint string such as 'tcp/127.0.0.1:7447'"):
        latest_model(7447, "piezo")  # type: ignore[arg-type]


def test_latest_model_reads_a_bounded_part_of_a_flood_of_replies(caplog: pytest.LogCaptureFixture) -> None:
    """2,000 replies of 512 KiB (1 GiB) next to the genuine model: at most 64 MiB read, the rest counted as
    ``query_bound`` and warned; the heap's peak stays far below the flood (was: every reply copied first)."""
    import logging
    import tracemalloc

    from streamid.transport.client import MODEL_QUERY_MAX_BYTES

    junk = b"x" * (512 * 1024)
    ep = endpoint()
    with Bus(ZenohSettings(listen=(ep,))) as server, Bus(ZenohSettings(connect=(ep,))) as client:
        server.queryable("streamid/piezo/model", lambda _k: [_update(3)])
        server.queryable("streamid/piezo/model", lambda _k: [junk] * 2000)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and len(client.get("streamid/piezo/model", 0.5, all_replies=True,
                                                             max_replies=2, max_bytes=1 << 20)) < 2:
            time.sleep(0.05)  # both declarations arrived
        tracemalloc.start()
        try:
            with caplog.at_level(logging.WARNING, logger="streamid.transport.client"):
                up = latest_model(client, "piezo", timeout_s=3.0, default=None)
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
    assert "(query_bound)" in caplog.text and "dropped unread" in caplog.text, caplog.text
    assert peak < MODEL_QUERY_MAX_BYTES + 64 * 1024 * 1024, f"peak {peak / 2**20:.0f} MiB"
    # the genuine model is read when it comes before the bound (Zenoh's order), never a crash either way
    assert up is None or up.version == 3
