"""The ``planbench`` command: :func:`planbench.cli.main.main` and one module per command group.

- :mod:`~planbench.cli.main`: the parser, ``plan``, ``list``, errors to exit codes.
- :mod:`~planbench.cli.bench`: ``bench``, ``report``, ``replay``, ``export``.
- :mod:`~planbench.cli.field`: ``field`` and ``kernel`` plots.
- :mod:`~planbench.cli.check`: ``check``, the conformance checker in a process of its own.
"""
