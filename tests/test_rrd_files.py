""".rrd segments: rotation by time and size, disk bounds, a writer killed with SIGKILL, and the repair.

The writer is a real subprocess (tests/rrd_writer.py: the daemon's :class:`Viz` drawing updates)
killed with SIGKILL while it writes; every file is read back with the rerun CLI (``rerun rrd
verify``) and the SDK's reader.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import RERUN, STREAMID

from streamid.errors import ConfigError
from streamid.viz import rrd_files
from streamid.viz.rerun_view import Viz, VizSettings, repair_rrd

sys.path.insert(0, str(Path(__file__).parent))
from rrd_writer import report  # noqa: E402 - the writer's updates, drawn in-process here

WRITER = str(Path(__file__).parent / "rrd_writer.py")
ROOT = Path(__file__).resolve().parents[1]


def verified(path: Path) -> tuple[bool, str]:
    return rrd_files.verify(path, rerun=RERUN, timeout_s=60)


def versions(path: Path) -> list[int]:
    """The model versions whose 'published' event is in the .rrd at ``path``."""
    from rerun.chunk import RrdReader

    out = []
    for c in RrdReader(path).stream().filter(content="/streams/s/events").to_chunks():
        for row in c.to_record_batch().column("TextLog:text").to_pylist():
            for text in row if isinstance(row, list) else [row]:
                m = re.match(r"model v(\d+) ", text)
                if m:
                    out.append(int(m.group(1)))
    return out


def test_sigkilled_writer_leaves_one_open_segment_and_repair_recovers_it(tmp_path: Path) -> None:
    """kill -9 mid-write: every closed segment verifies, the open one does not ("Missing RRD footer");
    its repaired copy verifies, and together they hold every update up to the newest fraction of a second."""
    base = tmp_path / "k.rrd"
    rotate_s = 1.0
    proc = subprocess.Popen([sys.executable, WRITER, str(base), str(rotate_s), "20"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    drawn_at: dict[int, float] = {}
    rotations = 0
    t_third: float | None = None
    v_third = 0
    try:
        assert proc.stdout is not None
        deadline = time.monotonic() + 40
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            if line.startswith("drawn v"):
                drawn_at[int(line.split("v")[1])] = time.monotonic()
            elif line.startswith("rotated"):
                rotations += 1
            if rotations == 3 and t_third is None:
                t_third, v_third = time.monotonic(), max(drawn_at)
            if t_third is not None and time.monotonic() - t_third >= 0.6 * rotate_s and max(drawn_at) >= v_third + 3:
                break  # well into a segment: the SDK wrote some of it (it flushes every ~0.2 s)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        rest = proc.stdout.read() if proc.stdout is not None else ""
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == -signal.SIGKILL
    assert rotations >= 3, f"the writer rotated {rotations} times before the deadline: {proc.stderr.read()[-2000:] if proc.stderr else ''}"
    t_kill = time.monotonic()
    for line in rest.splitlines():  # lines printed between the last read and the kill
        if line.startswith("drawn v"):
            drawn_at[int(line.split("v")[1])] = t_kill
    segs = rrd_files.segments_of(base)
    assert len(segs) >= 4 and segs[0] == base and segs[-1].name == f"k.{len(segs) - 1:03d}.rrd"
    for s in segs[:-1]:  # closed: footer written, verified as they are
        assert rrd_files.has_footer(s) and verified(s)[0], s
    ok, said = verified(segs[-1])  # the open one: the reported failure
    assert not ok and "Missing RRD footer" in said and not rrd_files.has_footer(segs[-1])
    closed = sorted(v for s in segs[:-1] for v in versions(s))
    newest = max(drawn_at)
    # without repair only the open segment is missing: at most rotate_s (+ one update) of the newest
    if max(closed) < newest:
        assert drawn_at[newest] - drawn_at[max(closed) + 1] <= rotate_s + 0.5, (max(closed), newest)

    rep = repair_rrd(segs[-1], tmp_path / "fixed.rrd")
    assert rep.output == tmp_path / "fixed.rrd" and rep.chunks > 0 and not rep.source_had_footer
    assert verified(rep.output)[0] and rrd_files.has_footer(rep.output)
    recovered = sorted(closed + versions(rep.output))
    assert recovered == list(range(1, max(recovered) + 1))  # nothing skipped, nothing twice
    assert max(recovered) > max(closed)  # the repair brought back updates of the open segment
    # with the repair, what is lost is what the SDK had not yet written (it flushes every ~0.2 s)
    lost_s = drawn_at[newest] - drawn_at[max(recovered)]
    assert lost_s <= 1.0, (max(recovered), newest, lost_s)
    print(f"SIGKILL: {len(segs)} segments, newest update v{newest}; closed segments up to v{max(closed)}, "
          f"with the repair up to v{max(recovered)} ({lost_s:.3f} s lost)")
    from rerun.chunk import RrdReader

    assert RrdReader(rep.output).blueprints() and RrdReader(rep.output).recordings()[0].recording_id == "rrd-writer"


def test_rotation_by_time_bounds_segments_and_bytes_and_counts_what_it_removed(tmp_path: Path) -> None:
    base = tmp_path / "t.rrd"
    viz = Viz(VizSettings(rrd=str(base), rrd_rotate_s=0.05, rrd_keep=3, rrd_max_mb=100.0, recording_id="t"))
    viz.add_stream("s")
    for v in range(1, 9):
        viz.log_update(report(v, n_val=100))
        time.sleep(0.06)
    viz.log_event("s", "the end")
    stats = viz.file_stats
    viz.close()
    files = [Path(f) for f in viz.files]
    assert stats["rotations"] >= 7 and len(files) == stats["segments"] == 3
    assert stats["removed"] == stats["rotations"] + 1 - 3 and stats["removed_bytes"] > 0
    assert sorted(tmp_path.iterdir()) == sorted(files) == rrd_files.segments_of(base)  # oldest deleted
    assert not base.exists()  # the first segment went first
    for f in files:
        assert verified(f)[0], f
    kept = sorted(v for f in files for v in versions(f))
    assert kept and kept == list(range(kept[0], 9))  # the newest updates are kept, in one piece

    # a byte bound: every segment ~0.1 MB (one update each); 0.35 MB keeps the newest three
    big = tmp_path / "b" / "b.rrd"
    big.parent.mkdir()
    viz = Viz(VizSettings(rrd=str(big), rrd_rotate_mb=0.05, rrd_max_mb=0.35, recording_id="b"))
    viz.add_stream("s")
    for v in range(1, 9):
        viz.log_update(report(v, n_val=400))
        viz.flush()
    viz.close()
    sizes = [os.path.getsize(f) for f in viz.files]
    assert viz.file_stats["removed"] >= 3 and sum(sizes[:-1]) <= 0.35e6, sizes
    assert sorted(p.name for p in big.parent.iterdir()) == sorted(Path(f).name for f in viz.files)


def test_an_idle_writer_closes_its_segment_once_due(tmp_path: Path) -> None:
    """Nothing drawn after the first update: the segment is closed on time all the same, and only once."""
    base = tmp_path / "i.rrd"
    viz = Viz(VizSettings(rrd=str(base), rrd_rotate_s=0.2, recording_id="idle"))
    try:
        viz.add_stream("s")
        viz.log_update(report(1))
        deadline = time.monotonic() + 10
        while not rrd_files.has_footer(base) and time.monotonic() < deadline:
            time.sleep(0.02)
        assert rrd_files.has_footer(base) and verified(base)[0] and versions(base) == [1]  # while still running
        time.sleep(0.5)  # nothing new: no more segments
        assert viz.files == [str(base), str(tmp_path / "i.001.rrd")] and viz.file_stats["rotations"] == 1
    finally:
        viz.close()


def test_rotation_leaves_no_threads_behind(tmp_path: Path) -> None:
    """Was: every segment left 2 SDK threads (a new recording stream) and every blueprint sent 2 more."""
    def threads() -> int:
        return len(os.listdir("/proc/self/task"))

    viz = Viz(VizSettings(rrd=str(tmp_path / "n.rrd"), rrd_rotate_mb=0.01, rrd_keep=5, recording_id="n"))
    viz.add_stream("s")
    viz.log_update(report(1, n_val=100))
    before = threads()
    for v in range(2, 32):
        viz.log_update(report(v, n_val=100))
    after, rotations = threads(), viz.file_stats["rotations"]
    viz.close()
    assert rotations >= 30 and after - before <= 2, (before, after, rotations)


def test_segments_of_an_earlier_run_are_removed_and_others_kept(tmp_path: Path) -> None:
    base = tmp_path / "d.rrd"
    first = Viz(VizSettings(rrd=str(base), rrd_rotate_mb=0.05, recording_id="first"))
    first.add_stream("s")
    for v in range(1, 4):
        first.log_update(report(v, n_val=400))
        first.flush()
    first.close()
    assert len(rrd_files.segments_of(base)) >= 3
    for other in ("d.notes.rrd", "dd.001.rrd", "d.01.rrd", "d.001.rrd.bak"):
        (tmp_path / other).write_bytes(b"RRF2 not ours")
    second = Viz(VizSettings(rrd=str(base), recording_id="second"))
    second.close()
    assert rrd_files.segments_of(base) == [base]  # d.001.rrd... of the first run are gone
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["d.rrd", "d.notes.rrd", "dd.001.rrd", "d.01.rrd",
                                                                  "d.001.rrd.bak"])


def test_segment_names_order_and_checks(tmp_path: Path) -> None:
    base = tmp_path / "x.rrd"
    assert rrd_files.segment_path(base, 0) == base
    assert rrd_files.segment_path(base, 7).name == "x.007.rrd"
    assert rrd_files.segment_path(base, 1234).name == "x.1234.rrd"
    for i in (1000, 2, 999, 10):
        rrd_files.segment_path(base, i).write_bytes(b"RRF2")
    assert [p.name for p in rrd_files.segments_of(base)] == ["x.002.rrd", "x.010.rrd", "x.999.rrd", "x.1000.rrd"]
    files, empty = rrd_files.resolve([base])  # x.rrd itself removed by rotation: its segments still resolve
    assert [p.name for p in files] == ["x.002.rrd", "x.010.rrd", "x.999.rrd", "x.1000.rrd"] and empty == []
    (tmp_path / "x.1001.rrd").write_bytes(b"")  # killed as it was created
    files, empty = rrd_files.resolve([base, tmp_path / "x.010.rrd"])
    assert len(files) == 4 and [p.name for p in empty] == ["x.1001.rrd"]
    with pytest.raises(ConfigError, match=r"no file '.*nothing\.rrd'; give a Rerun recording FILE\.rrd"):
        rrd_files.resolve([tmp_path / "nothing.rrd"])
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(ConfigError, match=r"'.*notes\.txt' is not an \.rrd file \(its name must end in \.rrd\)"):
        rrd_files.check_rrd(tmp_path / "notes.txt")
    (tmp_path / "fake.rrd").write_text("hello")
    with pytest.raises(ConfigError, match=r"'.*fake\.rrd' is not a Rerun recording: it does not start with RRF "
                                          r"\(it starts with b'hell'\)"):
        rrd_files.check_rrd(tmp_path / "fake.rrd")
    (tmp_path / "dir.rrd").mkdir()
    with pytest.raises(ConfigError, match="is not a file"):
        rrd_files.check_rrd(tmp_path / "dir.rrd")
    assert not rrd_files.has_footer(tmp_path / "fake.rrd") and not rrd_files.has_footer(tmp_path / "none.rrd")


def test_repair_refuses_what_it_cannot_do(tmp_path: Path) -> None:
    good = tmp_path / "g.rrd"
    viz = Viz(VizSettings(rrd=str(good), recording_id="g"))
    viz.add_stream("s")
    viz.log_update(report(1))
    viz.close()
    with pytest.raises(ConfigError, match="is the damaged file itself"):
        repair_rrd(good, good)
    with pytest.raises(ConfigError, match=r"must be an \.rrd file; got -o '.*g\.txt'"):
        repair_rrd(good, tmp_path / "g.txt")
    head = tmp_path / "head.rrd"
    head.write_bytes(good.read_bytes()[:200])  # the header, not one whole chunk
    with pytest.raises(ConfigError, match=r"no complete chunk could be read from '.*head\.rrd' \(200 bytes\)"):
        repair_rrd(head)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g.rrd", "head.rrd"]  # no partial copy left behind
    rep = repair_rrd(good)  # an intact file: a verified copy all the same
    assert rep.source_had_footer and rep.output == tmp_path / "g.repaired.rrd" and rep.chunks > 0


def test_daemon_rrd_rotate_s_flag_is_checked() -> None:
    res = subprocess.run([*STREAMID, "daemon", "--rrd", "x.rrd", "--rrd-rotate-s", "-1", "--duration", "1"],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 2
    assert "--rrd-rotate-s" in res.stderr and "got -1" in res.stderr
