"""Every file planbench reads or writes goes through here.

- :mod:`~planbench.files.inputs`: input files read as regular files of bounded size, named errors.
- :mod:`~planbench.files.outputs`: outputs never written over a results file; CSV cells escaped.
"""
