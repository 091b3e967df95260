"""``streamid watch --save-fmu`` within its bounds (issue 52, item 2), over real parts: parsed model updates, real
gcc, fmpy's ``validate_fmu`` on every FMU written, and a real ``streamid watch`` on loopback Zenoh fed by a forger.

* ``--keep N`` versions a stream; names that cannot collide across streams (``a`` v1 vs a stream ``a-v1``);
* ``--max-bytes``: the oldest versions go first, a stream's newest FMU that cannot fit is not written (said);
* ``--max-pending``: the oldest pending model is dropped, counted and said;
* a model that cannot be exported is skipped and said; the next one is saved;
* the compiler runs in its own process group, killed whole on its budget (no ``cc1`` left);
* a forged update with a lone surrogate in a name never ends the watcher; SIGTERM and ``--duration`` stop it while
  a long compile is under way, the compile's process group killed and nothing half-written.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from conftest import STREAMID, endpoint
from export_models import kinds
from streamid.model.narx import Model
from streamid.model.regressors import Normalisation, Regressor
from streamid.export.saver import FmuSaver, SaveBounds
from streamid.transport import Bus, ZenohSettings
from streamid.transport.updates import parse_model_update
from streamid.wire.documents import encode_json, model_update_message

fmpy = pytest.importorskip("fmpy", reason="needs fmpy (pip install '.[test]')")
from fmpy.validation import validate_fmu  # noqa: E402

DEADLINE_S = 30.0


@pytest.fixture(autouse=True)
def _cc() -> None:
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("needs a C compiler (Debian package gcc)")


def payload(stream: str, version: int, model: Model) -> bytes:
    return encode_json(model_update_message(
        stream=stream, version=version, model=model.to_dict(), window={"period_ns": 10_000_000}, metrics={},
        warm=False, generations=1, identification_s=0.1, window_closed_unix_ns=1, published_unix_ns=1,
        output=model.output_name, accepted=True))


def update(stream: str, version: int, model: Model | None = None) -> Any:
    return parse_model_update(payload(stream, version, model or kinds()["network"]))


def names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def saver_of(folder: Path, **bounds: int) -> tuple[FmuSaver, list[str]]:
    said: list[str] = []
    return FmuSaver(str(folder), SaveBounds(**bounds), say=said.append), said


def test_keep_n_versions_a_stream_and_names_that_cannot_collide_across_streams(tmp_path: Path) -> None:
    saver, said = saver_of(tmp_path, keep=2)
    for stream, version in (("a", 1), ("a-v1", 1), ("a.v1", 7), ("a", 2), ("a", 3), ("a", 4)):
        saver.offer(update(stream, version))
        saver.save_pending()
    assert names(tmp_path) == ["a+v3.fmu", "a+v4.fmu", "a-v1+v1.fmu", "a-v1.fmu", "a.fmu", "a.v1+v7.fmu", "a.v1.fmu"]
    assert (tmp_path / "a.fmu").read_bytes() == (tmp_path / "a+v4.fmu").read_bytes()
    assert saver.saved == 6 and saver.deleted == 2 and saver.failed == 0, said
    for f in tmp_path.iterdir():
        assert validate_fmu(str(f)) == [], f
    (tmp_path / "k0").mkdir()
    only_newest, _ = saver_of(tmp_path / "k0", keep=0)
    only_newest.offer(update("s", 1))
    only_newest.offer(update("s", 2))
    only_newest.save_pending()
    assert names(tmp_path / "k0") == ["s.fmu"]


def test_max_bytes_deletes_the_oldest_versions_and_refuses_what_cannot_fit(tmp_path: Path) -> None:
    (tmp_path / "probe").mkdir()
    probe, _ = saver_of(tmp_path / "probe")
    probe.offer(update("a", 1))
    probe.save_pending()
    size = (tmp_path / "probe" / "a.fmu").stat().st_size
    bound = int(3.5 * size)  # room for three FMUs of this size, not four
    out = tmp_path / "out"
    out.mkdir()
    saver, said = saver_of(out, keep=5, max_bytes=bound)
    for stream, version in (("a", 1), ("a", 2), ("a", 3), ("b", 1), ("c", 1)):
        saver.offer(update(stream, version))
        saver.save_pending()
        assert sum(p.stat().st_size for p in out.iterdir()) <= bound, names(out)
    # a v3 pushed a+v1 out, b v1 a+v2 and a+v3; stream c cannot fit even with b+v1 gone: refused, nothing deleted
    assert names(out) == ["a.fmu", "b+v1.fmu", "b.fmu"], names(out)
    assert any("c v1 not saved as an FMU" in s and "--max-bytes" in s for s in said), said
    for f in out.iterdir():
        assert validate_fmu(str(f)) == [], f


def test_the_pending_queue_drops_the_oldest_and_says_so(tmp_path: Path) -> None:
    saver, said = saver_of(tmp_path, max_pending=2)
    for v in range(1, 6):
        saver.offer(update("q", v))
    assert saver.pending == 2 and saver.dropped == 3
    assert [s for s in said if "dropped for newer models" in s] == [
        f"streamid watch: q v{v} not saved as an FMU: dropped for newer models (at most 2 wait to be compiled; "
        f"{v} dropped so far)" for v in (1, 2, 3)]
    saver.save_pending()
    assert names(tmp_path) == ["q+v4.fmu", "q+v5.fmu", "q.fmu"]


def test_a_model_that_cannot_be_exported_is_skipped_and_the_next_saved(tmp_path: Path) -> None:
    doc = kinds()["network"].to_dict()
    doc["widths"][0] = 1e200  # accepted by the reader; 2 w^2 overflows in C
    saver, said = saver_of(tmp_path)
    saver.offer(update("s", 1, Model.from_dict(doc)))
    saver.offer(update("s", 2))
    saver.save_pending()
    assert saver.failed == 1 and saver.saved == 1 and names(tmp_path) == ["s+v2.fmu", "s.fmu"]
    assert any("s v1 not saved as an FMU" in s and "C cannot spell" in s for s in said), said


def wide_model(regressors: int = 2000, neurons: int = 10) -> Model:
    """A model the limits accept whose C takes gcc tens of seconds (its gather lines: the square of them)."""
    rng = np.random.default_rng(0)
    return Model(regressors=tuple(Regressor("u", 0, i) for i in range(regressors)),
                 centres=rng.uniform(-1, 1, (neurons, regressors)), widths=rng.uniform(0.5, 1.5, neurons),
                 weights=rng.normal(0, 1, neurons), normalisation=Normalisation((-1.0,), (1.0,), -1.0, 1.0),
                 input_names=("u",), output_name="y", window={"period_ns": 10_000_000})


def cc_wrapper(tmp_path: Path) -> tuple[dict[str, str], Path]:
    """$CC: a script that records its process id (the compile's process group leader), then runs gcc."""
    pids = tmp_path / "cc.pids"
    script = tmp_path / "cc"
    script.write_text(f"#!/bin/sh\necho $$ >> {pids}\nexec {shutil.which('gcc') or shutil.which('cc')} \"$@\"\n")
    script.chmod(0o755)
    return {**os.environ, "CC": str(script)}, pids


def group_alive(pgid: int) -> list[str]:
    """The commands of the live (not zombie) processes of process group ``pgid``, from /proc (after a short wait:
    SIGKILL is delivered asynchronously). A killed child reparented to an init that never reaps stays a zombie:
    that is not a running compiler."""
    found: list[str] = []
    for _ in range(50):
        found = []
        for d in Path("/proc").iterdir():
            try:
                stat = (d / "stat").read_text()
            except (OSError, ValueError):
                continue
            comm, rest = stat[stat.index("(") + 1: stat.rindex(")")], stat[stat.rindex(")") + 2:].split()
            if rest[0] != "Z" and int(rest[2]) == pgid:
                found.append(comm)
        if not found:
            return found
        time.sleep(0.1)
    return found


def test_a_compile_over_its_budget_is_killed_with_its_whole_process_group(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    from streamid.errors import ConfigError
    from streamid.export.compiler import compile_shared
    from streamid.export.fmu import compile_budget, fmu_files
    from streamid.export.plan import plan_of

    env, pids = cc_wrapper(tmp_path)
    monkeypatch.setenv("CC", env["CC"])
    plan = plan_of([wide_model()], "wide", None)
    assert compile_budget(plan) >= 30.0  # a budget from its size (never below 30 s)
    root = tmp_path / "fmu"
    for rel, text in fmu_files(plan).files:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    with pytest.raises(ConfigError, match="ran over its budget of 1 s; its process group was killed"):
        compile_shared([root / "sources" / "wide.c", root / "sources" / "fmi2_wide.c"], root / "sources",
                       root / "wide.so", timeout_s=1.0)
    pgid = int(pids.read_text().split()[0])
    assert not group_alive(pgid)  # no cc1 (nor as, ld) left running
    assert not (root / "wide.so").exists()
    huge = plan_of([wide_model(regressors=4096, neurons=2)], "huge", None)
    with pytest.raises(ConfigError, match="network 0 has 4096 regressors.*--sources-only"):
        compile_budget(huge)


def watch(ep: str, out: Path, env: dict[str, str], *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen([*STREAMID, "watch", "--connect", ep, "--stream", "*", "--save-fmu", str(out), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def lines_of(proc: subprocess.Popen[str]) -> list[str]:
    got: list[str] = []
    threading.Thread(target=lambda: got.extend(iter(proc.stdout.readline, "")), daemon=True).start()  # type: ignore[union-attr]
    return got


def wait_for(pred: Any, what: str) -> None:
    end = time.monotonic() + DEADLINE_S
    while not pred():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.02)


def test_a_forged_name_never_ends_the_watcher_and_the_next_model_is_saved(tmp_path: Path) -> None:
    ep = endpoint()
    out = tmp_path / "fmus"
    out.mkdir()
    with Bus(ZenohSettings(listen=(ep,))) as forger:
        w = watch(ep, out, dict(os.environ), "--count", "1", "--duration", "60")
        try:
            lines = lines_of(w)
            pub = forger.publisher("streamid/rig/model")
            assert pub.wait_for_subscribers(DEADLINE_S)
            time.sleep(0.3)  # the watch's subscription is declared; its first query answered (nothing)
            bad = kinds()["network"].to_dict()
            bad["inputs"] = ["v\ud800", "valve"]  # issue 52: a UnicodeEncodeError traceback ended the watcher
            pub.put(payload("rig", 1, kinds()["network"]).replace(
                encode_json({"a": kinds()["network"].to_dict()["inputs"]})[5:-1],
                encode_json({"a": bad["inputs"]})[5:-1]))
            pub.put(payload("rig", 2, kinds()["network"]))
            assert w.wait(timeout=60) == 0
            err = w.stderr.read()  # type: ignore[union-attr]
        finally:
            if w.poll() is None:
                w.kill()
                w.wait()
    assert "Traceback" not in err and "\ud800" not in err, err
    assert "holds U+D800" in err and "skipped 1 invalid model updates (malformed: 1)" in err, err
    assert len(lines) == 1 and lines[0].startswith("rig v2 ")
    assert names(out) == ["rig+v2.fmu", "rig.fmu"] and validate_fmu(str(out / "rig.fmu")) == []


@pytest.mark.parametrize("how", ["SIGTERM", "--duration"])
def test_sigterm_and_duration_stop_a_long_compile_killing_its_process_group(tmp_path: Path, how: str) -> None:
    ep = endpoint()
    out = tmp_path / "fmus"
    out.mkdir()
    env, pids = cc_wrapper(tmp_path)
    extra = ("--duration", "4") if how == "--duration" else ()
    with Bus(ZenohSettings(listen=(ep,))) as forger:
        w = watch(ep, out, env, *extra)
        try:
            lines = lines_of(w)
            pub = forger.publisher("streamid/slow/model")
            assert pub.wait_for_subscribers(DEADLINE_S)
            time.sleep(0.3)
            pub.put(payload("slow", 1, wide_model()))  # gcc takes ~18 s and ~650 MB on it (docs/security.md)
            wait_for(lambda: pids.exists() and pids.read_text().strip(), "the compile to start")
            wait_for(lambda: lines, "the update's line")
            if how == "SIGTERM":
                w.send_signal(signal.SIGTERM)
            assert w.wait(timeout=DEADLINE_S) == 0  # (the compile alone would take ~18 s: it was stopped)
            err = w.stderr.read()  # type: ignore[union-attr]
        finally:
            if w.poll() is None:
                w.kill()
                w.wait()
    pgid = int(pids.read_text().split()[0])
    assert not group_alive(pgid), "a compiler process outlived the watch"
    assert "slow v1 not saved as an FMU: the C compiler" in err and "stopped (the command is ending)" in err, err
    assert [p.name for p in out.iterdir() if p.suffix == ".fmu"] == []  # nothing half-written
    assert "Traceback" not in err
