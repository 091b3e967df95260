"""MCAP logs: write/read round trip, damaged files, arrays, rerun's checker, interop decoders."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import rerun_check
from streamid.wire import codec
from streamid import logs as mcaplog
from streamid.wire.codec import SampleBatch
from streamid.errors import LogError



def _messages(n_batches: int = 60, batch: int = 500, stream: str = "dev") -> list[tuple[str, int, bytes]]:
    rng = np.random.default_rng(0)
    out = []
    for i in range(n_batches):
        b = SampleBatch(stream, i, i * batch * 1000, 1000, None,
                        {"u": rng.standard_normal(batch)}, {"y": rng.standard_normal(batch)})
        out.append((b.key(), b.end_ns + 7, codec.encode(b)))
    return out


def _write(path: Path, msgs, **kw) -> None:
    with mcaplog.LogWriter(path, **kw) as w:
        for key, t, data in msgs:
            w.write(key, data, t)


def test_round_trip_byte_exact_and_rerun_check(tmp_path: Path) -> None:
    msgs = _messages()
    extra = [("streamid/dev/status", 10**12, b'{"state": "ok"}'), ("lab/raw/thing", 10**12 + 1, b"\x00\xff")]
    path = tmp_path / "log.mcap"
    _write(path, msgs + extra, chunk_bytes=64 * 1024, metadata={"note": "test"})
    got = list(mcaplog.iter_log(path))
    assert [tuple(m) for m in got] == msgs + extra
    reader = mcaplog.LogReader(path, keys=["streamid/dev/status"])
    assert [m.data for m in reader] == [b'{"state": "ok"}']
    assert reader.metadata["streamid"]["note"] == "test"
    assert reader.metadata["streamid"]["format"] == mcaplog.LOG_FORMAT
    res = rerun_check(path)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "streamid/dev/samples" in res.stdout and "Error" not in res.stdout + res.stderr


def test_schema_registered_decodes_with_official_mcap_protobuf_decoder(tmp_path: Path) -> None:
    pytest.importorskip("mcap_protobuf")
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    path = tmp_path / "log.mcap"
    msgs = _messages(3, 4)
    _write(path, msgs)
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.chunk_count >= 1
        schema = next(iter(summary.schemas.values()))
        assert (schema.name, schema.encoding) == (codec.SCHEMA_NAME, "protobuf")
        decoded = list(reader.iter_decoded_messages())
    assert len(decoded) == 3
    for (schema, channel, message, proto), (key, t, data) in zip(decoded, msgs):
        assert channel.topic == key and channel.message_encoding == "protobuf"
        assert message.log_time == t and message.data == data
        b = codec.decode(data)
        assert message.publish_time == b.t0_ns and message.sequence == b.seq
        assert proto.stream == "dev" and list(proto.inputs[0].values) == b.inputs["u"].tolist()


def test_truncated_file_error_names_file_and_position_and_partial_read(tmp_path: Path) -> None:
    path = tmp_path / "full.mcap"
    msgs = _messages(60, 500)
    _write(path, msgs, chunk_bytes=64 * 1024)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(LogError) as err:
        list(mcaplog.iter_log(cut))
    text = str(err.value)
    assert str(cut) in text and "truncated at byte" in text and "partial" in text
    pos = int(text.split("truncated at byte ")[1].split()[0])
    assert 0 < pos < len(data) * 2 // 3
    reader = mcaplog.LogReader(cut, partial=True)
    got = [tuple(m) for m in reader]
    assert 0 < len(got) < len(msgs)
    assert got == msgs[: len(got)]  # every complete chunk, in order, byte-exact
    assert reader.problem is not None and "truncated" in reader.problem
    assert reader.good_bytes == pos
    # the arrays of the readable part
    arrays = mcaplog.read_log_arrays(cut, partial=True)
    assert len(arrays) == 500 * len(got)


def test_corrupt_chunk_is_named_and_skipped_in_partial_mode(tmp_path: Path) -> None:
    path = tmp_path / "full.mcap"
    msgs = _messages(60, 500)
    _write(path, msgs, chunk_bytes=64 * 1024)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(LogError, match=r"corrupt chunk record at byte \d+"):
        list(mcaplog.iter_log(bad))
    reader = mcaplog.LogReader(bad, partial=True)
    got = [tuple(m) for m in reader]
    assert len(msgs) - 20 < len(got) < len(msgs)  # one chunk (a few messages) lost
    assert all(m in msgs for m in got)
    assert "corrupt chunk" in (reader.problem or "")


@pytest.mark.parametrize("content", [b"", b"not an mcap file at all", b"\x89MCAP0\r\n"])
def test_not_an_mcap_file(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "x.mcap"
    path.write_bytes(content)
    with pytest.raises(LogError, match=str(path)):
        list(mcaplog.iter_log(path))


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(LogError, match="existing MCAP file"):
        mcaplog.LogReader(tmp_path / "nope.mcap")


def test_read_log_arrays_samples_and_split(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    u, y = rng.standard_normal(1234), rng.standard_normal(1234)
    for split in (False, True):
        path = tmp_path / f"a{split}.mcap"
        n_msgs = mcaplog.write_arrays_log(path, "s1", {"u": u}, {"y": y}, period_ns=5_000_000,
                                          t0_ns=10, batch_size=100, split=split)
        assert n_msgs == 13 * (2 if split else 1)
        a = mcaplog.read_log_arrays(path)
        assert a.stream == "s1" and a.period_ns == 5_000_000 and len(a) == 1234
        assert a.t_ns.tolist() == (10 + 5_000_000 * np.arange(1234)).tolist()
        assert a.inputs["u"].tobytes() == u.tobytes() and a.outputs["y"].tobytes() == y.tobytes()
        assert a.u().shape == (1234, 1) and a.y()[:, 0].tobytes() == y.tobytes()


def test_read_log_arrays_aligns_u_and_y_on_common_times(tmp_path: Path) -> None:
    path = tmp_path / "uy.mcap"
    with mcaplog.LogWriter(path) as w:
        bu = SampleBatch("s", 0, 0, 10, None, {"u": np.arange(10.0)}, {})
        by = SampleBatch("s", 0, 30, 10, None, {}, {"y": np.arange(10.0) + 100})
        for b in (bu, by):
            w.write(b.key(), codec.encode(b), b.end_ns)
    a = mcaplog.read_log_arrays(path, "s")
    assert a.t_ns.tolist() == [30, 40, 50, 60, 70, 80, 90]
    assert a.inputs["u"].tolist() == [3, 4, 5, 6, 7, 8, 9]
    assert a.outputs["y"].tolist() == [100, 101, 102, 103, 104, 105, 106]


def test_read_log_arrays_errors(tmp_path: Path) -> None:
    path = tmp_path / "two.mcap"
    with mcaplog.LogWriter(path) as w:
        for s in ("a", "b"):
            b = SampleBatch(s, 0, 0, 10, None, {"u": [1.0]}, {"y": [2.0]})
            w.write(b.key(), codec.encode(b), 0)
    with pytest.raises(LogError, match="exactly one stream"):
        mcaplog.read_log_arrays(path)
    assert mcaplog.read_log_arrays(path, "a").inputs["u"].tolist() == [1.0]
    with pytest.raises(LogError, match="no sample batches of stream 'zz'"):
        mcaplog.read_log_arrays(path, "zz")
    garbage = tmp_path / "garbage.mcap"
    with mcaplog.LogWriter(garbage) as w:
        w.write("streamid/c/samples", b"garbage", 1)
    with pytest.raises(LogError, match="logged at 1 ns is not a valid sample batch"):
        mcaplog.read_log_arrays(garbage)
    over = tmp_path / "overlap.mcap"
    with mcaplog.LogWriter(over) as w:
        for seq, t0 in ((0, 0), (1, 5)):
            b = SampleBatch("s", seq, t0, 10, None, {"u": [1.0, 2.0]}, {"y": [1.0, 2.0]})
            w.write(b.key(), codec.encode(b), t0)
    with pytest.raises(LogError, match="strictly increasing across batches"):
        mcaplog.read_log_arrays(over)


def test_writer_closes_chunks_by_time(tmp_path: Path) -> None:
    """A chunk is closed once its first message is older than the interval (SIGKILL safety)."""
    path = tmp_path / "t.mcap"
    w = mcaplog.LogWriter(path, chunk_interval_s=0.05)
    key, t, data = _messages(1, 10)[0]
    w.write(key, data, t)
    size0 = path.stat().st_size
    import time

    time.sleep(0.06)
    assert w.maybe_flush()
    assert path.stat().st_size > size0 + len(data) // 2  # the chunk reached the file
    assert [m.data for m in mcaplog.LogReader(path, partial=True)] == [data]
    w.close()
    assert [m.data for m in mcaplog.iter_log(path)] == [data]


def test_bundled_logs() -> None:
    assert {"mr_damper", "piezo_p885"} <= set(mcaplog.bundled_logs())
    assert mcaplog.bundled_log("mr_damper").is_file()
    assert mcaplog.bundled_log("mr_damper.mcap") == mcaplog.bundled_log("mr_damper")
    with pytest.raises(LogError, match="bundled log name must be one of"):
        mcaplog.bundled_log("nope")
