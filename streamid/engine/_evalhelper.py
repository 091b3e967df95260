"""Entry point of the evaluation helper process: ``python -m streamid.engine._evalhelper CONTROL FD SPIN_S``.

Started by :class:`streamid.engine.parallel.EvalHelper`; not meant to be run by hand.
"""

from __future__ import annotations

import sys

from streamid.engine.parallel import _serve

if __name__ == "__main__":
    sys.exit(_serve(sys.argv[1], int(sys.argv[2]), float(sys.argv[3])))
