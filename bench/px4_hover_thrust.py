"""A wrong MPC_THR_HOVER on real PX4 and on the emulator's PX4 flavour: the take-off and the hover thrust learned.

Real PX4 SITL (its SIH quadrotor, physically 0.49 of full thrust to hover) boots with ``MPC_THR_HOVER`` set to
``--hover`` (default 0.35, a vehicle file's value for another autopilot or before a payload was added), takes off
to ``--height`` m with PX4's own take-off and holds; its ULog gives the true height and PX4's hover thrust
estimate (``hover_thrust_estimate``). The emulator's PX4 flavour flies the same take-off with the same parameter
(in this process, no link traffic needed), with its hover thrust estimator on (``MPC_USE_HTE`` 1, PX4's default)
and, for contrast, off. Printed per run: the largest true height, the time from arming to within 0.1 m of the
take-off height, the time the estimate became valid, the estimate at the end and the vehicle's physical value.

    python bench/px4_hover_thrust.py [--hover 0.35] [--height 2.5] [--hold 20] [--instance 2]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from estimators.model.vehicle import load_vehicle  # noqa: E402 - after the path set-up


def real_px4(hover: float, height: float, hold: float, instance: int) -> dict[str, Any]:
    """PX4 SITL's take-off with MPC_THR_HOVER ``hover``, judged on its ULog."""
    from bench_px4_hover import px4_hold
    from pyulog import ULog

    from sim_bridge.sitl.px4_sitl import Px4Sitl

    with tempfile.TemporaryDirectory() as tmp:
        sitl = Px4Sitl(instance=instance, workdir=Path(tmp) / "px4", params={"MPC_THR_HOVER": hover})
        with sitl:
            px4_hold(sitl.connection_url, height, 1.0, hold)
        ulog = ULog(str(sitl.ulogs()[-1]), ["vehicle_local_position_groundtruth", "hover_thrust_estimate"])
        d = {x.name: x.data for x in ulog.data_list}
    truth, hte = d["vehicle_local_position_groundtruth"], d["hover_thrust_estimate"]
    t, z = truth["timestamp"] * 1e-6, -truth["z"]
    ground = float(np.median(z[: max(1, len(z) // 20)]))
    lifted = t[z > ground + 0.05]
    t_hte, valid = hte["timestamp"] * 1e-6, hte["valid"].astype(bool)
    return _figures(t - lifted[0], z - ground, t_hte - lifted[0], valid, hte["hover_thrust"], height)


def emulator(hover: float, height: float, hold: float, use_hte: bool) -> dict[str, Any]:
    """The emulator's PX4 flavour flying the same take-off (SIH's vehicle file, MPC_THR_HOVER ``hover``)."""
    from sim_bridge.autopilot import Autopilot
    from sim_bridge.emulator import Emulator
    from sim_bridge.protocol.link import Link, LinkFaults

    v = load_vehicle("px4-sih")
    link = Link(["udpin:127.0.0.1:0"], LinkFaults())
    try:
        ap = Autopilot("px4", v, link)
        for name, value in (("MPC_THR_HOVER", hover), ("MPC_USE_HTE", int(use_hte)), ("MIS_TAKEOFF_ALT", height)):
            ap.params[name].value = value
            ap._apply_params(name)
        em = Emulator(ap, link, v)
        em.step(2000)  # the estimate's start-up
        ap._arm(0.0)
        ap.request_mode(ap.fl.by_name["AUTO.TAKEOFF"])
        ts, zs, th, hv = [], [], [], []
        for k in range(int((hold + 15.0) * 100)):
            em.step(10)
            ts.append(k * 0.01)
            zs.append(em.x[2])
            th.append(ap.px4_hover.valid)
            hv.append(ap.px4_hover.h)
    finally:
        link.close()
    t, z = np.array(ts), np.array(zs)
    lifted = t[z > 0.05]
    return _figures(t - lifted[0], z, t - lifted[0], np.array(th), np.array(hv), height)


def _figures(t: Any, z: Any, t_hte: Any, valid: Any, h: Any, height: float) -> dict[str, Any]:
    near = t[(np.abs(z - height) < 0.1) & (t > 0)]
    ok = t_hte[valid & (t_hte > 0)]
    return {
        "max_height_m": float(z.max()),
        "reach_s": float(near[0]) if near.size else None,
        "hte_valid_s": float(ok[0]) if ok.size else None,
        "hte_end": float(h[-1]) if len(h) else None,
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--hover", type=float, default=0.35, help="MPC_THR_HOVER given to both (default 0.35)")
    p.add_argument("--height", type=float, default=2.5, help="take-off height, m (default 2.5)")
    p.add_argument("--hold", type=float, default=20.0, help="hold after the take-off, s (default 20)")
    p.add_argument("--instance", type=int, default=2, help="PX4 SITL instance (default 2)")
    p.add_argument("--no-px4", action="store_true", help="the emulator only")
    a = p.parse_args()
    if not 0.1 <= a.hover <= 0.8 or not 1.0 <= a.height <= 20.0 or not 1.0 <= a.hold <= 300.0:
        p.error("--hover must be in [0.1, 0.8], --height in [1, 20] m, --hold in [1, 300] s")
    physical = load_vehicle("px4-sih").hover_thrust_normalized
    rows = [("emulator, HTE on", emulator(a.hover, a.height, a.hold, True))]
    rows.append(("emulator, HTE off", emulator(a.hover, a.height, a.hold, False)))
    if not a.no_px4:
        rows.insert(0, ("real PX4 SITL (SIH)", real_px4(a.hover, a.height, a.hold, a.instance)))
    print(f"MPC_THR_HOVER {a.hover:g}, take-off to {a.height:g} m; the vehicle's physical hover thrust {physical:.3f}")
    print(f"{'':22} {'max height m':>12} {'reach s':>8} {'HTE valid s':>12} {'HTE at the end':>15}")
    for name, f in rows:
        cells = [f.get(k) for k in ("max_height_m", "reach_s", "hte_valid_s", "hte_end")]
        text = ["-" if c is None else f"{c:.3f}" for c in cells]
        print(f"{name:22} " + " ".join(f"{c:>{w}}" for c, w in zip(text, (12, 8, 12, 15))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
