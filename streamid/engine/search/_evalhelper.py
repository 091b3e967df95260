"""The evaluation helper process: ``python -m streamid.engine.search._evalhelper CONTROL FD SPIN_S OWNER_PID``.

Started by :class:`streamid.engine.search.parallel.EvalHelper` (whose module notes
describe the handshake); not meant to be run by hand. It maps the control file,
then loops: take a new run's data (bind), evaluate a posted batch, draw a block
of uniforms ahead in chunks, spin ``SPIN_S`` after the last work, then sleep on
the wake-up pipe. It exits on the quit word or when its owner is gone (then
removing the shared files the owner left): its parent is no longer ``OWNER_PID``
(also at its start: an owner killed while the helper imported), or the wake-up
pipe reads end-of-file (every write end closed).
"""

from __future__ import annotations

import mmap
import os
import select
import signal
import sys
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.engine.search.helper_protocol import (
    _BIND_ACK, _BIND_SEQ, _CAP, _CONTROL_BYTES, _D, _DONE, _DRAW_CHUNK, _DRAW_N, _DRAW_READY, _DRAW_SEQ, _DRAW_STATE,
    _ERRORS, _FLOATS_AT, _JOB_BIND, _JOB_N, _JOB_SEQ, _JOB_SHARED, _M, _N, _PATH_AT, _PATH_MAX, _PID, _QUIT,
    _SLEEPING, _STARTED, _UNIFORMS, _layout, _remove_folder, _views)
from streamid.engine.search.batch import BatchEvaluator


def _lowest_priority() -> None:
    """Run only on otherwise idle CPU time (Linux SCHED_IDLE; elsewhere nice 19).

    The helper must never take a core from the caller, from the caller's other
    threads (a daemon's ingestion) or from other programs: when it gets no CPU
    the caller simply evaluates alone.
    """
    if sys.platform == "linux":
        try:
            os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
            return
        except OSError:
            pass
    try:
        os.nice(19)
    except OSError:
        pass


def serve(ctl_path: str, wake_fd: int, spin_s: float, owner_pid: int | None = None) -> int:
    from streamid.engine.fit.blas import one_blas_thread

    # The owner's pid comes from the owner: one read here after the imports would miss an owner killed during them
    # (the helper then took init for its parent and never saw it go; found spinning on the pipe's EOF 38 min later).
    parent = os.getppid() if owner_pid is None else owner_pid
    if os.getppid() != parent:  # the owner is gone already: remove what it left
        _remove_folder(os.path.dirname(ctl_path))
        return 0

    with open(ctl_path, "r+b") as f:
        cmm = mmap.mmap(f.fileno(), _CONTROL_BYTES)
    ctl = np.frombuffer(cmm, dtype=np.int64, count=_FLOATS_AT // 8)
    fctl = np.frombuffer(cmm, dtype=np.float64, count=16, offset=_FLOATS_AT)
    _lowest_priority()
    bound, last = 0, int(ctl[_JOB_SEQ])
    ev: BatchEvaluator | None = None
    v: dict[str, NDArray[Any]] = {}
    cap = 0
    active_until = 0.0
    drawn = drawing = int(ctl[_DRAW_SEQ])
    gen, want, pos = np.random.default_rng(0), 0, 0
    ctl[_PID] = os.getpid()
    with one_blas_thread():
        while not ctl[_QUIT]:
            b = int(ctl[_BIND_SEQ])
            if b != bound:
                bound, ev = b, None
                try:
                    raw = bytes(cmm[_PATH_AT:_PATH_MAX]).split(b"\0", 1)[0].decode()
                    n, d, m, cap, nu = (int(ctl[i]) for i in (_N, _D, _M, _CAP, _UNIFORMS))
                    lay = _layout(n, d, m, cap, nu)
                    with open(raw, "r+b") as f:
                        dmm = mmap.mmap(f.fileno(), max(lay["_size"][0], 1))
                    v = _views(dmm, lay)
                    ev = BatchEvaluator(v["R"], v["target"], m, cap, float(fctl[0]))
                    ctl[_BIND_ACK] = b
                except (OSError, ValueError):  # a newer bind already replaced this one
                    ctl[_BIND_ACK] = -b
                active_until = time.perf_counter() + spin_s
                continue
            s = int(ctl[_JOB_SEQ])
            if s != last:
                last = s
                if ev is not None and ctl[_JOB_BIND] == bound:
                    ctl[_STARTED] = s
                    q = int(ctl[_JOB_N])
                    if 0 < q <= cap:
                        try:
                            v["out"][:q] = ev.evaluate(v["masks"][:q], v["centres"][:q], v["widths"][:q],
                                                       shared=bool(ctl[_JOB_SHARED]))
                            ctl[_DONE] = s  # after the results
                        except Exception:  # inputs torn by a batch the caller already took back
                            ctl[_ERRORS] += 1
                active_until = time.perf_counter() + spin_s
                continue
            r = int(ctl[_DRAW_SEQ])
            if ev is not None and r != drawn:
                if r != drawing:  # a new request: start from the caller's generator state
                    w = ctl[_DRAW_STATE : _DRAW_STATE + 4].view(np.uint64)
                    want = int(ctl[_DRAW_N])
                    bitgen = np.random.PCG64()
                    bitgen.state = {
                        "bit_generator": "PCG64",
                        "state": {"state": int(w[0]) | int(w[1]) << 64, "inc": int(w[2]) | int(w[3]) << 64},
                        "has_uint32": 0,
                        "uinteger": 0,
                    }
                    gen, drawing, pos = np.random.Generator(bitgen), r, 0
                    if not 0 < want <= v["uniforms"].shape[0]:
                        drawn = r
                        continue
                stop = min(want, pos + _DRAW_CHUNK)  # in chunks: a batch never waits long for us
                gen.random(out=v["uniforms"][pos:stop])
                pos = stop
                if pos == want and int(ctl[_DRAW_SEQ]) == r:
                    ctl[_DRAW_READY] = r  # after the numbers
                    drawn = r
                active_until = time.perf_counter() + spin_s
                continue
            if time.perf_counter() < active_until:
                continue
            ctl[_SLEEPING] = 1
            if ctl[_JOB_SEQ] == last and ctl[_BIND_SEQ] == bound and not ctl[_QUIT]:
                ready, _, _ = select.select([wake_fd], [], [], 0.25)
                if ready:
                    try:
                        if not os.read(wake_fd, 4096):  # end of file: every write end is closed, the owner is gone
                            _remove_folder(os.path.dirname(ctl_path))
                            return 0
                    except BlockingIOError:
                        pass
            ctl[_SLEEPING] = 0
            if os.getppid() != parent:  # the caller died without closing: remove what it left
                _remove_folder(os.path.dirname(ctl_path))
                return 0
    return 0


if __name__ == "__main__":
    # Ctrl-C in a terminal reaches the whole process group; the owner decides when this process ends (it closes
    # it, or this loop sees the owner gone), so the helper neither dies early nor prints a traceback.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    sys.exit(serve(sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4]) if len(sys.argv) > 4 else None))
