"""Zenoh transport over real loopback sessions; settings and flags; stream keys."""

from __future__ import annotations

import argparse
import json
import threading
import time

import pytest

from conftest import endpoint
from streamid.wire import keys
from streamid.errors import ConfigError, TransportError
from streamid.commands.zenoh_flags import add_connection_flags, settings_from_args
from streamid.transport import DEFAULT_ENDPOINT, Bus, ZenohSettings


def _wait(pred, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.01)
    return pred()


def test_pub_sub_bytes_in_order_nothing_lost(bus_pair: tuple[Bus, Bus]) -> None:
    a, b = bus_pair
    got: list[tuple[str, bytes]] = []
    lock = threading.Lock()

    def on(key: str, payload: bytes) -> None:
        with lock:
            got.append((key, payload))

    a.subscribe("streamid/**", on)
    pub = b.publisher("streamid/dev/samples")
    assert pub.wait_for_subscribers(5.0)
    sent = [i.to_bytes(4, "little") * 100 for i in range(5000)]
    for p in sent:
        pub.put(p)
    assert _wait(lambda: len(got) == len(sent))
    assert all(k == "streamid/dev/samples" for k, _ in got)
    assert [p for _, p in got] == sent  # BLOCK congestion control: all, in order
    assert all(isinstance(p, bytes) for _, p in got)


def test_callback_exception_does_not_stop_the_subscription(bus_pair: tuple[Bus, Bus]) -> None:
    a, b = bus_pair
    got: list[bytes] = []

    def on(key: str, payload: bytes) -> None:
        if payload == b"boom":
            raise RuntimeError("boom")
        got.append(payload)

    a.subscribe("streamid/x/*", on)
    pub = b.publisher("streamid/x/u")
    assert pub.wait_for_subscribers(5.0)
    for p in (b"1", b"boom", b"2"):
        pub.put(p)
    assert _wait(lambda: got == [b"1", b"2"])


def test_queryable_and_get(bus_pair: tuple[Bus, Bus]) -> None:
    a, b = bus_pair
    a.queryable("streamid/dev/model", lambda key: b'{"model": 1}')
    a.queryable("streamid/other/model", lambda key: None)  # no reply
    replies: list = []
    assert _wait(lambda: bool(replies.extend(b.get("streamid/*/model", 0.5)) or replies))
    assert replies[0] == ("streamid/dev/model", b'{"model": 1}')
    assert all(k != "streamid/other/model" for k, _ in replies)


def test_unsubscribe_and_close(bus_pair: tuple[Bus, Bus]) -> None:
    a, b = bus_pair
    got: list[bytes] = []
    h = a.subscribe("streamid/**", lambda k, p: got.append(p))
    pub = b.publisher("streamid/a/y")
    assert pub.wait_for_subscribers(5.0)
    h.close()
    assert _wait(lambda: not pub.has_subscribers())
    pub.put(b"x")
    time.sleep(0.1)
    assert got == []
    b.close()
    b.close()  # idempotent
    with pytest.raises(TransportError, match="closed"):
        b.publisher("streamid/a/y")


def test_invalid_key_expressions_raise_transport_error(bus_pair: tuple[Bus, Bus]) -> None:
    a, _ = bus_pair
    with pytest.raises(TransportError, match="key expression"):
        a.subscribe("streamid//bad", lambda k, p: None)
    with pytest.raises(TransportError, match="publisher"):
        a.publisher("streamid/*/samples/**/x//")
    with pytest.raises(TypeError, match="bytes"):
        a.publisher("streamid/a/samples").put("text")  # type: ignore[arg-type]


