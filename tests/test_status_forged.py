"""``streamid status`` against replayed and forged answers, and a flood of them (issue 52, item 4).

A real ``streamid daemon`` serving a stream on loopback Zenoh; forgers are plain Zenoh client sessions on the same
endpoint (anyone who reaches the daemon without access control), or a process of their own
(``tests/reply_flood_peer.py``) when the test measures the memory of ``streamid status``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from conftest import STREAMID, endpoint, stop_process, wait_until

from streamid.commands.status import MAX_ANSWER_BYTES, collect
from streamid.transport import Bus, ZenohSettings

TESTS = Path(__file__).resolve().parent


def _status(ep: str, stream: str, want_rc: int, timeout: str = "1.5") -> subprocess.CompletedProcess[str]:
    out: subprocess.CompletedProcess[str] | None = None
    for _ in range(5):  # declarations propagate asynchronously: ask again until every answer is in
        out = subprocess.run([*STREAMID, "status", "--connect", ep, "--stream", stream, "--timeout", timeout],
                             capture_output=True, text=True, timeout=60)
        if out.returncode == want_rc and "ignored" in out.stderr:
            break
    assert out is not None
    return out


def test_a_replayed_copy_of_the_daemons_answer_is_a_conflict_and_stray_documents_are_counted(tmp_path: Path) -> None:
    """Was: a copy of the real status (same daemon id and epoch) with another version and ``degraded: "FORGED"``
    replaced the real row (exit 0, no CONFLICT); a document naming another stream, or none, was shown."""
    ep = endpoint()
    daemon = subprocess.Popen([*STREAMID, "daemon", "--listen", ep, "--stream", "dev1", "--no-rerun"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        with Bus(ZenohSettings(mode="client", connect=(ep,), connect_wait_s=30)) as forger:
            real: list[bytes] = []
            assert wait_until(lambda: bool(real.extend(p for _, p in forger.get("streamid/dev1/status", 0.5))
                                           or real), 60)
            genuine = json.loads(real[-1])
            copy = dict(genuine, version=7, degraded=True, degraded_reason="FORGED")  # same daemon, same epoch
            other = dict(genuine, stream="dev2")  # a real document of another stream, on dev1's key
            nameless = {k: v for k, v in genuine.items() if k != "stream"}
            for doc in (copy, other, nameless):
                forger.queryable("streamid/dev1/status", lambda _k, d=doc: json.dumps(d).encode())
            out = _status(ep, "dev1", 3)
    finally:
        stop_process(daemon)
    assert out.returncode == 3, (out.returncode, out.stdout, out.stderr)
    rows = [ln for ln in out.stdout.splitlines() if ln.startswith("dev")]
    daemon_id = genuine["daemon"]["origin"]["daemon"]
    assert len(rows) == 2 and all(r.startswith("dev1 ") and r.split()[1] == daemon_id for r in rows), out.stdout
    assert {r.split()[2] for r in rows} == {f"v{genuine['version']}", "v7"}, rows
    assert all("CONFLICT: 2 answers" in r and "2 times with different content" in r for r in rows), rows
    assert any("FORGED" in r for r in rows) and "replayed or forged" in out.stderr, out.stderr
    assert "ignored 1 status documents without a 'stream'" in out.stderr, out.stderr
    assert "ignored 1 answers whose document names another stream" in out.stderr, out.stderr


def test_collect_keeps_one_copy_of_identical_answers_and_each_different_one() -> None:
    doc = {"format": "streamid.status/1", "stream": "a", "version": 3,
           "daemon": {"origin": {"daemon": "d", "epoch_ns": 5}}}
    raw = json.dumps(doc).encode()
    got = collect([("streamid/a/status", raw), ("streamid/a/status", raw),
                   ("streamid/a/status", json.dumps(dict(doc, version=4)).encode()),
                   ("streamid/b/status", raw), ("streamid/a/status", b"not json")])
    assert len(got.docs["a"]) == 2 and list(got.docs) == ["a"]
    assert (got.wrong_key, got.no_stream, got.invalid) == (1, 0, 1)


def test_status_under_a_flood_of_large_answers_reads_a_bounded_part_in_bounded_memory(tmp_path: Path) -> None:
    """2,000 answers of 1 MB each (2 GB): was a 2.0 GB peak (6,000: a MemoryError traceback); now at most 16 MiB
    of answers are read, the rest counted and said, and the command's peak RSS stays under 500 MB."""
    doc = {"format": "streamid.status/1", "stream": "dev1", "version": 3, "pad": "x" * 1_000_000}
    payload = tmp_path / "answer.json"
    payload.write_text(json.dumps(doc))
    assert len(payload.read_bytes()) <= MAX_ANSWER_BYTES
    ep = endpoint()
    with Bus(ZenohSettings(mode="router", listen=(ep,))):
        forger = subprocess.Popen([sys.executable, str(TESTS / "reply_flood_peer.py"), ep, "streamid/dev1/status",
                                   "2000", str(payload)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        try:
            assert forger.stdout is not None and forger.stdout.readline().strip() == "ready"
            rc, rss_kib, out, err = _run_measured([*STREAMID, "status", "--connect", ep, "--stream", "dev1",
                                                   "--timeout", "3"], tmp_path)
        finally:
            assert forger.stdin is not None
            forger.stdin.close()
            stop_process(forger)
    assert rc == 0, err[-2000:]
    assert "dropped" in err and "beyond what one ask reads" in err, err[-2000:]
    assert [ln.split()[0] for ln in out.splitlines()[1:]] == ["dev1"], out
    # its own peak: 55 MB measured alone, the same with 6,000 answers (was 1,344 MB at 2,000, growing with the flood)
    assert 0 < rss_kib < 300 * 1024, f"streamid status peaked at {rss_kib / 1024:.0f} MB; {err}"
    print(f"streamid status under 2,000 answers of 1 MB: peak RSS {rss_kib / 1024:.0f} MB; {err.strip()}", file=sys.stderr)


def _run_measured(cmd: list[str], tmp_path: Path) -> tuple[int, int, str, str]:
    """Run ``cmd``; (exit code, its own peak RSS in KiB, stdout, stderr); killed after 120 s (stuck). The peak is
    its own VmHWM read while it lives (:func:`benchmarks.kit.run_with_peak`: wait4's ru_maxrss would start from the
    pytest worker's, 800 MB after other tests in the same worker, not the command's)."""
    from benchmarks.kit import run_with_peak

    run = run_with_peak(cmd, tmp_path / "out", tmp_path / "err", 120.0)  # a deadline for a stuck command, not a speed
    return (run.code, run.peak_kib, (tmp_path / "out").read_text(), (tmp_path / "err").read_text())
