"""Checking configurations and paths against the true geometry.

- :mod:`~planbench.checking.collision`: configurations in collision, distances (coal through pinocchio).
- :mod:`~planbench.checking.certified`: continuous certification of path segments, the verdicts.
- :mod:`~planbench.checking.cloud_pairs`: distances to point-cloud obstacles (coal octrees).
"""
