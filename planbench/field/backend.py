"""Choice between the compiled (numba) and the plain numpy/scipy implementation of the hot loops.

``backend="auto"`` uses numba when it is installed and numpy/scipy otherwise; both give the same
numbers (to rounding). numba is imported on first use only, so ``import planbench`` stays fast.
"""

from __future__ import annotations

import functools
import importlib.util
from types import ModuleType

from planbench.errors import InvalidConfigError

__all__ = ["BACKENDS", "have_numba", "resolve", "compiled"]

BACKENDS = ("auto", "numba", "numpy")


@functools.cache
def have_numba() -> bool:
    """Whether numba can be imported."""
    return importlib.util.find_spec("numba") is not None


def resolve(backend: str) -> str:
    """``"numba"`` or ``"numpy"`` for a requested backend name."""
    if backend not in BACKENDS:
        raise InvalidConfigError(f"unknown field backend {backend!r}; use one of {BACKENDS}")
    if backend == "auto":
        return "numba" if have_numba() else "numpy"
    if backend == "numba" and not have_numba():
        raise InvalidConfigError("field backend 'numba' needs numba: pip install numba (or use backend='numpy')")
    return backend


def compiled() -> ModuleType:
    """The compiled kernels module (imports numba)."""
    from planbench.field import _compiled  # on use: numba is optional and takes ~0.15 s to import

    return _compiled
