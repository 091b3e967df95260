"""Security: the secured Zenoh configurations of ``examples/zenoh/`` and the source code.

Real Zenoh sessions on loopback (explicit ``tcp/127.0.0.1:PORT`` / ``tls/127.0.0.1:PORT``
endpoints, multicast scouting off) using the shipped JSON5 files, with only the
endpoints and file paths replaced:

- a daemon-like listener (``examples/zenoh/daemon.json5``: user/password
  authentication + access control, default deny) serves a stream the way the
  daemon does (subscribes ``streamid/*/*``, publishes and answers ``.../model``);
- authenticated sensor / analyst / recorder / daemon identities get through with
  exactly the rights their role has;
- a session with wrong credentials (wrong password, unknown user, none) receives
  nothing while a correct one does, and nothing it publishes reaches the listener;
- the same rules in a router (``router.json5``) with the daemon behind it
  (``daemon-via-router.json5``);
- the real ``streamid daemon --zenoh-config examples/zenoh/daemon.json5`` fed by
  ``streamid replay`` as the sensor;
- the TLS variant (``examples/zenoh/tls/``) with certificates generated at test time
  by ``examples/zenoh/make-test-certs.sh`` (openssl).

Every wait is bounded in time.  Static checks (no unpickling, loopback defaults) are
in ``test_security_static.py``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from conftest import endpoint, require
from test_security_static import is_loopback_endpoint
from streamid.errors import TransportError
from streamid.transport import Bus, ZenohSettings

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples" / "zenoh"
CREDENTIALS = EXAMPLES / "credentials.txt"

#: Upper bound of every wait for something that must arrive.
ARRIVE_S = 10.0
#: How long traffic keeps flowing after the correct party got its messages, to
#: give anything that should NOT arrive every chance to arrive.
GRACE_S = 0.5


# --------------------------------------------------------------------------- helpers
def _j(value: object) -> str:
    return json.dumps(value)


def _settings(
    name: str,
    *,
    listen: tuple[str, ...] = (),
    connect: tuple[str, ...] = (),
    mode: str | None = None,
    extra: tuple[tuple[str, str], ...] = (),
) -> ZenohSettings:
    """Settings from a shipped config, with the test's loopback endpoints and absolute paths.

    Only what must differ in a test is replaced: the endpoints (fresh ports), the
    credentials dictionary path (absolute, so the test does not depend on the cwd),
    multicast scouting (forced off, as the files already say) and ``extra``.
    """
    path = EXAMPLES / name
    base = ZenohSettings(mode=None, config_file=str(path)).to_config()
    forced: list[tuple[str, str]] = [("scouting/multicast/enabled", "false")]
    if json.loads(base.get_json("transport/auth/usrpwd/dictionary_file")) is not None:
        forced.append(("transport/auth/usrpwd/dictionary_file", _j(str(CREDENTIALS))))
    if not listen:  # a daemon config used as a connecting identity listens nowhere
        forced.append(("listen/endpoints", "[]"))
    return ZenohSettings(
        mode=mode, listen=listen, connect=connect, config_file=str(path),
        extra=tuple(forced) + tuple(extra),
    )


class Inbox:
    """Thread-safe record of ``(key, payload)`` received by a subscription callback."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._items: list[tuple[str, bytes]] = []

    def __call__(self, key: str, payload: bytes) -> None:
        with self._cond:
            self._items.append((key, payload))
            self._cond.notify_all()

    def items(self) -> list[tuple[str, bytes]]:
        with self._cond:
            return list(self._items)

    def count(self, prefix: bytes) -> int:
        """How many payloads start with ``prefix``."""
        return sum(1 for _, p in self.items() if p.startswith(prefix))


def _pump(put: Callable[[], None], done: Callable[[], bool], timeout_s: float = ARRIVE_S) -> bool:
    """Call ``put()`` every 20 ms until ``done()`` or ``timeout_s``; then ``GRACE_S`` more puts.

    Returns whether ``done()`` became true.  Bounded in time and in count.
    """
    period = 0.02
    deadline = time.monotonic() + timeout_s
    ok = False
    for _ in range(int(timeout_s / period) + 1):
        put()
        if done():
            ok = True
            break
        if time.monotonic() >= deadline:
            break
        time.sleep(period)
    grace_end = time.monotonic() + GRACE_S
    for _ in range(int(GRACE_S / period) + 1):
        if time.monotonic() >= grace_end:
            break
        put()
        time.sleep(period)
    return ok


