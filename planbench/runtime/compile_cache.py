"""Whether numba's on-disk cache already holds planbench's compiled kernels, and how it gets there.

The field kernels and the IK loop's step are compiled by numba on first use and cached on disk
(``cache=True``); compiling them all takes 8 s on the 2-core VM, loading them from the cache
well under a second. A first ``planbench plan`` on a fresh install should not wait for that:
when the cache is cold, ``plan`` computes with the numpy implementations (the same numbers to
rounding, a few times slower per step) and starts ``python -m planbench.cli.compile`` in the
background, which compiles the kernels, at low priority, then leaves a marker saying so. The
benchmark never takes this route: its workers compile before their first timed setup.

The marker is keyed by what numba's cache is keyed by (numba and Python versions, the CPU, the
kernels' source files), so editing a kernel or moving to another machine makes the cache cold
again. A marker whose cache was deleted since costs one compilation, never a wrong result.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import platform
import shutil
import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

__all__ = [
    "KERNELS_GROUP",
    "enabled",
    "is_warm",
    "kernel_modules",
    "kernel_sources",
    "mark_warm",
    "marker_path",
    "use_private_cache",
    "warm_in_background",
    "warm_now",
]

COMPILE_MODULE = "planbench.cli.compile"
"""What the background compilation runs (``python -m``): plans of the field planners, which
compile (or load) every kernel they use; a module of the command line, since it plans."""

KERNELS_GROUP = "planbench.kernels"
"""The entry-point group in which a package declares a module whose functions numba compiles with
``cache=True`` (name: any; value: the module), for instance in its ``pyproject.toml``::

    [project.entry-points."planbench.kernels"]
    my-planner = "my_planner._compiled"

The marker's key includes those modules' sources, and a sandboxed worker's private cache is seeded
with their cached code. Read from the installed metadata: nothing is imported."""


def kernel_modules() -> list[str]:
    """The modules declared in :data:`KERNELS_GROUP` by the installed packages, sorted."""
    return sorted({ep.value.split(":")[0].strip() for ep in entry_points(group=KERNELS_GROUP)})


def kernel_sources() -> list[Path]:
    """The source files of :func:`kernel_modules` (found without importing them, or numba)."""
    out = []
    for name in kernel_modules():
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.origin:
            out.append(Path(spec.origin))
    return out


def marker_path() -> Path:
    """The marker file for this numba, Python, CPU and these kernel sources."""
    import numba

    key = [numba.__version__, sys.version, platform.machine(), _cpu_name()]
    for src in kernel_sources():
        st = src.stat()
        key.append(f"{src}:{st.st_mtime_ns}:{st.st_size}")
    digest = hashlib.sha256("\n".join(key).encode()).hexdigest()[:16]
    base = os.environ.get("NUMBA_CACHE_DIR") or os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "planbench" / f"numba-warm-{digest}"


def _cpu_name() -> str:
    try:
        from llvmlite import binding

        return f"{binding.get_host_cpu_name()}:{binding.get_host_cpu_features().flatten()}"
    except Exception:  # an llvmlite without these calls: the machine name stands in
        return platform.processor()


def enabled() -> bool:
    """Whether a cold cache may switch a command to numpy and start the background compilation
    (``PLANBENCH_BACKGROUND_COMPILE=0`` in the environment: no, numba compiles in the foreground)."""
    return os.environ.get("PLANBENCH_BACKGROUND_COMPILE", "1") != "0"


def is_warm() -> bool:
    """Whether the background compilation (:mod:`planbench.cli.compile`) has run for this cache key."""
    try:
        return marker_path().exists()
    except (OSError, ImportError):
        return False


def _compile_command() -> tuple[list[str], dict[str, Any]]:
    """The command that runs :data:`COMPILE_MODULE`, and the keywords that discard its input and output."""
    quiet = {name: subprocess.DEVNULL for name in ("stdin", "stdout", "stderr")}
    return [sys.executable, "-m", COMPILE_MODULE], quiet


def mark_warm() -> None:
    """Write the marker: numba's cache now holds the kernels for this key."""
    path = marker_path()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("numba's cache holds planbench's kernels for this key\n")


def warm_in_background() -> None:
    """Start :data:`COMPILE_MODULE` in a detached, low-priority process (output discarded); at most one
    runs at a time (a lock file next to the marker)."""
    try:
        # start_new_session: it outlives the command that started it, untouched by its Ctrl-C
        args, quiet = _compile_command()
        subprocess.Popen(args, start_new_session=True, **quiet)
    except OSError:  # no process to spare: the next command finds the cache cold again, nothing worse
        pass


def use_private_cache(directory: str) -> int:
    """Make numba cache to ``directory`` in this process, seeded with a copy of the shared cache of
    planbench's kernels; the number of files copied.

    For a sandboxed benchmark worker (:mod:`planbench.bench.sandbox`), which may write only to its
    scratch folder: numba refuses to cache at all where it cannot write, and a shared cache a
    plugin could write would let it plant compiled code in the next plugin's process. Call it
    before the kernels' modules are imported (numba picks a function's cache place then). It does
    not import numba (150 ms), which a worker of a planner without numba code never needs.
    """
    os.makedirs(directory, exist_ok=True)
    copied = 0
    user = os.environ.get("NUMBA_CACHE_DIR", "")
    for src in kernel_sources():
        target = os.path.join(directory, cache_subpath(src))
        for shared in _shared_cache_dirs(src, user):
            files = sorted(shared.glob(f"{src.stem}.*.nb[ic]"))
            if not files:
                continue
            os.makedirs(target, exist_ok=True)
            for f in files:
                shutil.copy2(f, target)
                copied += 1
            break
    os.environ["NUMBA_CACHE_DIR"] = directory  # what numba reads when it is imported
    config = sys.modules.get("numba.core.config")
    if config is not None:  # imported already
        config.CACHE_DIR = directory  # type: ignore[attr-defined]
    return copied


def cache_subpath(src: Path | str) -> str:
    """The folder numba gives ``src``'s cache in a cache directory: the source folder's name and the
    SHA-1 of its absolute path (numba's ``_CacheLocator.get_suitable_cache_subpath``, written out so
    that a worker needs no numba import to find it; a test holds the two equal)."""
    folder = os.path.dirname(os.path.abspath(src))
    return "_".join([os.path.split(folder)[-1], hashlib.sha1(folder.encode()).hexdigest()])


def _shared_cache_dirs(src: Path, user: str = "") -> list[Path]:
    """Where numba keeps ``src``'s cache outside a private one, in numba's order: the user's
    ``NUMBA_CACHE_DIR``, next to the source, user-wide (``$XDG_CACHE_HOME/numba``)."""
    sub = cache_subpath(src)
    wide = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "numba" / sub
    return [Path(user) / sub] if user else [src.parent / "__pycache__", wide]


def warm_now(timeout: float = 600.0) -> bool:
    """Fill the shared cache (:data:`COMPILE_MODULE`, in a child process) unless it is warm; whether it is
    warm afterwards. The benchmark does this before its workers start: a sandboxed worker cannot
    write the shared cache, so each would otherwise compile in its own (5-8 s per worker)."""
    if is_warm():
        return True
    try:
        args, quiet = _compile_command()
        subprocess.run(args, timeout=timeout, check=False, **quiet)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return is_warm()
