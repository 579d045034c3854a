"""``slung sweep --runs N [--controllers ...] [--scheduler ADDRESS] --out DIR``: Monte Carlo over the parameter
distributions of a TOML file (``offboard.harness.sweep``), on Dask (a local cluster by default, ``--scheduler`` for a
remote one), results streamed to ``DIR/results.csv`` as chunks finish; an interrupted sweep resumes where it
stopped when run again with the same file and folder. docs/compare.md#slung-sweep."""

from __future__ import annotations

import argparse
import csv
import json
import logging
import math
import os
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from estimators.errors import UserError
from offboard.control.controllers import registry
from offboard.harness import sweep
from offboard.outputs import prepare_output_dir, write_atomic

RESULTS = "results.csv"
#: runs per Dask task by engine: enough to amortize a task's set-up (the compiled path's reference rows), few enough
#: to keep both workers busy to the end and to lose little to an interruption
CHUNK = {"scalar": 10, "compiled": 100}


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=int, required=True, metavar="N", help="runs per controller")
    p.add_argument(
        "--controllers",
        metavar="LIST",
        default=None,
        help=f"comma-separated controllers (default: every one, {', '.join(registry.CONTROLLERS)}; the compiled "
        "engine flies 1000 runs of each in about 10 s on two workers)",
    )
    p.add_argument("--file", metavar="TOML", help="distributions and success criteria (default: the shipped one)")
    p.add_argument("--engine", choices=sweep.ENGINES, help="override the file's run.engine")
    p.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler (tcp://host:8786); default: a local cluster")
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="local cluster worker processes (default: the CPU count); 0 runs everything in this process",
    )
    p.add_argument(
        "--chunk",
        type=int,
        default=None,
        metavar="K",
        help="runs per Dask task (default: 10 scalar, 100 compiled)",
    )
    p.add_argument("--no-figures", action="store_true", help="no PNG figures")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (an existing sweep there is resumed)")


def run(args: argparse.Namespace) -> int:
    summary = execute(
        args.runs,
        registry.parse_list(args.controllers),
        args.out,
        file=args.file,
        engine=args.engine,
        scheduler=args.scheduler,
        workers=args.workers,
        chunk=args.chunk,
        figures=not args.no_figures,
    )
    print(format_summary(summary))
    print(f"sweep: {args.out}")
    return 0