def _counter_put(bus: Bus, key: str, prefix: bytes) -> Callable[[], None]:
    """A ``put()`` publishing ``prefix + n`` on ``key`` (n counting up)."""
    pub = bus.publisher(key)
    n = iter(range(10**9))
    return lambda: pub.put(prefix + str(next(n)).encode())


@dataclass
class DaemonLike:
    """A listener with the daemon's Zenoh config doing what the daemon does on the bus."""

    bus: Bus
    endpoint: str
    inbox: Inbox  # everything received on streamid/*/* (the daemon's subscription)
    _served: dict[str, bytes] = field(default_factory=dict)

    def serve(self, stream: str) -> Callable[[], None]:
        """Declare ``streamid/<stream>/model`` publisher + queryable; return a model ``put()``."""
        key = f"streamid/{stream}/model"
        self._served[stream] = b"model-of-" + stream.encode()
        self.bus.queryable(key, lambda _k: self._served[stream])
        return _counter_put(self.bus, key, b"model-of-" + stream.encode() + b"#")


@pytest.fixture(scope="module")
def daemon() -> Iterator[DaemonLike]:
    ep = endpoint()
    bus = Bus(_settings("daemon.json5", listen=(ep,)))
    try:
        inbox = Inbox()
        bus.subscribe("streamid/*/*", inbox)  # exactly the daemon's discovery subscription
        yield DaemonLike(bus, ep, inbox)
    finally:
        bus.close()


def _client(name: str, daemon: DaemonLike, **kw: object) -> Bus:
    return Bus(_settings(name, connect=(daemon.endpoint,), **kw))  # type: ignore[arg-type]


def _refused(settings: ZenohSettings) -> Bus:
    """Open a session that must be refused: a client retries a refused open for ``connect_wait_s`` (10 s by
    default, for a daemon still starting); 1 s here, since the listener is up. The refusal is the same."""
    return Bus(dataclasses.replace(settings, connect_wait_s=1.0))


def _credentials() -> dict[str, str]:
    pairs = [line.split(":", 1) for line in CREDENTIALS.read_text().splitlines() if line.strip()]
    return {u: p for u, p in pairs}


# --------------------------------------------------------------------------- the shipped files
ALL_CONFIGS = sorted(p.relative_to(EXAMPLES).as_posix() for p in EXAMPLES.rglob("*.json5"))


def test_the_examples_exist() -> None:
    assert {"daemon.json5", "sensor.json5", "analyst.json5", "recorder.json5", "router.json5",
            "daemon-via-router.json5", "tls/daemon.json5", "tls/sensor.json5",
            "tls/analyst.json5"} <= set(ALL_CONFIGS)


@pytest.mark.parametrize("name", ALL_CONFIGS)
def test_example_config_is_accepted_by_zenoh_and_stays_on_loopback(name: str) -> None:
    # Zenoh refuses unknown keys and wrong values when the file is loaded (ZError ->
    # TransportError), so loading checks every key against the installed Zenoh; the
    # live tests below also open a session with every file (which checks the rest,
    # e.g. that policies name existing rules, and that the certificates load).
    conf = ZenohSettings(mode=None, config_file=str(EXAMPLES / name)).to_config()
    listen = json.loads(conf.get_json("listen/endpoints"))
    connect = json.loads(conf.get_json("connect/endpoints"))
    assert isinstance(listen, list), f"{name} must set listen/endpoints (Zenoh's peer default is every interface)"
    for ep in listen + connect:
        assert is_loopback_endpoint(ep), f"{name}: {ep} is not loopback"
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    assert json.loads(conf.get_json("scouting/gossip/enabled")) is False
    usrpwd = json.loads(conf.get_json("transport/auth/usrpwd"))
    if name in ("router.json5", "tls/router.json5"):  # the router only checks the others: no identity of its own
        assert usrpwd["user"] is None and usrpwd["password"] is None
    else:
        assert _credentials().get(usrpwd["user"]) == usrpwd["password"], f"{name}: user/password not in credentials.txt"
    if name in ("daemon.json5", "tls/daemon.json5", "router.json5", "tls/router.json5"):
        assert json.loads(conf.get_json("access_control/enabled")) is True
    else:  # a client's own ACL would apply to its link too: the enforcing side has it
        assert json.loads(conf.get_json("access_control/enabled")) is False


