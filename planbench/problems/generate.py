"""Regenerate planbench's own problem sets: ``python -m planbench.problems.generate --out planbench/data/gen``.

The command line of :mod:`planbench.problems.generators` (``--help`` for its options). It lives in a module
of its own because ``planbench`` imports the generators on start-up (for the ``gen:`` selector), and
``python -m`` on a module that is already imported runs it twice.
"""

from __future__ import annotations

import sys

from planbench.problems.generators import main

if __name__ == "__main__":
    sys.exit(main())
