"""Data files that expand far beyond their size on disk (issue 52, item 5): ``.mat`` and MCAP.

Each hostile file is written here, small on disk, in a stream (never its expanded content in memory), and given
to a real ``streamid identify`` process: one line on standard error, exit status 2, no traceback, and the process's
peak RSS (``getrusage`` of its wrapper's only child) under a generous bound far below what the file expands to.
"""

from __future__ import annotations

import math
import struct
import sys
import zlib
from pathlib import Path

import numpy as np
from conftest import STREAMID
from test_bad_files import _max_rss_mb, _one_line_exit_2

from streamid.logs.datafile import load_table
from streamid.logs.mat_files import MAX_MAT_ELEMENTS, MAX_MAT_EXPANDED_BYTES

RSS_BOUND_MB = 300  # generous: a bare `streamid identify` is ~100 MB here; the files expand to 300 MB - 1 GB


def hostile_mat(path: Path, variables: list[tuple[str, int, int]]) -> None:
    """A MATLAB v5 .mat of compressed uint8 zero vectors, written in a stream: (name, rows its header claims, bytes
    its data holds) for each; small on disk whatever it expands to (zeros compress ~1000:1)."""
    head = b"MATLAB 5.0 MAT-file, written by tests/test_hostile_files.py".ljust(116, b" ")
    with open(path, "wb") as fh:
        fh.write(head + bytes(8) + struct.pack("<H", 0x0100) + b"IM")
        for name, rows, n_data in variables:
            nm = name.encode()
            parts = [struct.pack("<IIII", 6, 8, 9, 0),  # array flags: mxUINT8_CLASS
                     struct.pack("<IIii", 5, 8, rows, 1),  # dimensions: rows x 1
                     struct.pack("<II", 1, len(nm)) + nm.ljust(8 * math.ceil(len(nm) / 8), b"\0"),
                     struct.pack("<II", 2, n_data)]  # miUINT8 data of n_data bytes
            pad = (-n_data) % 8
            c = zlib.compressobj(9)
            out = [c.compress(struct.pack("<II", 14, sum(map(len, parts)) + n_data + pad) + b"".join(parts))]
            zero, left = bytes(1 << 20), n_data
            while left:
                k = min(left, 1 << 20)
                out.append(c.compress(zero[:k]))
                left -= k
            out += [c.compress(bytes(pad)), c.flush()]
            comp = b"".join(out)
            fh.write(struct.pack("<II", 15, len(comp)) + comp)


def test_the_builder_writes_files_scipy_reads() -> None:
    import scipy.io

    import tempfile

    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "small.mat"
        hostile_mat(f, [("u", 10, 10), ("y", 13, 13)])
        assert scipy.io.whosmat(str(f)) == [("u", (10, 1), "uint8"), ("y", (13, 1), "uint8")]
        assert scipy.io.loadmat(str(f))["y"].shape == (13, 1)


def test_a_small_mat_of_300_million_uint8_zeros_is_refused_before_conversion(tmp_path: Path) -> None:
    """The issue's file: 292 KB on disk, 2 x 150M uint8 zeros.  Was: 2.9 GB allocated (uint8 -> float64 x 8) and a
    numpy _ArrayMemoryError traceback."""
    p = tmp_path / "zeros.mat"
    hostile_mat(p, [("u", 150_000_000, 150_000_000), ("y", 150_000_000, 150_000_000)])
    assert p.stat().st_size < 400_000
    r, mb = _max_rss_mb([*STREAMID, "identify", str(p), "--input", "u", "--output", "y"])
    line = _one_line_exit_2(r)
    assert "zeros.mat" in line and "hold 300000000 elements" in line and "150000000 x 1 uint8" in line, line
    assert f"read up to {MAX_MAT_ELEMENTS} elements" in line, line
    assert mb < RSS_BOUND_MB, f"peak RSS {mb:.0f} MB"
    print(f"2 x 150M uint8 .mat ({p.stat().st_size} bytes): refused at peak RSS {mb:.0f} MB", file=sys.stderr)