@pytest.mark.parametrize("name", ["daemon.json5", "tls/daemon.json5", "router.json5", "tls/router.json5"])
def test_daemon_config_is_default_deny_and_consistent(name: str) -> None:
    conf = ZenohSettings(mode=None, config_file=str(EXAMPLES / name)).to_config()
    acl = json.loads(conf.get_json("access_control"))
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    assert json.loads(conf.get_json("transport/auth/usrpwd/dictionary_file")) == "examples/zenoh/credentials.txt"
    rule_ids = {r["id"] for r in acl["rules"]}
    subject_ids = {s["id"] for s in acl["subjects"]}
    for pol in acl["policies"]:
        assert set(pol["rules"]) <= rule_ids and set(pol["subjects"]) <= subject_ids, pol
    assert all(r["permission"] == "allow" and r.get("flows") for r in acl["rules"])
    users = {u for s in acl["subjects"] for u in s["usernames"]}
    assert users == set(_credentials()) == {"daemon", "sensor", "analyst", "recorder"}
    plain = ZenohSettings(mode=None, config_file=str(EXAMPLES / "daemon.json5")).to_config()
    assert acl == json.loads(plain.get_json("access_control")), f"{name} must share daemon.json5's ACL"


# --------------------------------------------------------------------------- authentication
def test_authenticated_sensor_and_analyst_get_through(daemon: DaemonLike) -> None:
    put_model = daemon.serve("auth-ok")
    with _client("sensor.json5", daemon) as sensor, _client("analyst.json5", daemon) as analyst:
        got = Inbox()
        analyst.subscribe("streamid/auth-ok/model", got)
        put_sample = _counter_put(sensor, "streamid/auth-ok/samples", b"sensor-ok#")
        assert _pump(put_sample, lambda: daemon.inbox.count(b"sensor-ok#") >= 3)
        assert _pump(put_model, lambda: got.count(b"model-of-auth-ok#") >= 3)
        assert {k for k, _ in got.items()} == {"streamid/auth-ok/model"}
        assert analyst.get("streamid/auth-ok/model", timeout_s=5.0) == [
            ("streamid/auth-ok/model", b"model-of-auth-ok")
        ]


def _intruder(kind: str, role: str, daemon: DaemonLike) -> Bus:
    """A session with wrong credentials; for a wrong password, those of ``role``'s user.

    Peer mode: the session opens (a client would fail to open, see below) and keeps
    trying to connect, so "receives nothing" is a real observation, not a crash.
    """
    if kind == "no-credentials":
        return Bus(ZenohSettings(mode="peer", connect=(daemon.endpoint,)))
    if kind == "wrong-password":
        extra = (("transport/auth/usrpwd/password", _j("not-the-password")),)
    else:  # an unknown user presenting a valid password of another user
        extra = (("transport/auth/usrpwd/user", _j("mallory")),
                 ("transport/auth/usrpwd/password", _j(_credentials()[role])))
    return _client(f"{role}.json5", daemon, mode="peer", extra=extra)


@pytest.mark.parametrize("kind", ["wrong-password", "unknown-user", "no-credentials"])
def test_wrong_credentials_receive_nothing_and_reach_nothing(daemon: DaemonLike, kind: str) -> None:
    # The intruders claim the role that WOULD be allowed to do what they try (reading
    # models as "analyst", publishing samples as "sensor"), so only authentication
    # stops them, not the access control.
    stream = f"intruder-{kind}"
    put_model = daemon.serve(stream)
    with _client("analyst.json5", daemon) as analyst, _client("sensor.json5", daemon) as sensor, \
            _intruder(kind, "analyst", daemon) as reader, _intruder(kind, "sensor", daemon) as writer:
        good, bad = Inbox(), Inbox()
        analyst.subscribe(f"streamid/{stream}/model", good)
        reader.subscribe(f"streamid/{stream}/model", bad)
        # models flow to the correct analyst; the intruder gets none of them
        assert _pump(put_model, lambda: good.count(b"model-of-") >= 3)
        assert bad.items() == []
        assert reader.get(f"streamid/{stream}/model", timeout_s=0.5) == []
        # the intruder's samples never reach the listener, the sensor's do
        put_good = _counter_put(sensor, f"streamid/{stream}/samples", b"good#")
        put_bad = _counter_put(writer, f"streamid/{stream}/samples", b"intruder#")

        def both() -> None:
            put_good()
            put_bad()

        assert _pump(both, lambda: daemon.inbox.count(b"good#") >= 3)
        assert daemon.inbox.count(b"intruder#") == 0
        for intruder in (reader, writer):
            assert intruder.peers() == [] and intruder.routers() == []


