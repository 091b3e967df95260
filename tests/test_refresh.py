"""Cheaper warm updates (issue 38 item 2): the champion's weights refreshed by blocked least squares between
coevolution runs, judged as challengers, with a back-off policy visible in the status (streamid.online.refresh)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from streamid import OnlineIdentifier, StreamConfig
from streamid.engine.fit.rbf import activations
from streamid.errors import ConfigError
from streamid.online import RefreshPolicy, StreamState
from streamid.online.head import OutputHead
from streamid.online.refresh import RefreshJob, RefreshTrack, accumulate, coevolve_reason, refreshed_weights
from streamid.sim import get_device
from streamid.transport.updates import parse_model_update

# 200 Hz damper, 4 s windows (800 samples), one every 1 s: consecutive windows overlap, as in the daemon
CFG = StreamConfig(window_s=4.0, update_every_s=1.0, cold_generations=40, warm_generations=10, neurons=6,
                   max_lag_y=3, max_lag_u=3, max_pending_windows=64)
NAMES = {"inputs": ["velocity_cm_s"], "outputs": ["force_N"]}


@pytest.fixture(scope="module")
def damper() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t, u, y = get_device("mr_damper").simulate_seconds(20.0, seed=4)
    return t, u, y


@pytest.fixture(scope="module")
def run(damper: tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[OnlineIdentifier, list]:
    t, u, y = damper
    ident = OnlineIdentifier(CFG, stream="damper", refresh=RefreshPolicy(min_every=3, max_every=6))
    ident.learn_many(t, u, y, **NAMES)
    return ident, ident.update_all()


def test_policy_settings_are_checked_and_name_the_value() -> None:
    with pytest.raises(ConfigError, match=r"min_every must be an integer >= 1 \(updates\); got 0"):
        RefreshPolicy(min_every=0)
    with pytest.raises(ConfigError, match=r"max_every must be >= min_every \(8\); got 4"):
        RefreshPolicy(min_every=8, max_every=4)
    with pytest.raises(ConfigError, match=r"memory_s must be a number of seconds > 0; got -1"):
        RefreshPolicy(memory_s=-1)
    with pytest.raises(ConfigError, match="refresh must be a RefreshPolicy; got dict"):
        OnlineIdentifier(CFG, refresh={"enabled": False})  # type: ignore[arg-type]


def test_blocked_normal_equations_are_the_exact_forgetting_least_squares(run: tuple[OnlineIdentifier, list],
                                                                          damper: tuple[np.ndarray, ...]) -> None:
    ident, _ = run
    model = ident.model
    assert model is not None
    t, u, y = damper
    u2, y2 = u[:1200].reshape(-1, 1), y[:1200]
    period = int(t[1] - t[0])
    memory_s = 2.0
    # in three blocks (the rows newer than the previous block's end each time), then all at once
    ne = None
    for end in (400, 401, 1200):
        ne = accumulate(ne, model, u2[:end], y2[:end], 0, period, memory_s)
    once = accumulate(None, model, u2, y2, 0, period, memory_s)
    assert ne is not None and ne.rows == once.rows == 1200 - model.max_lag
    np.testing.assert_allclose(ne.a, once.a, rtol=1e-10, atol=1e-12)
    # the same as a weighted least squares solved directly (rows weighted exp(-age / memory_s))
    r, yn = model.regressor_rows(u2, y2)
    x = activations(r, model.centres, model.widths)
    x = np.hstack([x, model.linear_rows(u2, y2), np.ones((x.shape[0], 1))]) if model.linear is not None else x
    age_s = (x.shape[0] - 1 - np.arange(x.shape[0])) * period / 1e9
    sw = np.sqrt(np.exp(-age_s / memory_s))
    direct = np.linalg.lstsq(x * sw[:, None], yn * sw, rcond=None)[0]
    got = refreshed_weights(once, 1e-12)
    assert got is not None
    # the optimum is flat along the activations' near-collinear directions: compare the weighted residuals
    rss_direct, rss_got = (float(np.sum((sw * (yn - x @ w)) ** 2)) for w in (direct, got))
    rss_mean = float(np.sum((sw * (yn - np.average(yn, weights=sw**2))) ** 2))
    assert rss_direct <= rss_got <= rss_direct + 1e-6 * rss_mean, (rss_direct, rss_got, rss_mean)
    # another champion's equations are not reused: the rows start again
    other = dataclasses.replace(model, widths=model.widths * 1.1)
    again = accumulate(ne, other, u2, y2, 0, period, memory_s)
    assert again.rows == 1200 - model.max_lag and again.basis != ne.basis
    # a stream whose clock went back (a publisher restarted it): the rows start again, none is taken for seen
    reset = accumulate(ne, model, u2[:600], y2[:600], 0, period, memory_s)
    assert reset.rows == 600 - model.max_lag and reset.through_t_ns == 599 * period


def test_updates_between_coevolution_runs_refresh_the_weights_and_say_so(run: tuple[OnlineIdentifier, list]) -> None:
    ident, ups = run
    assert len(ups) == 17  # (20 s - 4 s) / 1 s + 1 windows
    kinds = [(up.document or {}).get("update") for up in ups if up.document is not None]
    assert ups[0].accepted and ups[0].code == "first" and ups[0].document["update"] == "identified"  # type: ignore[index]
    assert kinds.count("refreshed") >= 8 and kinds.count("identified") >= 3
    for up in ups:
        doc = up.document
        if doc is None or doc["update"] != "refreshed":
            continue
        # a refresh is a challenger: judged against the champion on the same held-out data
        assert up.decision is not None and up.decision.champion is not None
        assert up.decision.champion["version"] == doc["refreshed_from"]
        assert up.outcome.generations == 0 and up.model is not None
        champion_before = up.decision.champion["version"]
        assert up.model.metrics["update"] == "refreshed" and up.model.metrics["refreshed_from_version"] == champion_before
        assert up.model.metrics["refreshed_samples"] > 0
        # the champion's band (a refresh keeps the structure; docs/method.md, "Online"), judged on this window
        src_model = next(x.model for x in ups if x.accepted and x.version == champion_before)
        assert up.model.interval is not None and src_model is not None and up.model.interval == src_model.interval
        assert up.outcome.summary is not None and 0.0 <= up.outcome.summary.metrics["interval_coverage_val"] <= 1.0
        # the structure is kept: same lags, centres, widths; only weights (and the linear part) change
        assert up.accepted == (up.version > champion_before)
        parsed = parse_model_update(up.payload)  # what a subscriber reads
        assert parsed.document["update"] == "refreshed" and parsed.generations == 0
    refreshed_accepted = [up for up in ups if up.accepted and up.document["update"] == "refreshed"]  # type: ignore[index]
    for up in refreshed_accepted:  # a new version, its structure that of the version it refreshed
        src = next(x for x in ups if x.accepted and x.version == up.document["refreshed_from"])  # type: ignore[index]
        assert up.model is not None and src.model is not None
        assert up.model.regressors == src.model.regressors and np.array_equal(up.model.centres, src.model.centres)
        assert not np.array_equal(up.model.weights, src.model.weights)


def test_the_back_off_doubles_while_the_champion_keeps_winning_and_the_status_shows_the_policy(
        run: tuple[OnlineIdentifier, list]) -> None:
    ident, ups = run
    runs = [up for up in ups if up.document is not None and up.document["update"] == "identified"]
    st = ident.status()
    r = st["refresh"]
    assert r["identified"] == len(runs) and r["refreshed"] == len(ups) - len(runs)
    assert r["policy"] == {"enabled": True, "min_every": 3, "max_every": 6, "memory_s": 30.0, "ridge": 1e-9}
    assert r["next"] in ("refresh", "coevolution") and st["models"]["force_N"]["refresh"]["identified"] == len(runs)
    # the interval after each run: min_every after an accepted run, doubled (up to max_every) after a lost one
    every = 3
    gaps = []
    for a, b in zip(runs, runs[1:]):
        gaps.append((ups.index(b) - ups.index(a), a.code))
    for gap, code in gaps:
        every = 3 if code != "not_better" else min(6, 2 * every)
        assert gap == every, gaps
    assert any(code == "not_better" for _, code in gaps)  # the back-off was exercised


def test_a_coevolution_run_comes_at_once_on_drift_failure_or_failed_revalidation(run: tuple[OnlineIdentifier, list],
                                                                                 damper: tuple[np.ndarray, ...]) -> None:
    ident, _ = run
    model = ident.model
    assert model is not None
    track = RefreshTrack(RefreshPolicy(), every=8, due_in=5)
    head = OutputHead("force_N", version=3, model=model)
    assert coevolve_reason(track, head, None, CFG) == ""  # scheduled refreshes left
    assert coevolve_reason(track, dataclasses.replace(head, escalate=True), None, CFG) == "drift"
    assert "failed" in coevolve_reason(track, dataclasses.replace(head, failures_in_row=1), None, CFG)
    bad = dataclasses.replace(head, current={"r2_fr_val": 0.2, "r2_osa_val": 0.99})
    assert coevolve_reason(track, bad, None, CFG) == "the champion failed its re-validation"
    assert coevolve_reason(track, dataclasses.replace(head, model=None), None, CFG) == "no champion yet"
    assert coevolve_reason(RefreshTrack(RefreshPolicy(enabled=False)), head, None, CFG) == "refreshes disabled"
    # a loaded caller defers a scheduled run (a refresh instead), at most max_every times in a row; never a forced one
    due = RefreshTrack(RefreshPolicy(min_every=2, max_every=3), every=2, due_in=0)
    assert coevolve_reason(due, head, None, CFG) == "scheduled (every 2 updates)"
    assert [due.defer("scheduled (every 2 updates)") for _ in range(4)] == [True, True, True, False]
    assert not due.defer("drift") and due.summary("")["deferred"] == 3
    due.after(refresh=False, code="not_better", accepted=False, normal=None)  # the run happened: deferrals reset
    assert due.deferred == 0 and due.every == 3 and due.due_in == 2
    # a refreshed challenger refused below the floors: the next update reruns the coevolution
    track.after(refresh=True, code="validation", accepted=False, normal=None)
    assert coevolve_reason(track, head, None, CFG).startswith("a refreshed challenger was refused (validation)")
    # a refresh on a window whose input is constant is dropped like a coevolution run's
    t, u, y = damper
    w_ident = OnlineIdentifier(CFG, stream="flat")
    w_ident.learn_many(t[:800], np.ones(800), y[:800], **NAMES)
    window = w_ident._buffer.take()
    assert window is not None
    job = RefreshJob(window, CFG, 4, output="force_N", champion=model, champion_version=3)
    out = job.run()
    assert out.kind == "dropped" and out.code == "constant_signal" and "constant" in out.reason


def test_the_schedule_and_equations_resume_from_the_state(run: tuple[OnlineIdentifier, list],
                                                          damper: tuple[np.ndarray, ...]) -> None:
    ident, _ = run
    state = StreamState.from_json(ident.state().to_json())
    assert state.refresh["force_N"]["normal"] is not None
    again = OnlineIdentifier.from_state(state, CFG, refresh=RefreshPolicy(min_every=3, max_every=6))
    a, b = again.status()["refresh"], ident.status()["refresh"]
    assert a == b
    assert again._tracks["force_N"].normal.a.tolist() == ident._tracks["force_N"].normal.a.tolist()  # exact
    # an unusable part leaves a fresh track (the next update is a coevolution run) and says why
    broken = dataclasses.replace(state, refresh={"force_N": {**state.refresh["force_N"], "every": "x"}})
    fresh = OnlineIdentifier(CFG, stream="damper")
    warnings = fresh.restore(broken)
    assert any("refresh state" in w for w in warnings) and fresh.status()["refresh"]["identified"] == 0
    json.dumps(ident.status())  # JSON-ready


def test_a_loaded_caller_gets_a_refresh_where_a_scheduled_run_was_due(damper: tuple[np.ndarray, ...]) -> None:
    t, u, y = damper
    policy = RefreshPolicy(min_every=1, max_every=2)  # min_every 1: every update is a scheduled run
    ident = OnlineIdentifier(CFG, stream="damper", refresh=policy)
    ident.learn_many(t[:1400], u[:1400], y[:1400], **NAMES)  # 4 windows
    first = ident.update()
    assert first is not None and first.accepted and not isinstance(first.outcome, type(None))
    assert not ident.next_is_refresh() and ident.next_is_refresh(defer_scheduled=True)
    job = ident.next_job(defer_scheduled=True)
    assert isinstance(job, RefreshJob)  # deferred: a refresh
    ident.finish(job, job.run())
    again = ident.next_job(defer_scheduled=False)
    assert again is not None and not isinstance(again, RefreshJob)  # not loaded: the run comes
    ident.abandon(again)
    assert ident.status()["refresh"]["deferred"] == 1


def test_a_refresh_keeps_the_linear_parts_autoregression_stable() -> None:
    # tests/test_online_identifier.py's damper: its first champion is bounded (streamid.engine.choice.stability), and the
    # joint least squares of the next windows split its fit into autoregressions of roots 1.72 and 3.45 (measured
    # before this rule: both refreshes failed). Now the output terms are the linear part's own solution.
    from test_online_identifier import CFG as CFG_OI, NAMES as NAMES_OI

    from streamid.engine.choice.stability import is_bounded, radius
    from streamid.online.refresh import RefreshOutcome, own_autoregression

    t, u, y = get_device("mr_damper").simulate_seconds(8.2, seed=3)
    ident = OnlineIdentifier(CFG_OI, stream="damper")
    ident.learn_many(t[:1600], u[:1600], y[:1600], **NAMES_OI)
    ups = ident.update_all()
    champ = ups[0].outcome.model
    assert champ is not None and champ.linear is not None and is_bounded(champ)
    refreshes = [up.outcome for up in ups if isinstance(up.outcome, RefreshOutcome)]
    assert len(refreshes) == 3 and all(o.model is not None and is_bounded(o.model) for o in refreshes)
    first = refreshes[0]
    assert first.normal is not None and first.model is not None
    M = first.model.neurons  # the structure of the champion it refreshed (its long linear part, if any)
    regs = first.model.linear_regressors or first.model.regressors
    joint = refreshed_weights(first.normal, RefreshPolicy().ridge)
    assert joint is not None and radius(regs, joint[M:-1]) > 1.0  # the case: the joint solution is unstable
    z = own_autoregression(first.normal, first.model, RefreshPolicy().ridge)
    assert z is not None and radius(regs, z[M:-1]) < 1.0
    np.testing.assert_array_equal(first.model.weights, z[:M])  # what was published is that solution


def test_a_live_backlog_is_refreshed_in_order_before_a_scheduled_run(damper: tuple[np.ndarray, ...]) -> None:
    """A live stream (samples arriving at 1 x stream time) that fell behind keeps its windows (max_pending_s) and
    works through them in order by refreshes; the scheduled coevolution run waits until the backlog is drained."""
    t, u, y = damper
    ident = OnlineIdentifier(CFG, stream="damper", refresh=RefreshPolicy(min_every=1, max_every=2))  # every update due
    for a in range(0, 2000, 200):  # 10 s at 200 Hz, one chunk a second, each arriving as its last sample is taken
        ident.learn_many(t[a:a + 200], u[a:a + 200], y[a:a + 200], now_ns=int(t[a + 199]) + 10**9, **NAMES)
    w = ident.status(now_ns=int(t[1999]) + 4 * 10**9)["windows"]
    assert w["live"] and w["pending_windows"] == 7 and w["coalesced"] == 0  # windows ending at 4, 5, ..., 10 s
    assert w["backlog_s"] == pytest.approx(6.0, abs=0.01) and w["backlog_age_s"] == pytest.approx(9.0, abs=0.01)
    assert w["pending_bytes"] == 2000 * 2 * 8  # the seven overlapping windows' 10 s of samples, held once
    ups = ident.update_all()
    assert [up.window.number for up in ups] == sorted(up.window.number for up in ups) and len(ups) == 7
    kinds = [up.document["update"] if up.document else up.kind for up in ups]
    assert kinds == ["identified"] + ["refreshed"] * 5 + ["identified"], kinds
    st = ident.status()
    assert st["refresh"]["deferred_backlog"] == 5 and st["windows"]["backlog_s"] == 0.0
    assert st["windows"]["backlog_age_s"] is None


def test_a_shortened_first_run_only_for_a_streams_first_update(damper: tuple[np.ndarray, ...]) -> None:
    """A caller with other streams waiting may shorten a stream's first run (first_generations); it is not an
    escalation, and later runs have their usual generations."""
    t, u, y = damper
    ident = OnlineIdentifier(CFG, stream="damper", refresh=RefreshPolicy(min_every=1, max_every=2))
    ident.learn_many(t[:1400], u[:1400], y[:1400], **NAMES)  # 4 windows
    job = ident.next_job(first_generations=10)
    assert job is not None and job.generations == 10 and job.shortened_first
    up = ident.finish(job, job.run())
    assert up.document is not None and up.document["generations"] == 10 and up.accepted
    nxt = ident.next_job(first_generations=10)  # the first update has finished: not shortened again
    assert nxt is not None and not nxt.shortened_first and nxt.generations is None
    out = nxt.run()
    assert isinstance(nxt, RefreshJob) or out.generations == CFG.warm_generations


def test_a_live_stream_left_without_a_model_keeps_only_its_newest_window(damper: tuple[np.ndarray, ...]) -> None:
    """A live backlog is kept only while it can be worked through: a stream without a model whose last update
    failed keeps only its newest window, and the status says so (windows.backlog_kept)."""
    from streamid.online.update import Outcome

    t, u, y = damper
    ident = OnlineIdentifier(CFG, stream="damper")

    def feed(a: int, b: int) -> None:  # 1 s chunks at 200 Hz, each arriving as its last sample is taken: live
        for k in range(a, b, 200):
            ident.learn_many(t[k:k + 200], u[k:k + 200], y[k:k + 200], now_ns=int(t[k + 199]) + 10**9, **NAMES)

    feed(0, 1000)  # windows ending at 4 and 5 s
    assert ident.status()["windows"]["backlog_kept"] is True
    job = ident.next_job()
    assert job is not None
    ident.finish(job, Outcome("failed", "injected", "exception"))
    assert ident.status()["windows"]["backlog_kept"] is False
    feed(1000, 2000)  # windows ending at 6 ... 10 s: each replaces the one waiting
    w = ident.status()["windows"]
    assert w["live"] and w["pending_windows"] == 1 and w["coalesced"] == 5


def test_the_rerun_diagnostics_say_a_refresh_is_a_refresh(run: tuple[OnlineIdentifier, list], tmp_path: Path) -> None:
    """The champion's text and the events of a real .rrd, read back: a refresh says which version it re-solved,
    as `streamid watch` does, never ``warm · G=0`` (it runs no coevolution)."""
    import pyarrow as pa
    from rerun.chunk import RrdReader

    from streamid.daemon.report import update_report
    from streamid.viz.reports import model_markdown
    from streamid.viz.rerun_view import Viz, VizSettings

    _, ups = run
    drawn = [up for up in ups if up.outcome.summary is not None]
    rrd = tmp_path / "refresh.rrd"
    viz = Viz(VizSettings(rrd=str(rrd)))
    viz.add_stream("damper")
    reports = [update_report("damper", up, None) for up in drawn]
    for r in reports:
        viz.log_update(r)
    viz.close()
    for up, r in zip(drawn, reports):
        doc = up.document or {}
        head = model_markdown(r).splitlines()[0]
        if doc.get("update") == "refreshed":
            assert r.refreshed_from == doc["refreshed_from"] and f" · refreshed from v{doc['refreshed_from']} · " in head
        else:
            assert r.refreshed_from is None and f" · {'warm' if up.outcome.warm else 'cold'} · G=" in head
    chunks = RrdReader(rrd).stream().filter(content="/streams/damper/events").to_chunks()
    texts = [t for c in chunks for row in c.to_record_batch().column("TextLog:text").to_pylist()
             for t in (row if isinstance(row, list) else [row])]
    refreshes = sum((up.document or {}).get("update") == "refreshed" for up in drawn)
    assert refreshes >= 8 and sum("(refreshed from v" in t for t in texts) == refreshes
    assert not any("G=0" in t for t in texts) and any("(cold, G=40" in t for t in texts)
    # the update-time panel: every update's time, the rejected challengers' too (not only the published models')
    times = []
    for c in RrdReader(rrd).stream().filter(content="/streams/damper/history/identification_s").to_chunks():
        b = c.to_record_batch()
        if "Scalars:scalars" in b.schema.names:
            times += zip(b.column("stream_time").cast(pa.int64()).to_pylist(), b.column("Scalars:scalars").to_pylist())
    assert sum(not r.accepted for r in reports) >= 3
    assert [v[0] for _, v in sorted(times)] == [r.identification_s for r in sorted(reports, key=lambda r: r.window_end_ns)]
