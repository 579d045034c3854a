"""Record the PX4 SITL logs shipped in tests/data: a real PX4 (SIH quadrotor) on PX4 SITL instance INSTANCE, flown
by ``slung fly`` (take-off, hover scenario under OFFBOARD, land), its ULog and the companion's tlog kept.

    python bench/record_px4_sitl_logs.py --instance 9 --out /tmp/px4-rec

Writes OUT/fly/flight.tlog (slung fly's tlog of every packet), OUT/px4/log/**/*.ulg (PX4's own log of the flight)
and prints their paths. Needs the PX4 SITL folder (``sim_bridge.sitl.px4_sitl``).
"""

from __future__ import annotations

import argparse
import subprocess
from pathlib import Path

from bench_px4_hover import slung_fly

from offboard.logs.log_formats import ULOG_TOPICS
from sim_bridge.sitl.px4_sitl import Px4Sitl


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--instance", type=int, default=9)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--duration", type=float, default=12.0, help="offboard flight, s")
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    with Px4Sitl(instance=args.instance, workdir=args.out / "px4") as px4:
        cmd = slung_fly(
            px4.connection_url, "--scenario", "hover", "--duration", str(args.duration), "--vehicle", "px4-sih"
        )
        cmd += ["--end", "land", "--out", str(args.out / "fly")]
        code = subprocess.call(cmd)
        px4.run_for(15.0)  # landing and disarm (15 s of PX4's clock), still logged by PX4
    for f in [args.out / "fly" / "flight.tlog", *sorted((args.out / "px4").rglob("*.ulg"))]:
        print(f, f.stat().st_size if f.exists() else "missing")
    return code


if __name__ == "__main__":
    raise SystemExit(main())


# ---------------------------------------------------------------------------------------------------------------
# cutting the recorded logs to the size tests/data can hold

#: the ULog topics the replay reads and the SIH ground truth beside them
KEEP_TOPICS = (*ULOG_TOPICS, "vehicle_local_position_groundtruth", "vehicle_attitude_groundtruth")


def cut_ulog(src: Path, dst: Path, t0: float, t1: float) -> Path:
    """``src`` with only :data:`KEEP_TOPICS`, samples between vehicle times ``t0`` and ``t1`` (s), as ``dst``."""
    from pyulog import ULog

    ulog = ULog(str(src), list(KEEP_TOPICS))
    for d in ulog.data_list:
        t = d.data["timestamp"] * 1e-6
        keep = (t >= t0) & (t <= t1)
        d.data = {k: v[keep] for k, v in d.data.items()}
    ulog.write_ulog(str(dst))
    return dst


def cut_tlog(src: Path, dst: Path, t0: float, t1: float) -> Path:
    """The records of ``src`` whose logger time lies between ``t0`` and ``t1`` s after its first record."""
    from offboard.logs.tlog import TlogReader, encode_record

    out = bytearray()
    first = None
    for lt, msg in TlogReader.from_path(src):
        first = lt if first is None else first
        if t0 <= lt - first <= t1:
            out += encode_record(round(lt * 1e6), msg.get_msgbuf())
    dst.write_bytes(bytes(out))
    return dst
