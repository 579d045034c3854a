"""Figures of ``slung compare``: side-by-side PNGs (swing and tracking error of every controller, one row per
case) and ``report.html`` (``offboard.report.html_report``: one panel per case and signal, a trace per controller, the
figures of every case as tables)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from offboard.harness.compare import CaseResult
from offboard.logs.runlog import COL
from offboard.report.figures import pyplot, save_png


def write_figures(out: Path, by_case: dict[str, list[CaseResult]]) -> list[Path]:
    """``compare_swing.png``, ``compare_tracking.png`` and ``report.html`` in ``out``; returns their paths."""
    plt = pyplot()
    paths = []
    for key, title, unit, fname in (
        ("alpha", "swing alpha", "rad", "compare_swing.png"),
        ("e_F", "load tracking error |e_F|", "m", "compare_tracking.png"),
    ):
        n = len(by_case)
        fig, axes = plt.subplots(n, 1, figsize=(9.0, 2.8 * n), squeeze=False)
        for ax, (label, results) in zip(axes[:, 0], by_case.items()):
            for r in results:
                d = r.log.data
                y = d[:, COL["alpha"]] if key == "alpha" else np.hypot(d[:, COL["e_Fx"]], d[:, COL["e_Fy"]])
                ax.plot(d[:, COL["t"]], y, lw=0.9, label=r.controller)
            ta = results[0].case.scenario.arrival_time
            if ta is not None:
                ax.axvline(ta, color="grey", ls=":", lw=0.8)
            ax.set_title(f"{label}: {title}")
            ax.set_ylabel(unit)
            ax.grid(alpha=0.3)
        axes[-1, 0].set_xlabel("t (s)")
        axes[0, 0].legend(ncol=min(6, len(next(iter(by_case.values())))), fontsize=8)
        paths.append(save_png(fig, out / fname))
    paths.append(_html(out, by_case))
    return paths


def _html(out: Path, by_case: dict[str, list[CaseResult]]) -> Path:
    from offboard.report.html_report import Event, Panel, Trace, write_report_html

    panels = []
    events = []
    for label, results in by_case.items():
        t = results[0].log.data[:, COL["t"]]
        n = min(len(r.log.data) for r in results)
        t = t[:n]
        panels.append(
            Panel(f"{label}: swing", "rad", t, [Trace(r.controller, r.log.data[:n, COL["alpha"]]) for r in results])
        )
        panels.append(
            Panel(
                f"{label}: load tracking error",
                "m",
                t,
                [
                    Trace(r.controller, np.hypot(r.log.data[:n, COL["e_Fx"]], r.log.data[:n, COL["e_Fy"]]))
                    for r in results
                ],
            )
        )
        ta = results[0].case.scenario.arrival_time
        if ta is not None:
            events.append(Event(ta, "arrival", f"{label}: reference at rest"))
    metrics = {label: {r.controller: r.figures for r in rs} for label, rs in by_case.items()}
    return write_report_html(out, "slung compare", panels, events, metrics, subtitle=", ".join(by_case))
