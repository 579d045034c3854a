"""Start and stop a real ArduPilot Copter SITL carrying ArduPilot's own slung payload (the prebuilt build,
``shared/ardupilot-sitl``: its README has the ports, the boot sequence and the payload as MAVLink system 2).

This is a test and benchmark harness, not the flight path (``sim_bridge.sitl.px4_sitl`` is its PX4 twin): ``slung fly
--connect tcp:127.0.0.1:5760`` talks to whatever autopilot listens there; this module only starts one on this
machine, waits until it can fly, and watches its payload (:mod:`sim_bridge.sitl.ardupilot_monitor`).

Where the SITL is
    ``$SLUNG_ARDUPILOT_SITL`` if set, else ``<repo>/../shared/ardupilot-sitl`` (the folder holding ``run-copter`` and
    ``bin/arducopter``; also looked for beside the folders further up, for git worktrees).
    :func:`why_no_ardupilot_sitl` says why it is unusable, None when it is usable.

Instances and the payload
    ``INSTANCE`` i adds 10 i to every port (SERIAL0 tcp 5760 + 10 i for the companion, SERIAL1 5762 + 10 i for the
    monitor). ArduPilot's payload simulation always connects to 127.0.0.1:5763, instance 0's SERIAL2, whatever the
    instance: payload flights run on instance 0, one at a time on the machine. On a shared machine wrap whatever
    starts it in ``flock /tmp/ardupilot-instance0.lock`` (:data:`INSTANCE0_LOCK`; not taken here, so that a test run
    under that ``flock`` does not wait for itself); :meth:`ArduPilotSitl.start` refuses to start while another
    process listens on the instance's ports.

Lifetime
    :meth:`ArduPilotSitl.start` runs ``run-copter INSTANCE WORKDIR -- --serial0 tcp:0`` (SERIAL0 without ``:wait``:
    the SITL boots at once instead of waiting for its first client, so that the companion can connect only once it
    can fly) in its own process group, with stdout and stderr in ``WORKDIR/arducopter.log`` and the load from
    ``payload_kg`` / ``line_m`` (``SLUNG_PAYLOAD_KG`` / ``SLUNG_LINE_M``). It then attaches the passive monitor on
    SERIAL1 and waits until the pre-arm checks pass and EKF3 gives a local position (about 40 s after boot;
    :class:`ArduPilotSitlError` with the log's tail after ``ready_timeout_s``). :meth:`ArduPilotSitl.stop` sends
    SIGTERM to the group, then SIGKILL after ``stop_timeout_s``; as a context manager it stops on exit. The DataFlash
    logs (one per arming) are ``WORKDIR/logs/*.BIN``: :meth:`ArduPilotSitl.dataflash_logs`.

Clock
    ``--speedup 1``: the SITL runs on the wall clock; its boot clock (MAVLink ``time_boot_ms``, DataFlash ``TimeUS``)
    is the one ``slung fly`` writes as ``t_vehicle``, so a flight's tick log indexes the DataFlash truth directly.
"""

from __future__ import annotations

import os
import socket
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from sim_bridge.sitl.ardupilot_monitor import PayloadMonitor
from sim_bridge.sitl.sitl_process import SitlProcess, shared_folder

#: environment variable naming the SITL folder (``run-copter``, ``bin/arducopter``)
ENV_SITL = "SLUNG_ARDUPILOT_SITL"
#: the machine-wide lock of instance 0, the only instance whose payload simulation connects (see module docstring)
INSTANCE0_LOCK = Path("/tmp/ardupilot-instance0.lock")
#: SERIAL0 (the companion) and SERIAL1 (the monitor) of instance 0; instance i adds 10 i
SERIAL0_PORT = 5760
SERIAL1_PORT = 5762


class ArduPilotSitlError(RuntimeError):
    """ArduPilot SITL could not be started or did not become ready (the message includes the log's tail)."""


def default_sitl_path() -> Path:
    """``$SLUNG_ARDUPILOT_SITL``, else ``<repo>/../shared/ardupilot-sitl`` looked for beside each folder above the
    repository (a git worktree at ``work/wt/NAME`` finds ``work/shared/ardupilot-sitl``); the first candidate when
    none exists."""
    return shared_folder("ardupilot-sitl", ENV_SITL, "run-copter")


def why_no_ardupilot_sitl(root: Path | None = None) -> str | None:
    """None when a usable SITL is at ``root`` (default :func:`default_sitl_path`), else the reason it is not."""
    root = default_sitl_path() if root is None else root
    script, exe = root / "run-copter", root / "bin" / "arducopter"
    if not script.is_file():
        return f"no ArduPilot SITL launcher at {script} (set ${ENV_SITL} to the ardupilot-sitl folder)"
    if not exe.is_file():
        return f"no ArduPilot SITL binary at {exe}"
    for path in (script, exe):
        if not os.access(path, os.X_OK):
            return f"{path} is not executable"
    if not (root / "params" / "copter.parm").is_file():
        return f"{root / 'params'} holds no copter.parm (the SITL's default parameters)"
    return None


