"""``python -m planbench.cli``: the ``planbench`` command."""

import sys

from planbench.cli.main import main

sys.exit(main())