def test_a_mat_whose_header_lies_about_its_size_is_refused_by_what_it_expands_to(tmp_path: Path) -> None:
    """A 1 x 1 variable whose data holds 600 MB of zeros: the shapes pass, the expansion does not."""
    p = tmp_path / "lie.mat"
    hostile_mat(p, [("u", 1, 600_000_000)])
    r, mb = _max_rss_mb([*STREAMID, "identify", str(p), "--input", "u", "--output", "y"])
    line = _one_line_exit_2(r)
    assert "lie.mat" in line and f"expand to more than {MAX_MAT_EXPANDED_BYTES} bytes" in line, line
    assert mb < RSS_BOUND_MB, f"peak RSS {mb:.0f} MB"


def test_integer_matrices_are_read_a_column_at_a_time_to_the_same_numbers(tmp_path: Path) -> None:
    from scipy.io import savemat

    rng = np.random.default_rng(0)
    m = rng.integers(-3000, 3000, size=(500, 3)).astype(np.int16)
    savemat(tmp_path / "m.mat", {"X": m, "u": np.arange(500, dtype=np.uint8).reshape(-1, 1), "note": "text"},
            do_compression=True)
    cols = load_table(tmp_path / "m.mat").columns
    assert sorted(cols) == ["X[0]", "X[1]", "X[2]", "u"]
    for k in range(3):
        assert cols[f"X[{k}]"].dtype == np.float64 and np.array_equal(cols[f"X[{k}]"], m[:, k].astype(np.float64))
    assert np.array_equal(cols["u"], (np.arange(500) % 256).astype(np.float64))


def hostile_mcap(path: Path, expands_to: int, declares: int) -> None:
    """An MCAP file of one zstd chunk of ``expands_to`` zero bytes whose header declares ``declares`` bytes, the
    compression written in a stream (never the expansion in memory)."""
    import zstandard

    from streamid.logs.mcap_files import MAGIC

    def record(op: int, body: bytes) -> bytes:
        return struct.pack("<BQ", op, len(body)) + body

    def string(s: bytes) -> bytes:
        return struct.pack("<I", len(s)) + s

    c = zstandard.ZstdCompressor(level=19).compressobj()
    zero, left, parts = bytes(1 << 20), expands_to, []
    while left:
        k = min(left, 1 << 20)
        parts.append(c.compress(zero[:k]))
        left -= k
    parts.append(c.flush())
    data = b"".join(parts)
    chunk = struct.pack("<QQQI", 0, 0, declares, 0) + string(b"zstd") + struct.pack("<Q", len(data)) + data
    path.write_bytes(MAGIC + record(1, string(b"") + string(b"tests")) + record(6, chunk)
                     + record(0x0F, struct.pack("<I", 0)) + record(2, bytes(20)) + MAGIC)


def test_an_mcap_chunk_declaring_a_gigabyte_is_refused_before_decompression(tmp_path: Path) -> None:
    """The issue's file: ~31 KB, a zstd chunk expanding to 1 GB.  Was: refused only after a 2.07 GB peak."""
    from streamid.logs.mcap_files import MAX_CHUNK_BYTES

    p = tmp_path / "bomb.mcap"
    hostile_mcap(p, 1 << 30, 1 << 30)
    assert p.stat().st_size < 100_000
    r, mb = _max_rss_mb([*STREAMID, "identify", str(p), "--input", "u", "--output", "y"])
    line = _one_line_exit_2(r)
    assert "bomb.mcap: chunk record at byte 30" in line and f"declares {1 << 30} uncompressed bytes" in line, line
    assert "corrupt" not in line, line
    assert f"read up to {MAX_CHUNK_BYTES} bytes" in line, line
    assert mb < RSS_BOUND_MB, f"peak RSS {mb:.0f} MB"
    print(f"1 GB zstd chunk MCAP ({p.stat().st_size} bytes): refused at peak RSS {mb:.0f} MB", file=sys.stderr)


def test_an_mcap_chunk_expanding_beyond_what_it_declares_is_refused_as_soon_as_it_does(tmp_path: Path) -> None:
    """The same gigabyte behind a header declaring 1,000 bytes: decompression stops at 1,001."""
    p = tmp_path / "liar.mcap"
    hostile_mcap(p, 1 << 30, 1000)
    r, mb = _max_rss_mb([*STREAMID, "identify", str(p), "--input", "u", "--output", "y"])
    line = _one_line_exit_2(r)
    assert "liar.mcap" in line and "expands to more than the 1000 bytes it declares" in line, line
    assert mb < RSS_BOUND_MB, f"peak RSS {mb:.0f} MB"