def execute(
    runs: int,
    controllers: list[str],
    out_dir: str | Path,
    *,
    file: str | None = None,
    engine: str | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    chunk: int | None = None,
    figures: bool = True,
    progress: bool = True,
    stop_after_chunks: int | None = None,
) -> dict[str, Any]:
    """Run (or resume) a sweep; returns the summary written to ``DIR/summary.json``. ``stop_after_chunks``: stop
    (as an interrupt would) after that many chunks were written (tests of resume)."""
    if runs < 1:
        raise UserError(f"--runs must be >= 1, got {runs}")
    if workers is not None and workers < 0:
        raise UserError(f"--workers must be >= 0, got {workers}")
    config = sweep.load_config(file)
    if engine is not None:
        config = sweep.config_from_dict({**config.to_dict(), "engine": engine})
    chunk = chunk or CHUNK.get(config.engine, 10)
    if chunk < 1:
        raise UserError(f"--chunk must be >= 1, got {chunk}")
    feasibility = sweep.reference_feasibility(config)
    for msg in feasibility.messages:  # warnings only: a sweep may explore a hard move, but should say it is one
        print(f"feasibility check of the file's move (nominal vehicle): {msg}", file=sys.stderr)
    out = prepare_output_dir(out_dir)
    cfg_dict = config.to_dict()
    _check_same_sweep(out, cfg_dict)
    columns = sweep.table_columns()
    done = _read_done(out / RESULTS, columns)
    todo = [(c, [r for r in range(runs) if (c, r) not in done]) for c in controllers]
    # runs of a controller the fast engines do not fly go in the scalar path's chunks (10 runs)
    size = {c: chunk if sweep.engine_for(config, c) != "scalar" else min(chunk, 10) for c in controllers}
    tasks = [(c, rs[i : i + size[c]]) for c, rs in todo for i in range(0, len(rs), size[c])]
    n_todo = sum(len(rs) for _, rs in tasks)
    slow = [c for c, _ in todo if config.engine != "scalar" and sweep.engine_for(config, c) == "scalar"]
    if n_todo and slow:  # said even without the progress bar: it is why the sweep is slow
        print(
            f"the {config.engine} engine does not fly {', '.join(slow)} with estimator {config.estimator}, actuators "
            f"{config.actuators}: the scalar path flies them (about 7 simulated s per wall s per worker)",
            file=sys.stderr,
        )
    if n_todo and any(sweep.engine_for(config, c) == "compiled" for c, _ in tasks):
        # (a cold cache's compilation says so itself, once: estimators.compile_notice)
        sweep.warm_up(config, list(dict.fromkeys(c for c, _ in tasks)))
    baseline = sweep.single_run_speed(config) if n_todo else None
    wall0 = time.perf_counter()
    sim_s = 0.0
    cpu_s = 0.0
    finished = 0
    written = 0
    bar = _Progress(n_todo, enabled=progress)
    with open(out / RESULTS, "a", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        if fh.tell() == 0:
            writer.writerow(columns)
            fh.flush()
        try:
            for rows in _results(tasks, cfg_dict, scheduler, workers):
                for row in rows:
                    writer.writerow([_cell(row[k]) for k in columns])
                    sim_s += row["sim_s"]
                    cpu_s += row.get("cpu_s", 0.0)
                fh.flush()
                os.fsync(fh.fileno())
                finished += len(rows)
                written += 1
                bar.update(finished, sim_s / max(time.perf_counter() - wall0, 1e-9))
                if stop_after_chunks is not None and written >= stop_after_chunks:
                    raise KeyboardInterrupt
        finally:
            bar.close()
    wall = time.perf_counter() - wall0
    table = _read_table(out / RESULTS, columns)
    table = [r for r in table if r["controller"] in controllers and int(r["run"]) < runs]
    table.sort(key=lambda r: (controllers.index(r["controller"]), int(r["run"])))
    write_atomic(out / RESULTS, lambda p: _write_table(p, columns, table))
    summary = summarize(table, controllers, config)
    summary["this_invocation"] = {
        "runs": finished,
        "wall_s": wall,
        "sim_s": sim_s,
        "cpu_s_in_runs": cpu_s,
        "resumed_runs": len(done),
        "load_average_1min": os.getloadavg()[0],
    }
    summary["sim_seconds_per_wall_second"] = (sim_s / wall) if finished else None
    summary["sim_seconds_per_cpu_second"] = (sim_s / cpu_s) if finished and cpu_s > 0 else None
    summary["single_run_baseline"] = baseline
    summary["reference_feasibility"] = {"feasible": feasibility.feasible, "messages": list(feasibility.messages)}
    summary["engine"] = config.engine
    summary["engine_by_controller"] = {c: sweep.engine_for(config, c) for c in controllers}
    summary["scheduler"] = scheduler or (f"local cluster, {workers} workers" if workers else "local cluster")
    if workers == 0 and not scheduler:
        summary["scheduler"] = "this process"
    text = json.dumps(summary, indent=2, allow_nan=False)
    write_atomic(out / "summary.json", lambda p: p.write_text(text + "\n", encoding="utf-8"))
    if figures and table:
        from offboard.report.sweep_report import write_figures, write_html

        write_figures(out, table, controllers)
        write_html(out, table, controllers, summary)
    return summary


def _results(
    tasks: list[tuple[str, list[int]]], cfg: dict[str, Any], scheduler: str | None, workers: int | None
) -> Iterator[list[dict[str, Any]]]:
    """Rows of each task as it finishes: in this process (workers == 0) or on Dask."""
    if not tasks:
        return
    if workers == 0 and scheduler is None:
        for c, rs in tasks:
            yield sweep.run_chunk(cfg, c, rs)
        return
    from dask.distributed import Client, LocalCluster, as_completed

    logging.getLogger("distributed").setLevel(logging.WARNING)  # the scheduler's INFO lines would bury the progress bar
    cluster = None
    if scheduler is None:
        n = workers or os.cpu_count() or 1
        cluster = LocalCluster(
            n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=logging.WARNING
        )
        client = Client(cluster)
    else:
        try:
            client = Client(scheduler, timeout=10)
        except (OSError, TimeoutError) as exc:
            raise UserError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
    try:
        futures = [client.submit(sweep.run_chunk, cfg, c, rs, pure=False) for c, rs in tasks]
        for fut in as_completed(futures):
            yield fut.result()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _cell(v: Any) -> str:
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def _read_done(path: Path, columns: list[str]) -> set[tuple[str, int]]:
    return {(r["controller"], int(r["run"])) for r in _read_table(path, columns)}


def _read_table(path: Path, columns: list[str]) -> list[dict[str, str]]:
    """The rows of a results file; a last line cut short by an interrupted write is dropped (and cut off)."""
    if not path.exists():
        return []
    raw = path.read_bytes()
    if raw and not raw.endswith(b"\n"):
        raw = raw[: raw.rfind(b"\n") + 1]
        path.write_bytes(raw)
    lines = raw.decode("utf-8").splitlines()
    if not lines:
        return []
    if lines[0].split(",") != columns:
        raise UserError(f"{path} has other columns than this sweep's: use another --out folder")
    rows = []
    for rec in csv.DictReader(lines):
        if None in rec or any(v is None for v in rec.values()):
            continue
        rows.append(rec)
    return rows


def _write_table(path: Path, columns: list[str], rows: list[dict[str, str]]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for r in rows:
            w.writerow([r[c] for c in columns])


def _check_same_sweep(out: Path, cfg: dict[str, Any]) -> None:
    path = out / "sweep_config.json"
    if path.exists():
        try:
            old = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            old = None
        if old != json.loads(json.dumps(cfg)):
            raise UserError(f"{out} holds a sweep of another configuration: use another --out folder")
        return
    if (out / RESULTS).exists():
        raise UserError(f"{out / RESULTS} exists without its sweep_config.json: use another --out folder")
    text = json.dumps(cfg, indent=2)
    write_atomic(path, lambda p: p.write_text(text + "\n", encoding="utf-8"))


def summarize(table: list[dict[str, str]], controllers: list[str], config: sweep.SweepConfig) -> dict[str, Any]:
    """Per controller: runs, success rate, failures by reason, worst cases and failure regions."""
    from offboard.report.sweep_report import failure_regions

    out: dict[str, Any] = {"controllers": {}, "file": config.to_dict()}
    for c in controllers:
        rows = [r for r in table if r["controller"] == c]
        n = len(rows)
        ok = sum(r["success"] == "1" for r in rows)
        reasons: dict[str, int] = {}
        for r in rows:
            if r["failure"]:
                reasons[r["failure"]] = reasons.get(r["failure"], 0) + 1

        def worst(key: str, rows: list[dict[str, str]] = rows) -> float | None:
            vals = [float(r[key]) for r in rows if math.isfinite(float(r[key]))]
            return max(vals) if vals else None

        out["controllers"][c] = {
            "runs": n,
            "success_rate": ok / n if n else None,
            "failures": reasons,
            "worst": {k: worst(k) for k in ("peak_swing_rad", "residual_swing_rad", "tracking_rms_m", "final_error_m")},
            "failure_regions": failure_regions(rows),
        }
        out[c] = {"runs": n, "success_rate": ok / n if n else None}
    return out


def _engines_flown(s: dict[str, Any]) -> str:
    """The engines that flew the summary's rows: the file's, or which rows another flew (the scalar path for
    estimators and actuators the fast engines do not model, ``sweep.engine_for``)."""
    used = sorted(set(s["engine_by_controller"].values()))
    if used == [s["engine"]]:
        return f"{s['engine']} engine"
    if len(used) == 1:
        return f"{used[0]} engine, not the file's {s['engine']}"
    return "engines " + ", ".join(f"{c}: {e}" for c, e in s["engine_by_controller"].items())


def format_summary(s: dict[str, Any]) -> str:
    lines = [f"{'controller':<15}{'runs':>7}{'success':>10}{'worst resid rad':>17}{'worst track m':>15}  failures"]
    for c, d in s["controllers"].items():
        rate = "-" if d["success_rate"] is None else f"{100 * d['success_rate']:.1f} %"
        wr, wt = d["worst"]["residual_swing_rad"], d["worst"]["tracking_rms_m"]
        fails = ", ".join(f"{k} {v}" for k, v in sorted(d["failures"].items())) or "none"
        lines.append(
            f"{c:<15}{d['runs']:>7}{rate:>10}{'-' if wr is None else f'{wr:.4f}':>17}"
            f"{'-' if wt is None else f'{wt:.4f}':>15}  {fails}"
        )
        for region in d["failure_regions"]:
            lines.append(f"{'':<15}  fails more often where {region['text']}")
    inv = s["this_invocation"]
    rate = s["sim_seconds_per_wall_second"]
    lines.append(
        f"this invocation: {inv['runs']} runs ({inv['resumed_runs']} kept from before), {inv['sim_s']:.0f} simulated s "
        f"in {inv['wall_s']:.1f} s wall"
        + (f": {rate:.0f} simulated s per wall s ({_engines_flown(s)}, {s['scheduler']})" if rate else "")
    )
    b = s.get("single_run_baseline")
    cpu = s.get("sim_seconds_per_cpu_second")
    if rate and b and cpu:
        lines.append(
            f"per CPU second of the runs: {cpu:.0f} simulated s; one scalar run measured in the same invocation: "
            f"{b['per_wall_s']:.1f} simulated s per wall s, {b['per_cpu_s']:.1f} per CPU s "
            f"(load average {inv['load_average_1min']:.1f})"
        )
    return "\n".join(lines)


#: a sweep's progress printed to a file or pipe (not a terminal): one plain line at most this often (s)
PLAIN_PROGRESS_PERIOD_S = 5.0


class _Progress:
    """Progress on stderr as suits where it goes: on a terminal one bar redrawn in place (carriage returns); to a
    file or pipe (a log) one plain line every :data:`PLAIN_PROGRESS_PERIOD_S` and at the end, so a log holds
    readable lines rather than one line of redraws. ``tty``: None = ask stderr; ``clock``: seconds (monotonic)."""

    def __init__(
        self,
        total: int,
        enabled: bool = True,
        write: Callable[[str], Any] | None = None,
        tty: bool | None = None,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.total = total
        self.enabled = enabled and total > 0
        self.clock = clock
        self.t0 = clock()
        self.tty = sys.stderr.isatty() if tty is None else tty
        self.write = write or (lambda s: print(s, end="", file=sys.stderr, flush=True))
        self._last_plain: float | None = None
        self._last_done = -1

    def update(self, done: int, rate: float) -> None:
        if not self.enabled:
            return
        frac = done / self.total
        now = self.clock()
        el = now - self.t0
        eta = el / frac - el if frac > 0 else math.nan
        if self.tty:
            bar = "#" * int(30 * frac)
            self.write(f"\r  [{bar:<30}] {done}/{self.total} runs, {rate:.0f} sim-s/s, ETA {eta:.0f} s ")
            return
        due = self._last_plain is None or now - self._last_plain >= PLAIN_PROGRESS_PERIOD_S
        if (due or done >= self.total) and done != self._last_done:
            self._last_plain, self._last_done = now, done
            self.write(
                f"  {done}/{self.total} runs ({100 * frac:.0f} %), {rate:.0f} sim-s/s, {el:.0f} s elapsed, "
                f"ETA {eta:.0f} s\n"
            )

    def close(self) -> None:
        if self.enabled and self.tty:
            self.write("\n")