def test_client_with_wrong_password_cannot_even_open(daemon: DaemonLike) -> None:
    with pytest.raises(TransportError, match="cannot open zenoh session"):
        _refused(_settings("sensor.json5", connect=(daemon.endpoint,),
                           extra=(("transport/auth/usrpwd/password", _j("wrong")),)))


# --------------------------------------------------------------------------- access control
def test_acl_sensor_cannot_read_or_forge_models(daemon: DaemonLike) -> None:
    put_model = daemon.serve("acl-sensor")
    with _client("sensor.json5", daemon) as sensor, _client("analyst.json5", daemon) as analyst:
        seen_by_sensor, seen_by_analyst = Inbox(), Inbox()
        sensor.subscribe("streamid/acl-sensor/model", seen_by_sensor)
        analyst.subscribe("streamid/acl-sensor/model", seen_by_analyst)
        forge = _counter_put(sensor, "streamid/acl-sensor/model", b"forged#")

        def both() -> None:
            put_model()
            forge()

        assert _pump(both, lambda: seen_by_analyst.count(b"model-of-") >= 3)
        # reading models: denied (the sensor only sees its own forgeries, delivered locally)
        assert seen_by_sensor.count(b"model-of-") == 0
        assert all(p.startswith(b"forged#") for _, p in seen_by_sensor.items())
        assert seen_by_analyst.count(b"forged#") == 0  # publishing models: denied
        assert daemon.inbox.count(b"forged#") == 0
        assert sensor.get("streamid/acl-sensor/model", timeout_s=0.5) == []  # querying: denied


def test_acl_analyst_cannot_publish_or_read_samples(daemon: DaemonLike) -> None:
    put_model = daemon.serve("acl-analyst")
    with _client("sensor.json5", daemon) as sensor, _client("analyst.json5", daemon) as analyst, \
            _client("analyst.json5", daemon) as wide:
        samples_seen, wide_seen = Inbox(), Inbox()
        analyst.subscribe("streamid/acl-analyst/samples", samples_seen)  # reading samples: denied
        # a subscription wider than the rule (streamid/*/model) is refused as a whole
        wide.subscribe("streamid/**", wide_seen)
        put_good = _counter_put(sensor, "streamid/acl-analyst/samples", b"sensor#")
        put_bad = _counter_put(analyst, "streamid/acl-analyst/samples", b"analyst#")

        def all_three() -> None:
            put_good()
            put_bad()
            put_model()

        assert _pump(all_three, lambda: daemon.inbox.count(b"sensor#") >= 3)
        assert daemon.inbox.count(b"analyst#") == 0
        # the analyst only sees its own puts, delivered locally
        assert samples_seen.count(b"sensor#") == 0
        assert all(p.startswith(b"analyst#") for _, p in samples_seen.items())
        assert wide_seen.items() == []


def test_recorder_reads_everything_and_publishes_nothing(daemon: DaemonLike) -> None:
    put_model = daemon.serve("acl-recorder")
    with _client("sensor.json5", daemon) as sensor, _client("recorder.json5", daemon) as recorder:
        seen = Inbox()
        recorder.subscribe("streamid/**", seen)
        put_sample = _counter_put(sensor, "streamid/acl-recorder/samples", b"rec-sample#")
        put_bad = _counter_put(recorder, "streamid/acl-recorder/samples", b"rec-forged#")

        def all_three() -> None:
            put_sample()
            put_model()
            put_bad()

        assert _pump(all_three, lambda: seen.count(b"rec-sample#") >= 3 and seen.count(b"model-of-") >= 3)
        assert daemon.inbox.count(b"rec-forged#") == 0
        assert recorder.get("streamid/acl-recorder/model", timeout_s=0.5) == []