def port_in_use(port: int) -> bool:
    """Whether something listens on 127.0.0.1:``port`` (another SITL holding the instance's ports)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.settimeout(0.5)
        return s.connect_ex(("127.0.0.1", port)) == 0


@dataclass
class ArduPilotSitl(SitlProcess):
    """One ArduPilot Copter SITL with its slung payload (see the module docstring).

    instance: 0-9 (the payload connects only on 0); workdir: eeprom, DataFlash logs (a new temporary folder when
    None); payload_kg: the load (0: none); line_m: its line (m); extra_args: more ``arducopter`` options.
    """

    NAME = "ArduPilot SITL"
    LOG_NAME = "arducopter.log"
    ERROR = ArduPilotSitlError

    ready_timeout_s: float = 120.0  # ready: the pre-arm checks passed and EKF3 gives a local position (~40 s)
    payload_kg: float = 1.2
    line_m: float = 1.0
    extra_args: tuple[str, ...] = ()
    monitor: PayloadMonitor | None = field(default=None, init=False)

    # ------------------------------------------------------------------------------------------ facts ---
    @property
    def connection_url(self) -> str:
        """The companion computer's side, SERIAL0 (``slung fly --connect``)."""
        return f"tcp:127.0.0.1:{SERIAL0_PORT + 10 * self.instance}"

    @property
    def monitor_url(self) -> str:
        """SERIAL1, where :class:`PayloadMonitor` listens."""
        return f"tcp:127.0.0.1:{SERIAL1_PORT + 10 * self.instance}"

    def dataflash_logs(self) -> list[Path]:
        """The DataFlash logs written so far (one per arming), oldest first."""
        if self.workdir is None:
            return []
        return sorted((self.workdir / "logs").glob("*.BIN"))

    # -------------------------------------------------------------------------------------- lifetime ---
    def start(self) -> ArduPilotSitl:
        """Start the SITL and wait until it can fly; :class:`ArduPilotSitlError` if it is absent or not ready."""
        root = self.root or default_sitl_path()
        why = why_no_ardupilot_sitl(root)
        if why is not None:
            raise ArduPilotSitlError(why)
        self.root = root
        taken = [p for p in (SERIAL0_PORT + 10 * self.instance, SERIAL1_PORT + 10 * self.instance) if port_in_use(p)]
        if taken:
            raise ArduPilotSitlError(
                f"127.0.0.1 port {taken[0]} is already listening: another ArduPilot SITL runs as instance "
                f"{self.instance}"
            )
        if self.workdir is None:
            self.workdir = Path(tempfile.mkdtemp(prefix=f"slung-ardupilot-{self.instance}-"))
        self.workdir.mkdir(parents=True, exist_ok=True)
        env = dict(os.environ, SLUNG_PAYLOAD_KG=f"{self.payload_kg:g}", SLUNG_LINE_M=f"{self.line_m:g}")
        cmd = [str(root / "run-copter"), str(self.instance), str(self.workdir), "--", "--serial0", "tcp:0"]
        return self._launch([*cmd, *self.extra_args], env)

    def _wait_ready(self, t0: float) -> None:
        assert self._proc is not None
        deadline = t0 + self.ready_timeout_s
        while self.monitor is None:  # SERIAL1 listens a moment after the process starts
            if self._proc.poll() is not None:
                raise self._exited()
            try:
                self.monitor = PayloadMonitor.attach(self.monitor_url)
            except OSError:
                if time.monotonic() > deadline:
                    raise ArduPilotSitlError(f"SERIAL1 ({self.monitor_url}) never listened") from None
                time.sleep(0.2)
        while time.monotonic() < deadline:
            if self.monitor.ready():
                return
            if self._proc.poll() is not None:
                raise self._exited()
            time.sleep(0.2)
        raise ArduPilotSitlError(
            f"ArduPilot SITL instance {self.instance} not ready within {self.ready_timeout_s:g} s "
            f"({self.monitor.readiness()}); log {self.log_path}: {self._tail()}"
        )

    def _before_stop(self) -> None:
        if self.monitor is not None:
            self.monitor.close()


__all__ = [
    "ENV_SITL",
    "INSTANCE0_LOCK",
    "ArduPilotSitl",
    "ArduPilotSitlError",
    "default_sitl_path",
    "port_in_use",
    "why_no_ardupilot_sitl",
]
