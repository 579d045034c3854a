"""A full disk does not turn a flight into a traceback (issue 39): ``slung fly`` as its own process against the
bundled emulator (its own process, lockstep, real UDP on 127.0.0.1), with a file-size limit on the flight process
(RLIMIT_FSIZE, SIGXFSZ ignored: every write past the limit fails with EFBIG, as a full disk fails with ENOSPC).
The tlog stops mid-flight with a warning line, the flight flies on and ends with its own exit code, the small files
(metrics.json, events.json) are written before the large ones, the large ones that cannot be are warned about, and
stderr ends with one summary line that reports the outputs apart from the flight."""

from __future__ import annotations

import json
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from emulator_helpers import emulator_process, stop_emulator_process

from offboard.harness.demo_cli import free_udp_port
from offboard.logs.timeseries_file import read_table

ROOT = Path(__file__).resolve().parents[1]
#: bytes any one file of the flight process may reach: metrics.json (8.7 kB) and events.json (3.6 kB) fit, the tlog
#: (300 kB by the start of control) and the tick log do not: this hover's ticks take 38 bytes each as the folder
#: stores them since 7 Dec 2026, so 270 fit, and the flight is 6 s (1500 ticks at 250 Hz; a loaded machine, whose
#: lockstep emulator may run ahead of the loop, flew 300 in 3 s)
FILE_LIMIT = 10_000


def _limit_files() -> None:
    resource.setrlimit(resource.RLIMIT_FSIZE, (FILE_LIMIT, FILE_LIMIT))
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)


@pytest.mark.slow
def test_a_full_disk_leaves_the_flight_s_exit_code_warnings_metrics_and_one_summary_line(tmp_path: Path) -> None:
    port = free_udp_port()
    emu = emulator_process(port, "--lockstep", stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    out = tmp_path / "f"
    cmd = [sys.executable, "-c", "import sys; from offboard.cli import main; sys.exit(main(sys.argv[1:]))", "fly"]
    cmd += ["--connect", f"udpin:127.0.0.1:{port}", "--scenario", "hover", "--duration", "6", "--lockstep"]
    cmd += ["--no-figures", "--out", str(out)]
    try:
        p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300, preexec_fn=_limit_files)
    finally:
        stop_emulator_process(emu)
    err = p.stderr
    assert "Traceback" not in err, err[-3000:]
    m = json.loads((out / "metrics.json").read_text())
    assert p.returncode == m["flight"]["exit_code"] == 0 and m["flight"]["ended_by"] == "completed", err[-2000:]
    assert json.loads((out / "events.json").read_text())["loop"]
    # the tlog stopped at the limit, with a warning line, and is complete up to its last record
    assert (out / "flight.tlog").stat().st_size <= FILE_LIMIT
    lines = err.splitlines()
    stopped = [line for line in lines if "output stopped: " in line]
    assert "output stopped: tlog" in stopped[0] and "File too large" in stopped[0], err[-3000:]
    # it stopped during the flight (before the control phase began), and the flight went on
    assert lines.index(stopped[0]) < next(i for i, line in enumerate(lines) if line.startswith("[control]"))
    assert any("output stopped: timeseries_live.slts" in line for line in stopped), err[-3000:]
    failed = m["outputs"]["failed"]
    assert failed[0].startswith("tlog") and any(f.startswith("timeseries_live.slts") for f in failed), failed
    # the tick log streamed during the flight keeps every block written before the limit: readable, marked
    # incomplete, never past the limit (its rewrite at the end is atomic: no half-written copy replaces it)
    live = read_table(out / "timeseries_live.slts")
    assert not live.complete and len(live) > 10 and (out / "timeseries_live.slts").stat().st_size <= FILE_LIMIT
    summary = lines[-1]
    assert summary.startswith("slung fly: completed (exit 0)") and "outputs incomplete: tlog" in summary, summary