def test_daemon_identity_behind_a_router_does_what_the_daemon_does() -> None:
    """router.json5 (the same ACL in a router) + the daemon connecting with daemon-via-router.json5."""
    ep = endpoint()
    with Bus(_settings("router.json5", listen=(ep,))) as _router, \
            Bus(_settings("daemon-via-router.json5", connect=(ep,))) as daemon_session, \
            Bus(_settings("sensor.json5", connect=(ep,))) as sensor, \
            Bus(_settings("analyst.json5", connect=(ep,))) as analyst:
        samples, models, sensor_seen = Inbox(), Inbox(), Inbox()
        daemon_session.subscribe("streamid/*/*", samples)  # the daemon's subscription
        daemon_session.queryable("streamid/ident/model", lambda _k: b"served-by-daemon")
        put_model = _counter_put(daemon_session, "streamid/ident/model", b"ident-model#")
        analyst.subscribe("streamid/ident/model", models)
        sensor.subscribe("streamid/ident/model", sensor_seen)
        put_sample = _counter_put(sensor, "streamid/ident/samples", b"ident-sample#")
        forge = _counter_put(analyst, "streamid/ident/samples", b"ident-forged#")

        def samples_both() -> None:
            put_sample()
            forge()

        assert _pump(samples_both, lambda: samples.count(b"ident-sample#") >= 3)
        assert samples.count(b"ident-forged#") == 0  # analysts cannot publish samples
        assert _pump(put_model, lambda: models.count(b"ident-model#") >= 3)
        assert sensor_seen.items() == []  # sensors cannot read models through the router
        deadline = time.monotonic() + ARRIVE_S  # declarations propagate asynchronously
        replies: list[tuple[str, bytes]] = []
        for _ in range(50):
            replies = analyst.get("streamid/ident/model", timeout_s=0.5)
            if replies or time.monotonic() > deadline:
                break
        assert replies == [("streamid/ident/model", b"served-by-daemon")]
        assert sensor.get("streamid/ident/model", timeout_s=0.5) == []


FAST_DAEMON_TOML = """
[defaults]
window_samples = 400
update_every_samples = 400
cold_generations = 10
warm_generations = 3
neurons = 3
max_lag_y = 2
max_lag_u = 2
population = 8
min_r2_osa = -1e9
min_r2_fr = -1e9
"""


def _wait_listening(ep: str, proc: subprocess.Popen[str], timeout_s: float) -> bool:
    """Whether something accepts TCP connections on ``ep`` within ``timeout_s`` (while ``proc`` runs)."""
    host, port = ep.split("/", 1)[1].rsplit(":", 1)
    deadline = time.monotonic() + timeout_s
    for _ in range(int(timeout_s / 0.05) + 1):
        if proc.poll() is not None:
            return False
        try:
            with socket.create_connection((host, int(port)), timeout=0.2):
                return True
        except OSError:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.05)
    return False


