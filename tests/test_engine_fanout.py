"""``fan_out``: results in job order here, on a given executor; the helper only for jobs run here."""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from streamid.engine.search.fanout import fan_out


def _job(job: int, helper: Any = None) -> tuple[int, Any]:
    time.sleep(0.01 * (3 - job))  # later jobs finish first on a pool
    return job * job, helper


def test_in_process_gets_the_helper_and_reports_each_result() -> None:
    seen: list[int] = []
    out = fan_out(_job, [0, 1, 2], 1, helper="h", on_result=lambda r: seen.append(len(r)))
    assert out == [(0, "h"), (1, "h"), (4, "h")] and seen == [1, 2, 3]


def test_an_executor_keeps_the_job_order_and_is_left_running() -> None:
    seen: list[int] = []
    with ThreadPoolExecutor(3) as ex:
        out = fan_out(_job, [0, 1, 2], 1, executor=ex, helper="h", on_result=lambda r: seen.append(len(r)))
        assert out == [(0, None), (1, None), (4, None)] and seen == [1, 2, 3]
        assert ex.submit(_job, 3).result() == (9, None)
