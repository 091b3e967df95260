"""``streamid status``'s table line: every column under its header, the drift count included."""

from __future__ import annotations

from streamid.commands.status import HEADER, status_line


def test_the_status_line_puts_each_value_under_its_header_and_shows_the_drifts() -> None:
    doc = {"stream": "dev1", "daemon": {"origin": {"daemon": "alpha"}, "sharing": {"members": ["a", "b"]}},
           "version": 12, "champion": {"age_s": 3.2, "current": {"r2_fr_val": 0.9812}}, "drifts": 3, "degraded": False}
    line = status_line(doc)
    for column, value in (("FR R2 now", "0.9812"), ("drifts", "3"), ("daemons", "2")):
        end = HEADER.index(column) + len(column)  # right-aligned under its header
        assert line[end - len(value) : end] == value, (column, line)
    assert line.split()[:3] == ["dev1", "alpha", "v12"] and line.endswith("ok")
    bare = status_line({"stream": "dev2", "degraded": True, "degraded_reason": "no data"})
    assert bare[HEADER.index("drifts") + len("drifts") - 1] == "-" and bare.endswith("DEGRADED: no data")
