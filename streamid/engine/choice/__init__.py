"""The choice among candidates: which of the runs' models is kept, and what is made of it.

Owns: the candidates' free-run scores and the range guard (:mod:`~streamid.engine.choice.scores`), the
selection (:mod:`~streamid.engine.choice.selection`), complexity (:mod:`~streamid.engine.choice.complexity`),
ensembles of restarts (:mod:`~streamid.engine.choice.ensemble_choice`), the long linear part
(:mod:`~streamid.engine.choice.longlinear`), the refinement of the weights to the free run and its compiled
sensitivities (:mod:`~streamid.engine.choice.refine`, :mod:`~streamid.engine.choice.sensitivities`), stability
(:mod:`~streamid.engine.choice.stability`) and what a user should know before trusting a model
(:mod:`~streamid.engine.choice.caveats`).

May import: the stdlib, numpy, scipy, threadpoolctl, numba, ``streamid.errors``, ``streamid.threads``,
``streamid.model``, ``streamid.engine.settings``, ``streamid.engine.validation``, ``streamid.engine.fit`` and
``streamid.engine.search`` (docs/architecture.md; tests/test_layout.py).
"""
