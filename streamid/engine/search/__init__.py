"""The search: one run of the coevolution, and runs made in processes.

Owns: the steppable run (:class:`~streamid.engine.search.coevolution.Coevolution`, its exportable
``CoEAState`` and warm-start populations), the binary adaptive harmony search over lags
(:mod:`~streamid.engine.search.harmony`), DE/rand/1/bin over centres and widths (:mod:`~streamid.engine.search.de`),
the batched evaluation of a population (:mod:`~streamid.engine.search.batch`) and the helper process that
evaluates half of it (:mod:`~streamid.engine.search.parallel`, :mod:`~streamid.engine.search._evalhelper`), a run's
candidate models (:mod:`~streamid.engine.search.candidates`), the lag space and direct terms
(:mod:`~streamid.engine.search.lagspace`, :mod:`~streamid.engine.search.feedthrough`) and runs fanned out to
processes (:mod:`~streamid.engine.search.fanout`).

May import: the stdlib, numpy, scipy, threadpoolctl, numba, ``streamid.errors``, ``streamid.threads``,
``streamid.model``, ``streamid.engine.settings`` and ``streamid.engine.fit`` (docs/architecture.md;
tests/test_layout.py).
"""
