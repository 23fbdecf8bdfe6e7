"""Where problems come from: shipped and generated sets, selectors, the worked examples.

- :mod:`~planbench.problems.datasets`: selectors (``mbm:box/0001``, ``gen:...``, files) to problems.
- :mod:`~planbench.problems.generators`: planbench's own scene families (``python -m planbench.problems.generate``).
"""
