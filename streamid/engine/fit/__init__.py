"""The network's fit: what every candidate model of the search and the choice is made with.

Owns: the Gaussian activations and the least-squares output weights, whole or streamed over blocks of rows
(:mod:`~streamid.engine.fit.rbf`), the candidate-lag regressor matrix (:mod:`~streamid.engine.fit.lagmatrix`),
the one-BLAS-thread pin (:mod:`~streamid.engine.fit.blas`) and the search's compiled ``exp2`` and Gram, used where
numpy's are slow (:mod:`~streamid.engine.fit.kernels`).

May import: the stdlib, numpy, scipy, threadpoolctl, numba, ``streamid.errors`` and ``streamid.model``
(docs/architecture.md; tests/test_layout.py).
"""
