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



def test_the_champions_interval_on_current_data_is_in_two_columns_and_its_absence_a_dash() -> None:
    def champ(**current: object) -> dict[str, object]:
        return {"age_s": 1.0, "current": {"r2_fr_val": 0.97, **current}}

    def cell(line: str, column: str, width: int) -> str:
        end = HEADER.index(column) + len(column)  # right-aligned under its header
        return line[end - width : end].strip()

    doc = {"stream": "dev1", "version": 3, "champion": champ(interval_coverage_val=0.912, outside_domain_val=0.034)}
    line = status_line(doc)
    assert (cell(line, "band cover", 10), cell(line, "outside", 7), cell(line, "FR R2 now", 9)) == \
        ("91.2 %", "3.4 %", "0.9700"), line
    # absent, or not a share: a dash, no error
    for hostile in ({}, {"interval_coverage_val": None}, {"interval_coverage_val": "0.9"}, {"interval_coverage_val": True},
                    {"interval_coverage_val": 1.5, "outside_domain_val": -0.1}, {"outside_domain_val": [0.1]}):
        line = status_line({**doc, "champion": champ(**hostile)})
        assert (cell(line, "band cover", 10), cell(line, "outside", 7)) == ("-", "-"), (hostile, line)
    assert cell(status_line({"stream": "x", "champion": {"current": "x"}}), "band cover", 10) == "-"
    # several outputs: each output's champion in its own row, under the same headers
    mimo = {"stream": "f16", "version": 9, "models": {
        "a1": {"version": 9, "champion": champ(interval_coverage_val=1, outside_domain_val=0)},
        "a2": {"version": 8, "champion": champ()}}}
    rows = output_lines(mimo)
    assert [r.split()[:2] for r in rows] == [["a1", "v9"], ["a2", "v8"]]
    assert [(cell(r, "band cover", 10), cell(r, "outside", 7)) for r in rows] == [("100.0 %", "0.0 %"), ("-", "-")]
