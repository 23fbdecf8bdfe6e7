"""What planbench draws, shared by the static and the closed-loop side.

- :mod:`~planbench.visual.plots`: matplotlib set up headless, figures saved safely, shared marks.
- :mod:`~planbench.visual.replay`: a path in 3D, one offline HTML page (meshcat).
"""
