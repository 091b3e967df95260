"""A real MDF 4 file, as ETAS INCA, Continental's Datalyser and Vector CANape left it (tests/data/asap2_demo_mf4,
from asammdf's source distribution; provenance and licence in its PROVENANCE.md): read onto one grid by the files'
rule, checked against asammdf's own reading; its text channels and an ambiguous display name refused in one line;
converted to a streamid log and read back."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from streamid.commands.main import main
from streamid.errors import DataError
from streamid.logs import read_log_arrays
from streamid.logs.datafile import load_record

asammdf = pytest.importorskip("asammdf")

HERE = Path(__file__).resolve().parent / "data" / "asap2_demo_mf4"
MF4 = HERE / "ASAP2_Demo_V171.mf4"
SHA256 = "40bb473c464f4ec6eda5f6dfc503b7695f3440031553c89f135298e0b0192be9"
SLOW = "ASAM.M.SCALAR.UBYTE.FORM_X_PLUS_4"  # 10 ms raster (group 1), a conversion: physical = raw + 4
FAST = "ASAM.M.SCALAR.FLOAT64.IDENTICAL"  # 1 ms raster (group 4, "Engine_3")


def _asammdf(name: str, raw: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(t_ns, values) of a channel as asammdf reads it, independently of streamid."""
    mdf = asammdf.MDF(str(MF4))
    try:
        s = mdf.get(name, raw=raw)
        return np.round(np.asarray(s.timestamps) * 1e9).astype(np.int64), np.asarray(s.samples, dtype=np.float64)
    finally:
        mdf.close()


def test_the_file_is_the_one_its_provenance_names() -> None:
    assert hashlib.sha256(MF4.read_bytes()).hexdigest() == SHA256
    assert SHA256 in (HERE / "PROVENANCE.md").read_text(encoding="utf-8")


def test_a_10ms_channel_held_on_a_1ms_channels_own_timestamps() -> None:
    rec = load_record(MF4, [SLOW], FAST)
    t_out, y = _asammdf(FAST)
    t_in, u = _asammdf(SLOW)
    raw_t, raw = _asammdf(SLOW, raw=True)
    np.testing.assert_array_equal(u, raw + 4)  # the channel's conversion is applied (the tool's physical values)
    # the grid: the output's own times from the input's first sample on (cut, never extrapolated)
    keep = t_out >= t_in[0]
    assert rec.t_ns is not None and np.array_equal(rec.t_ns, t_out[keep])
    assert rec.period_ns == 1_000_000 and rec.info["clock"] == FAST
    np.testing.assert_array_equal(rec.y, y[keep])
    # each output time holds the input's latest sample at or before it
    held = u[np.searchsorted(t_in, t_out[keep], side="right") - 1]
    np.testing.assert_array_equal(rec.u[:, 0], held)
    assert not any("faster than the output" in n for n in rec.notes)  # the input is the slower one here
    assert any(f"cut {int((~keep).sum())} of the output's {t_out.size} samples" in n for n in rec.notes), rec.notes


@pytest.mark.parametrize(("signal", "said"), [
    ("ASAM.M.SCALAR.UBYTE.VTAB_RANGE_NO_DEFAULT_VALUE", "holds text values, not numbers"),
    ("DI.ASAM.M.SCALAR.UBYTE.IDENTICAL.STATUS_STRING", "is the display name of 2 channels "
     "(ASAM.M.SCALAR.UBYTE.IDENTICAL.STATUS_STRING, ASAM.M.SCALAR.UBYTE.RAT_FUNC.IDENT.STATUS_STRING): name one"),
    ("time", "no channel 'time' (a channel is NAME, or NAME@GROUP where a name repeats); it holds 38 channels (the "
             "first 20 shown): ASAM.M.SCALAR.SBYTE.IDENTICAL.DISCRETE, "),
])
def test_what_cannot_be_a_signal_is_refused_in_one_line(signal: str, said: str) -> None:
    with pytest.raises(DataError) as err:
        load_record(MF4, [signal], FAST)
    assert said in str(err.value) and "\n" not in str(err.value), str(err.value)


def test_a_display_name_of_one_channel_reads_that_channel() -> None:
    a = load_record(MF4, ["DI.ASAM.M.SCALAR.UBYTE.IDENTICAL"], FAST)
    b = load_record(MF4, ["ASAM.M.SCALAR.UBYTE.IDENTICAL"], FAST)
    np.testing.assert_array_equal(a.u, b.u)


def test_record_convert_writes_the_grid_as_a_streamid_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "inca.mcap"
    assert main(["record", "convert", str(MF4), str(log), "--input", SLOW, "--output", FAST, "--stream", "inca"]) == 0
    assert "as stream 'inca'" in capsys.readouterr().out
    rec = load_record(MF4, [SLOW], FAST)
    arr = read_log_arrays(log)
    assert arr.stream == "inca" and np.array_equal(arr.t_ns, rec.t_ns)
    np.testing.assert_array_equal(arr.inputs[SLOW], rec.u[:, 0])
    np.testing.assert_array_equal(arr.outputs[FAST], rec.y)
