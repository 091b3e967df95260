r"""A helper process that evaluates half of every population batch: the second core.

A coevolution generation evaluates its P pairs at once (:class:`~streamid.engine.search.batch.BatchEvaluator`);
at the paper's sizes that batch is ~0.3 ms of numpy calls, too short for a pool of
workers and too many small calls for Python threads (they serialise on the GIL).
:class:`EvalHelper` starts ONE long-lived helper process (``python -m
streamid.engine.search._evalhelper``: a fresh interpreter, never a fork, so a caller holding
a Zenoh session is safe) that shares memory with the caller. For each batch the
caller writes the second half of the members into the shared memory, bumps a
sequence number, evaluates the first half itself, and takes the helper's results
as soon as they are there.

Why this is safe and exact
--------------------------
* **Same numbers.** Both halves run the same :class:`BatchEvaluator` code on the
  same data, each member independently of the others in its batch, with one BLAS
  thread; a run with a helper is bitwise identical to one without (tested), and
  ``same seed, same result`` holds whoever computed what.
* **Never waits on a stalled helper.** When the caller has finished its half and
  the helper has not even started (asleep, or its core is busy with something
  else), or has not finished within the time the caller's own half took, the
  caller evaluates the helper's half itself and ignores whatever the helper
  writes later (every result is tagged with its batch's sequence number). After
  the n-th miss in a row the caller evaluates alone for 2**n batches. A busy
  machine therefore costs a few extra half-batches per run, never a hang.
* **Never slower than one core, decided by measuring.** Whether the split pays
  depends on the machine (measured: slower on some of the project's 2-core VMs,
  faster on others) and on the batch size. Each binding (one run) therefore
  alternates the split path and the caller alone over its first
  ``2 * TRIAL_BATCHES`` batches, keeps the one of lower median time per member,
  and makes the trial again every ``RETRIAL_BATCHES`` batches (the load changes).
  The cost of being wrong is bounded by the trial batches.
* **Handshake through shared memory.** The helper spins on the sequence number
  while batches keep coming (a round trip is ~1.5 us here, a semaphore or pipe
  wake-up tens of us) and sleeps on a pipe after ``spin_s`` without work, so an
  idle helper uses no CPU. The caller writes a batch's inputs before its sequence
  number, the helper its results before its "done" number; x86-64 keeps stores in
  program order as seen by the other core (TSO), which this handshake relies on:
  :meth:`EvalHelper.supported` is false elsewhere and callers then evaluate alone.
* **Only idle CPU.** The helper runs under ``SCHED_IDLE`` (Linux; nice 19
  elsewhere): it never takes CPU time from the caller or any other program,
  it only uses a core that would otherwise idle.
* **Nothing is pickled.** Control words, data and results are plain arrays in
  files of a private folder on ``/dev/shm`` (tmpfs) that both processes map; the
  folder is removed by :meth:`EvalHelper.close`, or by the helper when its
  parent disappears without closing (it then exits).
* **Random numbers drawn ahead.** In its idle time the helper draws the next
  block of uniforms of a run from a copy of the caller's PCG64 state
  (:meth:`HelperBinding.request_uniforms`); the caller takes them and advances
  its own generator past them, so the stream is exactly the caller's.

One helper serves one run at a time: :meth:`EvalHelper.bind` for a new run retires
the previous binding (which then evaluates in its own process).
"""

from __future__ import annotations

import mmap
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from streamid.engine.search.batch import BatchEvaluator
from streamid.engine.search.helper_protocol import (
    _BIND_ACK, _BIND_SEQ, _CAP, _CONTROL_BYTES, _D, _DONE, _DRAW_N, _DRAW_READY, _DRAW_SEQ, _DRAW_STATE, _FLOATS_AT,
    _JOB_BIND, _JOB_N, _JOB_SEQ, _JOB_SHARED, _M, _N, _PATH_AT, _PATH_MAX, _PID, _QUIT, _SLEEPING, _STARTED,
    _UNIFORMS, _layout, _remove_folder, _shm_dir, _unlink, _views)
