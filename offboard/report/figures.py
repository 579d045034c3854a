"""Figures of the reports (``offboard.report.report`` for ``slung sim`` / ``fly`` / ``demo``,
``offboard.report.replay_report`` for ``slung replay``): matplotlib on its non-interactive Agg backend, and the one way
a figure is saved (laid out, written atomically as PNG at 110 dpi with a palette of 256 colours, closed)."""

from __future__ import annotations

import io
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
    """Lay ``fig`` out, write it to ``path`` as PNG (atomically: a reader never sees half a file), close it. The
    image is reduced to a palette of 256 colours (Pillow's fast octree): a plot of lines on white looks the same
    and takes a quarter of the bytes (a demo's ten figures: 1.5 MB in full colour, 0.4 MB)."""
    from PIL import Image  # matplotlib's own dependency

    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, dpi=DPI, format="png")
    pyplot().close(fig)
    buf.seek(0)
    with Image.open(buf) as im:
        palette = im.convert("RGB").quantize(colors=256, method=Image.Quantize.FASTOCTREE)
    write_atomic(path, lambda p: palette.save(p, format="PNG"))
    return path