def test_real_cli_daemon_with_the_shipped_configs(tmp_path: Path) -> None:
    """``streamid daemon --zenoh-config examples/zenoh/daemon.json5`` run as documented
    (from the repository root); ``streamid replay`` as the sensor; analyst gets models,
    the sensor does not."""
    ep = endpoint()
    (tmp_path / "fast.toml").write_text(FAST_DAEMON_TOML)
    cli = [sys.executable, "-m", "streamid"]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    daemon = subprocess.Popen(
        [*cli, "daemon", "--zenoh-config", "examples/zenoh/daemon.json5", "--listen", ep, "--no-rerun",
         "--config", str(tmp_path / "fast.toml"), "--duration", "60"],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    try:
        assert _wait_listening(ep, daemon, 30.0), "the daemon never listened on " + ep
        with Bus(_settings("analyst.json5", connect=(ep,))) as analyst, \
                Bus(_settings("sensor.json5", connect=(ep,))) as sensor:
            models, sensor_seen = Inbox(), Inbox()
            analyst.subscribe("streamid/*/model", models)
            sensor.subscribe("streamid/*/model", sensor_seen)
            probe = sensor.publisher("streamid/e2e/samples")  # matches once the daemon subscribed
            assert probe.wait_for_subscribers(20.0), "the daemon never subscribed"
            replay = subprocess.run(
                [*cli, "replay", "mr_damper", "--stream", "e2e", "--max-speed", "--end", "5",
                 "--zenoh-config", "examples/zenoh/sensor.json5", "--connect", ep, "--json"],
                cwd=ROOT, env=env, capture_output=True, text=True, timeout=60,
            )
            assert replay.returncode == 0, replay.stderr
            deadline = time.monotonic() + 20.0
            while not models.items() and time.monotonic() < deadline:
                time.sleep(0.05)
            got = models.items()
            assert got, "no model reached the analyst"
            key, payload = got[0]
            assert key == "streamid/e2e/model" and json.loads(payload)["stream"] == "e2e"
            assert analyst.get("streamid/e2e/model", timeout_s=5.0) != []
            assert sensor_seen.items() == []
            assert sensor.get("streamid/e2e/model", timeout_s=0.5) == []
    finally:
        daemon.send_signal(signal.SIGINT)
        try:
            out, _ = daemon.communicate(timeout=15)
        except subprocess.TimeoutExpired:
            daemon.kill()
            out, _ = daemon.communicate(timeout=5)
    assert daemon.returncode == 0, out


# --------------------------------------------------------------------------- TLS
@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Two throw-away CAs + daemon certificates made by the shipped script (keys never committed)."""
    require("openssl")  # examples/zenoh/make-test-certs.sh runs it
    dirs = []
    for name in ("certs", "other-ca"):
        out = tmp_path_factory.mktemp(name)
        subprocess.run(["sh", str(EXAMPLES / "make-test-certs.sh"), str(out), "1"],
                       check=True, capture_output=True, timeout=60)
        assert (out / "daemon.key").stat().st_mode & 0o077 == 0  # private key not readable by others
        assert sorted(f.name for f in out.iterdir()) == ["ca.pem", "daemon.key", "daemon.pem"]  # no CA key left
        dirs.append(out)
    return dirs[0], dirs[1]


def _tls(name: str, certs_dir: Path, *, more: tuple[tuple[str, str], ...] = (), **kw: object) -> ZenohSettings:
    """A shipped TLS config with the certificate paths of ``certs_dir``."""
    extra = (
        ("transport/link/tls/root_ca_certificate", _j(str(certs_dir / "ca.pem"))),
    ) if name != "tls/daemon.json5" else (
        ("transport/link/tls/listen_certificate", _j(str(certs_dir / "daemon.pem"))),
        ("transport/link/tls/listen_private_key", _j(str(certs_dir / "daemon.key"))),
    )
    return _settings(name, extra=extra + more, **kw)  # type: ignore[arg-type]


def test_tls_daemon_serves_authenticated_tls_clients_only(certs: tuple[Path, Path]) -> None:
    good_ca, other_ca = certs
    port = endpoint().rsplit(":", 1)[1]
    tls_ep, tcp_ep = f"tls/127.0.0.1:{port}", f"tcp/127.0.0.1:{port}"
    with Bus(_tls("tls/daemon.json5", good_ca, listen=(tls_ep,))) as server:
        inbox = Inbox()
        server.subscribe("streamid/*/*", inbox)
        put_model = _counter_put(server, "streamid/tls/model", b"tls-model#")
        with Bus(_tls("tls/sensor.json5", good_ca, connect=(tls_ep,))) as sensor, \
                Bus(_tls("tls/analyst.json5", good_ca, connect=(tls_ep,))) as analyst:
            models = Inbox()
            analyst.subscribe("streamid/tls/model", models)
            put_sample = _counter_put(sensor, "streamid/tls/samples", b"tls-sample#")
            assert _pump(put_sample, lambda: inbox.count(b"tls-sample#") >= 3)
            assert _pump(put_model, lambda: models.count(b"tls-model#") >= 3)
            # the ACL is the same over TLS: the sensor still cannot read models
            sensor_seen = Inbox()
            sensor.subscribe("streamid/tls/model", sensor_seen)
            assert _pump(put_model, lambda: models.count(b"tls-model#") >= 6)
            assert sensor_seen.items() == []
        # a client trusting another CA refuses the daemon's certificate
        with pytest.raises(TransportError, match="cannot open zenoh session"):
            _refused(_tls("tls/sensor.json5", other_ca, connect=(tls_ep,)))
        # plain TCP with the right password cannot talk to the TLS listener
        with pytest.raises(TransportError, match="cannot open zenoh session"):
            _refused(_settings("sensor.json5", connect=(tcp_ep,)))
        # right certificate chain, wrong password: refused as well
        with pytest.raises(TransportError, match="cannot open zenoh session"):
            _refused(_tls("tls/sensor.json5", good_ca, connect=(tls_ep,),
                          more=(("transport/auth/usrpwd/password", _j("wrong")),)))