def test_listen_endpoint_in_use_is_a_transport_error(zenoh_listen: ZenohSettings) -> None:
    with Bus(zenoh_listen):
        with pytest.raises(TransportError) as err:
            Bus(zenoh_listen)
    text = str(err.value)  # one sentence: the endpoint, the cause and the flag that changes it; no Rust source path
    assert text.startswith(f"cannot listen on {zenoh_listen.listen[0]}: the address is already in use")
    assert "--listen" in text and ".rs" not in text and "\n" not in text


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"mode": "server"}, "mode must be one of"),
        ({"connect": ("127.0.0.1:7447",)}, "Zenoh locator"),
        ({"listen": ("http/127.0.0.1:7447",)}, "protocol must be one of"),
        ({"config_file": "/nonexistent/zenoh.json5"}, "existing JSON5 file"),
    ],
)
def test_settings_validation(kwargs: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        ZenohSettings(**kwargs)


def test_config_file_is_used(tmp_path) -> None:
    ep = endpoint()
    cfg = tmp_path / "z.json5"
    cfg.write_text('{ mode: "peer", listen: { endpoints: ["%s"] }, '
                   'scouting: { multicast: { enabled: false } } }' % ep)
    with Bus(ZenohSettings(config_file=str(cfg))) as a, Bus(ZenohSettings(connect=(ep,))) as b:
        got: list[bytes] = []
        a.subscribe("k/**", lambda k, p: got.append(p))
        pub = b.publisher("k/1")
        assert pub.wait_for_subscribers(5.0)
        pub.put(b"via config file")
        assert _wait(lambda: got == [b"via config file"])
    bad = tmp_path / "bad.json5"
    bad.write_text("{ not_a_zenoh_key: 1 }")
    with pytest.raises(TransportError):
        Bus(ZenohSettings(config_file=str(bad)))


def test_connection_flags() -> None:
    p = argparse.ArgumentParser()
    add_connection_flags(p, default_connect=(DEFAULT_ENDPOINT,))
    s = settings_from_args(p.parse_args([]))
    assert s == ZenohSettings(connect=(DEFAULT_ENDPOINT,), connect_wait_s=None)  # a command waits until stopped
    assert s.resolved_mode() == "client"  # connects, listens nowhere
    assert settings_from_args(p.parse_args(["--connect-wait", "3"])).connect_wait_s == 3.0
    with pytest.raises(SystemExit):
        p.parse_args(["--connect-wait", "-1"])
    s = settings_from_args(p.parse_args(["--listen", "tcp/127.0.0.1:1", "--listen", "tcp/127.0.0.1:2"]))
    assert s.listen == ("tcp/127.0.0.1:1", "tcp/127.0.0.1:2") and s.connect == ()
    s = settings_from_args(p.parse_args(["--mode", "client", "--connect", "tcp/127.0.0.1:3",
                                         "--multicast-scouting"]))
    assert (s.mode, s.connect, s.multicast_scouting) == ("client", ("tcp/127.0.0.1:3",), True)
    with pytest.raises(SystemExit):
        p.parse_args(["--mode", "server"])


def test_keys() -> None:
    assert keys.samples_key("piezo") == "streamid/piezo/samples"
    assert keys.u_key("a") == "streamid/a/u" and keys.y_key("a") == "streamid/a/y"
    assert keys.model_key("a") == "streamid/a/model" and keys.status_key("a") == "streamid/a/status"
    assert keys.parse_key("streamid/mr_damper-2.v1/y") == ("mr_damper-2.v1", "y")
    for bad in ("streamid/a", "other/a/u", "streamid/a/b/u", "streamid/a/unknown", "streamid/*/u",
                "streamid/../u", "streamid//u"):
        with pytest.raises(ConfigError):
            keys.parse_key(bad)
    for bad in ("", "a/b", "a*", "x" * 129, "é", ".."):
        with pytest.raises(ConfigError, match="stream name must be"):
            keys.samples_key(bad)


def test_config_file_mode_is_kept_unless_mode_flag_given(tmp_path) -> None:
    cfg = tmp_path / "z.json5"
    cfg.write_text('{ mode: "client", connect: { endpoints: ["tcp/127.0.0.1:1"] } }')
    p = argparse.ArgumentParser()
    add_connection_flags(p, default_connect=(DEFAULT_ENDPOINT,))
    s = settings_from_args(p.parse_args(["--zenoh-config", str(cfg)]))
    assert s.mode is None and s.connect == () and s.config_file == str(cfg)
    assert json.loads(s.to_config().get_json("mode")) == "client"
    assert json.loads(s.to_config().get_json("connect/endpoints")) == ["tcp/127.0.0.1:1"]
    s = settings_from_args(p.parse_args(["--zenoh-config", str(cfg), "--mode", "peer"]))
    assert json.loads(s.to_config().get_json("mode")) == "peer"


def test_config_file_without_listen_or_scouting_stays_on_loopback(tmp_path) -> None:
    """A file that says nothing about listening or scouting must not get Zenoh's
    defaults (every interface, multicast on): streamid listens nowhere and scouts not."""
    bare = tmp_path / "bare.json5"
    bare.write_text('{ mode: "peer" }')
    conf = ZenohSettings(mode=None, config_file=str(bare)).to_config()
    assert json.loads(conf.get_json("listen/endpoints")) == []
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    explicit = tmp_path / "explicit.json5"
    explicit.write_text(
        '{ mode: "peer", listen: { endpoints: ["tcp/127.0.0.1:7999"] },'
        ' scouting: { multicast: { enabled: true } } }'
    )
    conf = ZenohSettings(mode=None, config_file=str(explicit)).to_config()
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7999"]
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is True


def test_sessions_leave_nothing_in_dev_shm_even_after_os_exit(zenoh_endpoint: str) -> None:
    """Zenoh's shared-memory pools (16 MiB each) are off: a CLI process leaving with os._exit left them behind."""
    import os
    import subprocess
    import sys

    assert ZenohSettings().to_config().get_json("transport/shared_memory/enabled") == "false"
    on = ZenohSettings(extra=(("transport/shared_memory/enabled", "true"),))
    assert on.to_config().get_json("transport/shared_memory/enabled") == "true"  # still possible, explicitly
    if not os.path.isdir("/dev/shm"):
        pytest.skip("no /dev/shm here")
    code = (
        "import json, os, sys\n"
        "from streamid.transport import Bus, ZenohSettings\n"
        f"b = Bus(ZenohSettings(listen=({zenoh_endpoint!r},)))\n"
        "b.put('streamid/shm/samples', bytes(16000))\n"
        "print(json.dumps(sorted(os.listdir('/dev/shm'))), flush=True)\n"
        "b.close()\n"
        "os._exit(0)\n"
    )
    before = set(os.listdir("/dev/shm"))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    during = {n for n in json.loads(out.stdout.strip().splitlines()[-1]) if n.endswith(".zenoh")}
    after = {n for n in os.listdir("/dev/shm") if n.endswith(".zenoh")} - before
    assert not (during - before), f"zenoh mapped shared memory: {sorted(during - before)}"
    assert not after, f"left behind in /dev/shm: {sorted(after)}"


def test_default_mode_is_client_for_a_process_that_only_connects() -> None:
    assert ZenohSettings(connect=("tcp/127.0.0.1:1",)).resolved_mode() == "client"
    assert ZenohSettings(listen=("tcp/127.0.0.1:1",)).resolved_mode() == "peer"
    assert ZenohSettings(connect=("tcp/127.0.0.1:1",), listen=("tcp/127.0.0.1:2",)).resolved_mode() == "peer"
    assert ZenohSettings().resolved_mode() == "peer"
    assert ZenohSettings(mode="peer", connect=("tcp/127.0.0.1:1",)).resolved_mode() == "peer"
    with pytest.raises(ConfigError, match="connect_wait_s must be"):
        ZenohSettings(connect_wait_s=-1.0)


def test_two_default_sessions_meet_through_a_router_they_both_connect_to() -> None:
    """The README's several-machines recipe: nobody listens but the router (peers never met there)."""
    ep = endpoint()
    with Bus(ZenohSettings(mode="router", listen=(ep,))):
        with Bus(ZenohSettings(connect=(ep,))) as a, Bus(ZenohSettings(connect=(ep,))) as b:
            got: list[bytes] = []
            b.subscribe("streamid/t/samples", lambda _k, p: got.append(p))
            pub = a.publisher("streamid/t/samples")
            assert pub.wait_for_subscribers(5.0)
            pub.put(b"through the router")
            assert _wait(lambda: got == [b"through the router"])


def test_a_client_from_a_config_file_waits_for_its_router_too(tmp_path) -> None:
    ep = endpoint()
    cfg = tmp_path / "client.json5"
    cfg.write_text('{ mode: "client", connect: { endpoints: ["%s"] } }' % ep)
    t0 = time.monotonic()
    with pytest.raises(TransportError, match="cannot connect"):
        Bus(ZenohSettings(config_file=str(cfg), connect_wait_s=0.6))
    assert time.monotonic() - t0 >= 0.5  # the file's client mode retried, like --mode client


def test_a_client_waits_for_a_late_router_and_stop_ends_the_wait() -> None:
    ep = endpoint()
    t0 = time.monotonic()
    with pytest.raises(TransportError, match="cannot connect to"):
        Bus(ZenohSettings(connect=(ep,), connect_wait_s=0.6))
    assert 0.5 <= time.monotonic() - t0  # it retried for its bound (at least), then said why
    stop = threading.Event()
    t0 = time.monotonic()  # before the timer starts: the wait is measured from no later than the timer's own start
    threading.Timer(0.7, stop.set).start()
    with pytest.raises(TransportError):
        Bus(ZenohSettings(connect=(ep,), connect_wait_s=None), stop=stop)
    assert stop.is_set() and time.monotonic() - t0 >= 0.7  # it waited (no bound) until stop ended the wait
    holder: list[Bus] = []
    threading.Timer(1.0, lambda: holder.append(Bus(ZenohSettings(mode="router", listen=(ep,))))).start()
    try:
        with Bus(ZenohSettings(connect=(ep,), connect_wait_s=20.0)) as late:
            assert _wait(lambda: bool(holder)) and late.routers()  # opened once the router was up, connected to it
    finally:
        for b in holder:
            b.close()
