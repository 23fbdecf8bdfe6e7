"""What every plot of planbench shares: matplotlib loaded headless on first use, figures written
only where an output may go, and the success-rate bar that static and closed-loop reports draw
alike."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from planbench.files.outputs import check_output
from planbench.metrics import wilson_interval

__all__ = ["pyplot", "save", "success_bar"]


def pyplot() -> Any:
    """matplotlib's pyplot on the Agg backend, imported on first use: it costs about half a second,
    which every ``planbench`` command would otherwise pay."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig: Any, path: str | Path, dpi: int = 150) -> Path:
    """Lay out ``fig``, write it to ``path`` (never over a results file: :func:`check_output`) and
    close it; the file written."""
    target = check_output(path)
    fig.tight_layout()
    fig.savefig(target, dpi=dpi)
    pyplot().close(fig)
    return target


def success_bar(ax: Any, x: float, runs: Sequence[dict[str, Any]], width: float, color: int, label: str | None) -> None:
    """The success-rate bar of ``runs`` (rows with a ``success`` flag) at ``x``: its Wilson 95 %
    interval as an error bar and a ``k/n`` label; nothing without runs. A 0 % bar keeps a sliver
    of height and its label: it reads as 0 of n, not as no data."""
    n, solved = len(runs), sum(1 for r in runs if r["success"])
    if not n:
        return
    rate = solved / n
    lo, hi = wilson_interval(solved, n)
    ax.bar(x, max(rate, 0.006), width, color=f"C{color}", label=label)
    ax.errorbar(x, rate, yerr=[[rate - lo], [hi - rate]], color="k", capsize=2, lw=0.8)
    ax.text(x, hi + 0.015, f"{solved}/{n}", ha="center", fontsize="xx-small")
