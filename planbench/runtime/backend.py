"""Choice between the compiled (numba) and the plain numpy/scipy implementation of the hot loops.

``backend="auto"`` uses numba when it is installed and numpy/scipy otherwise; both give the same
numbers (to rounding). numba is imported on first use only, so ``import planbench`` stays fast.
A command can make ``"auto"`` mean numpy for the whole process (:func:`prefer`): ``planbench plan``
does while numba's cache is cold (:mod:`planbench.runtime.compile_cache`).
"""

from __future__ import annotations

import functools
import importlib.util

from planbench.errors import InvalidConfigError

__all__ = ["BACKENDS", "have_numba", "prefer", "resolve"]

BACKENDS = ("auto", "numba", "numpy")
_AUTO: str | None = None  # what "auto" means in this process when set (prefer)


@functools.cache
def have_numba() -> bool:
    """Whether numba can be imported."""
    return importlib.util.find_spec("numba") is not None


def prefer(backend: str | None) -> None:
    """Make ``"auto"`` mean ``backend`` (``"numpy"``, or ``"numba"`` where installed) in this
    process, for the field and the IK loop alike; None: back to numba when installed."""
    global _AUTO
    if backend is not None and backend not in ("numba", "numpy"):
        raise InvalidConfigError(f"prefer 'numba', 'numpy' or None, not {backend!r}")
    if backend == "numba" and not have_numba():
        raise InvalidConfigError("numba is not installed: pip install numba")
    _AUTO = backend


def resolve(backend: str) -> str:
    """``"numba"`` or ``"numpy"`` for a requested backend name."""
    if backend not in BACKENDS:
        raise InvalidConfigError(f"unknown field backend {backend!r}; use one of {BACKENDS}")
    if backend == "auto":
        return _AUTO or ("numba" if have_numba() else "numpy")
    if backend == "numba" and not have_numba():
        raise InvalidConfigError("field backend 'numba' needs numba: pip install numba (or use backend='numpy')")
    return backend
