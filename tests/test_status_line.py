"""``streamid status``'s table lines: every column under its header, the drift count included, and a line per
output under a stream of several."""

from __future__ import annotations

from streamid.commands.status import HEADER, output_lines, status_line


def test_the_status_line_puts_each_value_under_its_header_and_shows_the_drifts() -> None:
    doc = {"stream": "dev1", "daemon": {"origin": {"daemon": "alpha"}, "sharing": {"members": ["a", "b"]}},
           "version": 12, "champion": {"age_s": 3.2, "current": {"r2_fr_val": 0.9812}}, "drifts": 3, "degraded": False,
           "windows": {"pending_windows": 3, "backlog_s": 2.0}}
    line = status_line(doc)
    for column, value in (("FR R2 now", "0.9812"), ("drifts", "3"), ("backlog", "3 / 2.0 s"), ("daemons", "2")):
        end = HEADER.index(column) + len(column)  # right-aligned under its header
        assert line[end - len(value) : end] == value, (column, line)
    assert line.split()[:3] == ["dev1", "alpha", "v12"] and line.endswith("ok")
    bare = status_line({"stream": "dev2", "degraded": True, "degraded_reason": "no data"})
    assert bare[HEADER.index("drifts") + len("drifts") - 1] == "-" and bare.endswith("DEGRADED: no data")
    assert bare[HEADER.index("backlog") + len("backlog") - 1] == "-"  # the status does not say
    idle = status_line({**doc, "windows": {"pending_windows": 0, "backlog_s": 0.0}})
    assert idle[HEADER.index("backlog") + len("backlog") - 1] == "0"
    assert output_lines(doc) == []  # one output: its champion is on the stream's line


def test_a_stream_of_several_outputs_gets_a_line_per_output_under_its_own() -> None:
    """MIMO (the F-16: three accelerations) has one champion per output: the stream's line shows none of them (the
    first output's alone would pass for the stream's), and each output's line puts its figures under the header."""
    def out(version: int, age: float, fr: float | None, drifts: int) -> dict[str, object]:
        return {"version": version, "drifts": drifts,
                "champion": {"age_s": age, "current": None if fr is None else {"r2_fr_val": fr}}}

    doc = {"stream": "f16", "daemon": {"origin": {"daemon": "alpha"}}, "version": 9, "drifts": 2, "degraded": False,
           "champion": {"age_s": 4.0, "current": {"r2_fr_val": 0.8}},
           "models": {"accel2": out(7, 1.5, 0.9123, 2), "accel1": out(9, 0.5, None, 0), "accel3": out(8, 3.0, 0.9871, 0)}}
    line = status_line(doc)
    champion_end = HEADER.index("champion") + len("champion")
    assert line.split()[:3] == ["f16", "alpha", "v9"] and "0.8" not in line and line[champion_end - 3] == "-", line
    rows = output_lines(doc)
    assert [r.split()[0] for r in rows] == ["accel1", "accel2", "accel3"] and all(r.startswith("  ") for r in rows)
    for row, (version, fr, drifts) in zip(rows, (("v9", "-", "0"), ("v7", "0.9123", "2"), ("v8", "0.9871", "0"))):
        assert row.split()[1] == version, row
        for column, value in (("FR R2 now", fr), ("drifts", drifts)):
            end = HEADER.index(column) + len(column)
            assert row[end - len(value) : end] == value, (column, row)