from streamid.errors import ConfigError, StreamidError

__all__ = ["EvalHelper", "HelperBinding"]

@dataclass
class _Stats:
    offloaded: int = 0
    missed: int = 0
    local: int = 0
    predrawn: int = 0
    chose_split: int = 0  # decisions after a trial (see HelperBinding.TRIAL_BATCHES)
    chose_local: int = 0


class EvalHelper:
    """One helper process evaluating half of each population batch (see the module notes).

    Parameters
    ----------
    spin_s : float
        How long the helper keeps polling for the next batch before it sleeps (s).
    start_timeout_s : float
        How long :meth:`wait_ready` (and the constructor, with ``wait=True``) waits for the helper.
    wait : bool
        Wait until the helper runs before returning (else the first runs may go alone).

    Examples
    --------
    >>> from streamid.engine import identify, CoEAConfig
    >>> with EvalHelper() as helper:                             # doctest: +SKIP
    ...     result = identify(u, y, CoEAConfig(), 0, helper=helper)
    """

    def __init__(self, *, spin_s: float = 0.002, start_timeout_s: float = 30.0, wait: bool = True) -> None:
        if not self.supported():
            raise ConfigError(
                "the evaluation helper needs Linux or another POSIX system on x86-64 "
                f"(store order of the shared-memory handshake); this is {sys.platform} on {platform.machine()}"
            )
        if not (0.0 <= spin_s <= 1.0):
            raise ConfigError(f"spin_s must be in [0, 1] seconds; got {spin_s!r}")
        self.spin_s = float(spin_s)
        self.start_timeout_s = float(start_timeout_s)
        self._dir = tempfile.mkdtemp(prefix="streamid-helper-", dir=_shm_dir())
        self._ctl_path = os.path.join(self._dir, "control")
        with open(self._ctl_path, "wb") as f:
            f.truncate(_CONTROL_BYTES)
        with open(self._ctl_path, "r+b") as f:
            self._ctl_mm = mmap.mmap(f.fileno(), _CONTROL_BYTES)
        self._ctl = np.frombuffer(self._ctl_mm, dtype=np.int64, count=_FLOATS_AT // 8)
        self._fctl = np.frombuffer(self._ctl_mm, dtype=np.float64, count=16, offset=_FLOATS_AT)
        self._lock = threading.Lock()
        self._bind_seq = 0
        self._job_seq = 0
        self._draw_seq = 0
        self._data: tuple[str, mmap.mmap] | None = None
        self.stats = _Stats()
        rfd, self._wake = os.pipe()
        os.set_blocking(self._wake, False)
        env = dict(os.environ)
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            env[var] = "1"
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "streamid.engine.search._evalhelper", self._ctl_path, str(rfd), repr(self.spin_s),
                 str(os.getpid())],
                pass_fds=(rfd,),
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                env=env,
                close_fds=True,
            )
        except BaseException:
            os.close(self._wake)
            self._cleanup_files()
            raise
        finally:
            os.close(rfd)
        self._closed = False
        if wait:
            try:
                self.wait_ready()
            except BaseException:
                self.close()
                raise

    @staticmethod
    def supported() -> bool:
        """True where the shared-memory handshake is valid (POSIX on x86-64)."""
        return os.name == "posix" and platform.machine().lower() in ("x86_64", "amd64")

    @property
    def ready(self) -> bool:
        return not self._closed and int(self._ctl[_PID]) == self._proc.pid

    @property
    def pid(self) -> int:
        return self._proc.pid

    def wait_ready(self, timeout_s: float | None = None) -> None:
        """Block until the helper runs; :class:`StreamidError` if it exits or the timeout passes."""
        deadline = time.monotonic() + (self.start_timeout_s if timeout_s is None else timeout_s)
        while not self.ready:
            code = self._proc.poll()
            if code is not None:
                raise StreamidError(f"the evaluation helper exited at start (exit code {code}); see its stderr above")
            if time.monotonic() > deadline:
                raise StreamidError(
                    f"the evaluation helper did not start within {self.start_timeout_s:g} s (pid {self._proc.pid})"
                )
            time.sleep(0.002)

    def bind(
        self,
        regressors: NDArray[np.float64],
        target: NDArray[np.float64],
        neurons: int,
        capacity: int,
        ridge: float,
        local: BatchEvaluator,
        uniforms: int = 0,
    ) -> HelperBinding:
        """Give the helper one run's data; the returned binding evaluates like ``local``, in two processes.

        ``local`` must be the caller's :class:`BatchEvaluator` on the same data
        (capacity >= ``capacity``); it evaluates the caller's half and any half
        the helper misses. ``uniforms``: the largest block of uniforms the run
        will ask the helper to draw ahead (:meth:`HelperBinding.request_uniforms`).
        """
        if self._closed:
            raise StreamidError("this EvalHelper is closed")
        R = np.ascontiguousarray(regressors, dtype=np.float64)
        n, d = R.shape
        cap = max(1, capacity - (capacity + 1) // 2)
        lay = _layout(n, d, int(neurons), cap, max(0, int(uniforms)))
        with self._lock:
            if self._closed:
                raise StreamidError("this EvalHelper is closed")
            path = os.path.join(self._dir, f"data-{self._bind_seq + 1}")
            with open(path, "wb") as f:
                f.truncate(max(lay["_size"][0], 1))
            with open(path, "r+b") as f:
                mm = mmap.mmap(f.fileno(), max(lay["_size"][0], 1))
            v = _views(mm, lay)
            v["R"][...] = R
            v["target"][...] = target
            old, self._data = self._data, (path, mm)
            if old is not None:
                _unlink(old[0])
            ctl = self._ctl
            ctl[_N], ctl[_D], ctl[_M], ctl[_CAP], ctl[_UNIFORMS] = n, d, int(neurons), cap, max(0, int(uniforms))
            self._fctl[0] = float(ridge)
            raw = path.encode()
            if len(raw) >= _PATH_MAX - _PATH_AT:
                raise ConfigError(f"temporary path too long for the helper: {path!r}")
            self._ctl_mm[_PATH_AT : _PATH_AT + len(raw) + 1] = raw + b"\0"
            self._bind_seq += 1
            ctl[_BIND_SEQ] = self._bind_seq
            self._poke()
            return HelperBinding(self, self._bind_seq, local, v, cap)

    def _poke(self) -> None:
        if self._ctl[_SLEEPING]:
            try:
                os.write(self._wake, b"\0")
            except (BlockingIOError, BrokenPipeError):
                pass

    def close(self) -> None:
        """Stop the helper (within ~1 s, then killed) and remove the shared files."""
        if getattr(self, "_closed", True):
            return
        self._closed = True
        self._ctl[_QUIT] = 1
        try:
            os.write(self._wake, b"\0")
        except OSError:
            pass
        try:
            self._proc.wait(timeout=1.0)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait(timeout=5.0)
        os.close(self._wake)
        self._cleanup_files()

    def _cleanup_files(self) -> None:
        with self._lock:  # never while a bind() is creating the next data file
            _remove_folder(self._dir)

    def __enter__(self) -> EvalHelper:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:  # a forgotten helper still goes away with its owner
        try:
            self.close()
        except Exception:
            pass


class HelperBinding:
    """Evaluates population batches like a :class:`BatchEvaluator`, half of each in the helper."""

    #: Smallest batch split between the two processes.
    MIN_MEMBERS = 4
    #: After the n-th miss in a row the caller evaluates alone for ``2**n`` batches (at most this many):
    #: a helper whose core is busy elsewhere is soon left alone, and retried now and then.
    MAX_BACKOFF = 512
    #: Never slower than one core: the first batches of a binding alternate between the split
    #: path and the caller alone; after this many of each, the one of lower median time per
    #: member is kept, and the trial is made again every ``RETRIAL_BATCHES`` batches.
    TRIAL_BATCHES = 6
    RETRIAL_BATCHES = 2000

    def __init__(self, helper: EvalHelper, seq: int, local: BatchEvaluator, views: dict[str, NDArray[Any]], cap: int):
        self.helper, self.seq, self.local, self.cap = helper, seq, local, cap
        self._v = views
        self._misses = 0
        self._skip = 0
        self._draw: tuple[int, int, tuple[int, int]] | None = None  # (request, count, PCG64 state basis)
        self._timings: tuple[list[float], list[float]] = ([], [])  # seconds per member: (split, alone)
        self._mode: str | None = None  # None while trying both; then "split" or "alone"
        self._since = 0  # batches since the last decision

    def remote(
        self,
        masks: NDArray[np.bool_],
        centres: NDArray[np.float64],
        widths: NDArray[np.float64],
        *,
        shared: bool | None = None,
        timeout_s: float = 10.0,
    ) -> NDArray[np.float64]:
        """Evaluate a whole batch (at most the helper's capacity) in the helper and wait for it.

        A health check of the helper (and what the tests compare with the local
        evaluator); :class:`StreamidError` if the helper does not answer in time.
        """
        p = masks.shape[0]
        if not 0 < p <= self.cap:
            raise ConfigError(f"the helper takes 1 to {self.cap} members per batch; got {p}")
        h, v, ctl = self.helper, self._v, self.helper._ctl
        deadline = time.monotonic() + timeout_s
        while not self._usable():
            if h._closed or h._bind_seq != self.seq or time.monotonic() > deadline:
                raise StreamidError(f"the evaluation helper (pid {h.pid}) did not take this run's data in time")
            time.sleep(0.001)
        if shared is None:
            shared = p == 1 or not np.any(masks[1:] != masks[0])
        v["masks"][:p], v["centres"][:p], v["widths"][:p] = masks, centres, widths
        ctl[_JOB_N], ctl[_JOB_SHARED], ctl[_JOB_BIND] = p, int(shared), self.seq
        h._job_seq += 1
        s = h._job_seq
        ctl[_JOB_SEQ] = s
        h._poke()
        while ctl[_DONE] != s:
            if time.monotonic() > deadline or h._proc.poll() is not None:
                raise StreamidError(f"the evaluation helper (pid {h.pid}) did not answer within {timeout_s:g} s")
            time.sleep(0.0002)
        return np.array(v["out"][:p])

    def request_uniforms(self, rng: np.random.Generator, count: int) -> None:
        """Ask the helper to draw, in its idle time, the next ``count`` uniforms ``rng.random`` would give.

        Only for ``numpy.random.PCG64`` generators (the default); the helper
        starts from a copy of the generator's current state. Take them with
        :meth:`take_uniforms`.
        """
        self._draw = None
        bg = rng.bit_generator
        if type(bg) is not np.random.PCG64 or not 0 < count <= self._v["uniforms"].shape[0] or not self._usable():
            return
        st = bg.state["state"]
        basis = (int(st["state"]), int(st["inc"]))
        words = np.array([w & 0xFFFFFFFFFFFFFFFF for w in (basis[0], basis[0] >> 64, basis[1], basis[1] >> 64)],
                         dtype=np.uint64).view(np.int64)
        h, ctl = self.helper, self.helper._ctl
        ctl[_DRAW_STATE : _DRAW_STATE + 4] = words
        ctl[_DRAW_N] = count
        h._draw_seq += 1
        ctl[_DRAW_SEQ] = h._draw_seq  # after the state and count
        self._draw = (h._draw_seq, count, basis)

    def take_uniforms(self, rng: np.random.Generator, count: int) -> NDArray[np.float64] | None:
        """The block asked for with :meth:`request_uniforms`, if it is exactly ``rng``'s next ``count``
        uniforms and ready; ``rng`` is then advanced past them. Otherwise None (draw them yourself).

        The returned array is the shared buffer: use it before the next request.
        """
        d, self._draw = self._draw, None
        if d is None or d[1] != count or self.helper._ctl[_DRAW_READY] != d[0] or not self._usable():
            return None
        bg = rng.bit_generator
        st = bg.state["state"]
        if type(bg) is not np.random.PCG64 or (int(st["state"]), int(st["inc"])) != d[2]:
            return None  # someone drew from rng since the request
        bg.advance(count)
        self.helper.stats.predrawn += 1
        return self._v["uniforms"][:count]

    def _usable(self) -> bool:
        h = self.helper
        return not h._closed and h._bind_seq == self.seq and int(h._ctl[_BIND_ACK]) == self.seq

    def evaluate(
        self,
        masks: NDArray[np.bool_],
        centres: NDArray[np.float64],
        widths: NDArray[np.float64],
        *,
        return_weights: bool = False,
        shared: bool | None = None,
    ) -> Any:
        """As :meth:`BatchEvaluator.evaluate`; the second half of the members goes to the helper."""
        p = masks.shape[0]
        h = self.helper
        q = p - (p + 1) // 2
        if return_weights or p < self.MIN_MEMBERS or q > self.cap or self._skip > 0 or not self._usable():
            self._skip = max(0, self._skip - 1)
            h.stats.local += 1
            return self.local.evaluate(masks, centres, widths, return_weights=return_weights, shared=shared)
        if self._mode is not None:
            self._since += 1
            if self._since >= self.RETRIAL_BATCHES:
                self._mode, self._timings = None, ([], [])
        split, alone = self._timings
        if self._mode == "alone" or (self._mode is None and len(alone) < len(split)):
            t0 = time.perf_counter()
            h.stats.local += 1
            f_alone = self.local.evaluate(masks, centres, widths, shared=shared)
            if self._mode is None:
                alone.append((time.perf_counter() - t0) / p)
                self._decide()
            return f_alone
        t0 = time.perf_counter()
        f_split = self._split(masks, centres, widths, shared)
        if self._mode is None:
            split.append((time.perf_counter() - t0) / p)
            self._decide()
        return f_split

    def _decide(self) -> None:
        split, alone = self._timings
        if min(len(split), len(alone)) < self.TRIAL_BATCHES:
            return
        faster = float(np.median(split)) < float(np.median(alone))
        self._mode, self._since = ("split" if faster else "alone"), 0
        if faster:
            self.helper.stats.chose_split += 1
        else:
            self.helper.stats.chose_local += 1

    @property
    def mode(self) -> str | None:
        """``"split"`` or ``"alone"`` once decided by measuring; None while the trial runs."""
        return self._mode

    def _split(
        self, masks: NDArray[np.bool_], centres: NDArray[np.float64], widths: NDArray[np.float64], shared: bool | None
    ) -> NDArray[np.float64]:
        """The second half of the batch in the helper, the first here (see the module notes)."""
        p = masks.shape[0]
        h = self.helper
        q = p - (p + 1) // 2
        k = p - q
        if shared is None:
            shared = p == 1 or not np.any(masks[1:] != masks[0])
        v, ctl = self._v, h._ctl
        v["masks"][:q] = masks[k:]
        v["centres"][:q] = centres[k:]
        v["widths"][:q] = widths[k:]
        ctl[_JOB_N] = q
        ctl[_JOB_SHARED] = int(shared)
        ctl[_JOB_BIND] = self.seq
        h._job_seq += 1
        s = h._job_seq
        ctl[_JOB_SEQ] = s  # after the inputs: the helper reads them once it sees s
        h._poke()
        t0 = time.perf_counter()
        f = np.empty(p)
        f[:k] = self.local.evaluate(masks[:k], centres[:k], widths[:k], shared=shared)
        now = time.perf_counter()
        done = ctl[_DONE] == s
        if not done and ctl[_STARTED] == s:  # running: wait at most as long as our own half took
            deadline = now + (now - t0) + 20e-6
            while ctl[_DONE] != s and time.perf_counter() < deadline:
                pass
            done = ctl[_DONE] == s
        if done:
            f[k:] = v["out"][:q]
            self._misses = 0
            h.stats.offloaded += 1
        else:
            f[k:] = self.local.evaluate(masks[k:], centres[k:], widths[k:], shared=shared)
            self._misses += 1
            h.stats.missed += 1
            self._skip = min(self.MAX_BACKOFF, 1 << self._misses)
        return f

