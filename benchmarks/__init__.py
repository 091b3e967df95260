"""What ``streamid bench`` measures: tooling beside the product, never inside it.

The benchmarks drive the product packages (``streamid``, ``recorders``, ``replay``); no product package imports
them (``tests/test_layout.py``, rule ``benchmarks-apart``).  The ``bench`` subcommand plugs into the ``streamid``
CLI through the ``streamid.commands`` entry point, and sections through ``streamid.benchmarks``.
"""
