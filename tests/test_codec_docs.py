"""The publishing examples of docs/wire-format.md work as printed (only endpoint and count changed)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import endpoint
from recorders import Recorder
from streamid.wire import codec
from streamid import logs as mcaplog
from streamid.transport import ZenohSettings

DOC = Path(__file__).resolve().parents[1] / "docs" / "wire-format.md"


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", DOC.read_text(encoding="utf-8"), flags=re.S)


def test_hand_written_publisher_example_over_zenoh(tmp_path: Path) -> None:
    code = _python_blocks()[0]
    assert "import streamid" not in code and "from streamid" not in code
    assert code.count("tcp/127.0.0.1:7447") == 1 and "range(100)" in code
    ep = endpoint()
    code = code.replace("tcp/127.0.0.1:7447", ep).replace("range(100)", "range(5)")
    code = code.replace("time.sleep(0.05)", "time.sleep(0.01)")
    # publish only once the recorder's subscription is known (as a daemon would be running already)
    code = code.replace("    for seq in", "    t = time.monotonic()\n    while not pub.matching_status.matching and time.monotonic() - t < 20:\n"
                                          "        time.sleep(0.01)\n    for seq in", 1)
    script = tmp_path / "publisher.py"
    script.write_text(code)
    out = tmp_path / "rec.mcap"
    with Recorder(out, ZenohSettings(listen=(ep,))) as rec:
        res = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60)
        assert res.returncode == 0, res.stderr
        assert rec.wait_for(5, 10.0)
    msgs = list(mcaplog.iter_log(out))
    assert [m.key for m in msgs] == ["streamid/mydevice/samples"] * 5
    batches = [codec.decode(m.data) for m in msgs]
    assert [b.seq for b in batches] == [0, 1, 2, 3, 4]
    for b in batches:
        assert len(b) == 1000 and b.period_ns == 50_000 and b.stream == "mydevice"
        assert np.allclose(b.outputs["y"], np.tanh(b.inputs["u"]))


def test_protobuf_class_example_matches_hand_written(tmp_path: Path) -> None:
    pytest.importorskip("google.protobuf")
    # stand-in for what `protoc --python_out=. sample_batch.proto` generates
    (tmp_path / "sample_batch_pb2.py").write_text(
        "from google.protobuf import descriptor_pb2, descriptor_pool, message_factory\n"
        "from streamid.wire.codec import FILE_DESCRIPTOR_SET\n"
        "_pool = descriptor_pool.DescriptorPool()\n"
        "for _f in descriptor_pb2.FileDescriptorSet.FromString(FILE_DESCRIPTOR_SET).file:\n"
        "    _pool.Add(_f)\n"
        "SampleBatch = message_factory.GetMessageClass(_pool.FindMessageTypeByName('streamid.SampleBatch'))\n"
    )
    sys.path.insert(0, str(tmp_path))
    try:
        hand, proto = {}, {}
        first = _python_blocks()[0]
        exec(first[: first.index("conf = zenoh.Config()")], hand)  # noqa: S102 - our own docs
        exec(_python_blocks()[1], proto)  # noqa: S102
    finally:
        sys.path.remove(str(tmp_path))
        sys.modules.pop("sample_batch_pb2", None)
    args = ("mydevice", 3, 1_700_000_000_000_000_000, 50_000, [0.5, -1.0, 2.0], [1.0, 2.0, 3.0])
    a, b = hand["batch"](*args), proto["batch"](*args)
    assert a == b
    d = codec.decode(a)
    assert (d.stream, d.seq, d.t0_ns, d.period_ns) == args[:4]
    assert d.inputs["u"].tolist() == args[4] and d.outputs["y"].tolist() == args[5]
