"""Figures of the reports (``offboard.report.report`` for ``slung sim`` / ``fly`` / ``demo``,
``offboard.report.replay_report`` for ``slung replay``): matplotlib on its non-interactive Agg backend, and the one way
a figure is saved (laid out, written atomically as PNG at 110 dpi, closed)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from offboard.outputs import write_atomic

DPI = 110


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (imported on first use: matplotlib is slow to import)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig: Any, path: Path) -> Path:
    """Lay ``fig`` out, write it to ``path`` as PNG (atomically: a reader never sees half a file), close it."""
    fig.tight_layout()
    write_atomic(path, lambda p: fig.savefig(p, dpi=DPI, format="png"))
    pyplot().close(fig)
    return path
