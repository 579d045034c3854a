"""Start and stop a real PX4 SITL autopilot (the prebuilt build, ``shared/px4-sitl``): with its SIH quadrotor, or
with an external simulator (``Px4Sitl(model=px4_hil.HIL_MODEL)``: ``sim_bridge.sitl.px4_hil``, a vehicle with a load).

This is a test and benchmark harness, not the flight path: ``slung fly`` talks to whatever autopilot listens on
the link; this module only starts one on this machine. The real PX4 is the reference the emulator imitates.

Where the SITL is
    ``$SLUNG_PX4_SITL`` if set, else ``<repo>/../shared/px4-sitl`` (the folder holding ``bin/px4`` and ``etc``;
    also looked for beside the folders further up, for git worktrees).
    :func:`find_px4_sitl` returns None (with :func:`why_no_px4_sitl` saying why) when it is absent.

Why a private bin folder
    PX4's startup script calls its modules through command aliases (``px4-param``, ``px4-commander``, ...), which
    a PX4 build makes as symlinks to ``px4``. In the shipped folder they were flattened into 3-byte text files
    holding ``px4`` (not executable), so the script fails with ``px4-param: Permission denied``. Each
    :class:`Px4Sitl` makes ``WORKDIR/bin`` where every such alias is a symlink to the real ``bin/px4`` and the other
    files (``px4-alias.sh``) are copies, and puts it first on the PATH of the PX4 process.

Instances
    ``INSTANCE`` i (0-9) shifts every port by i: PX4 sends the offboard link to 127.0.0.1:14540+i (so the
    companion listens there: :attr:`Px4Sitl.connection_url` is ``udpin:127.0.0.1:14540+i``) and is system i+1.
    Processes that run at the same time need distinct instances.

Lifetime
    :meth:`Px4Sitl.start` runs ``px4 -d -i INSTANCE -w WORKDIR etc`` in its own process group (so that stopping it
    reaches every child) with stdout and stderr in ``WORKDIR/px4.log``, and waits for ``Ready for takeoff!``
    (typically 5-15 s; :class:`Px4SitlError` with the log's tail after ``ready_timeout_s``). :meth:`Px4Sitl.stop`
    sends SIGTERM to the group, then SIGKILL after ``stop_timeout_s``. Used as a context manager it stops on exit.
    The ULog flight logs (one per arming) are under ``WORKDIR/log``: :meth:`Px4Sitl.ulogs`.

PX4's clock
    PX4's boot clock (MAVLink ``time_boot_ms``, ULog timestamps) is not the wall clock: on a loaded machine it ran
    at about half speed (CI, 2026-12-04: 29 s of wall clock left 15.7 s of PX4's log after a hand-over).
    :meth:`Px4Sitl.run_for` waits for seconds of PX4's own clock, read from its offboard link.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from pymavlink import mavutil

from sim_bridge.sitl.sitl_process import SitlProcess, shared_folder

#: environment variable naming the SITL folder (``bin/px4``, ``etc``)
ENV_SITL = "SLUNG_PX4_SITL"
#: what PX4 prints when it is ready to arm
READY_TEXT = "Ready for takeoff!"
#: the SIH quadrotor of the build (airframe 10040)
SIH_MODEL = "sihsim_quadx"
#: the port PX4 instance 0 sends its offboard (onboard-mode) MAVLink stream to; instance i adds i
OFFBOARD_PORT_BASE = 14540


class Px4SitlError(RuntimeError):
    """PX4 SITL could not be started or did not become ready (the message includes the log's tail)."""


def default_sitl_path() -> Path:
    """``$SLUNG_PX4_SITL``, else ``<repo>/../shared/px4-sitl``, looked for beside each folder above the repository
    (a git worktree at ``work/wt/NAME`` finds ``work/shared/px4-sitl``); the first candidate when none exists."""
    return shared_folder("px4-sitl", ENV_SITL, "bin/px4")


def why_no_px4_sitl(root: Path | None = None) -> str | None:
    """None when a usable SITL is at ``root`` (default :func:`default_sitl_path`), else the reason it is not."""
    root = default_sitl_path() if root is None else root
    exe = root / "bin" / "px4"
    if not exe.is_file():
        return f"no PX4 SITL binary at {exe} (set ${ENV_SITL} to the px4-sitl folder)"
    if not os.access(exe, os.X_OK):
        return f"{exe} is not executable"
    if not (root / "etc" / "init.d-posix" / "rcS").is_file():
        return f"{root / 'etc'} holds no PX4 startup script (init.d-posix/rcS)"
    return None


def find_px4_sitl(root: Path | None = None) -> Path | None:
    """The SITL folder when usable, else None (see :func:`why_no_px4_sitl`)."""
    root = default_sitl_path() if root is None else root
    return None if why_no_px4_sitl(root) is not None else root


def make_bin_dir(sitl_bin: Path, dest: Path) -> Path:
    """``dest`` holding a symlink to ``sitl_bin/px4`` for every alias file whose content is ``px4`` (or which already
    is a symlink) and a copy of every other file; returns ``dest``."""
    dest.mkdir(parents=True, exist_ok=True)
    real = (sitl_bin / "px4").resolve()
    for src in sorted(sitl_bin.iterdir()):
        target = dest / src.name
        if target.exists() or target.is_symlink():
            continue
        alias = src.name.startswith("px4-") and (src.is_symlink() or _is_flattened_alias(src))
        if src.name == "px4" or alias:
            target.symlink_to(real)
        elif src.is_file():
            shutil.copy2(src, target)
    return dest


def _is_flattened_alias(path: Path) -> bool:
    try:
        return path.stat().st_size < 16 and path.read_bytes().strip() == b"px4"
    except OSError:
        return False


@dataclass
class Px4Sitl(SitlProcess):
    """One PX4 SITL instance with the SIH quadrotor or an external simulator (``model``; see the module docstring).

    instance: 0-9 (ports and system id shift by it); workdir: parameters, dataman, logs (a new temporary folder
    when None, kept after stop so that the ULogs can be read; removed by :meth:`cleanup`); params: parameters set at
    start through the environment hook PX4's rcS reads (``PX4_PARAM_<NAME>``), e.g. ``{"COM_OBL_RC_ACT": 5}``.
    nice: the PX4 process's niceness (``nice -n``). The default, -10, stands in for the autopilot's own flight
    computer: on a machine shared with the companion's loop and other work, PX4 gets the CPU first (under
    ``stress --cpu 2`` on 2 cores at normal priority, EKF2's height drifted 0.17 m from the truth in a 20 s
    hover, where quiet-machine hovers were within 0.015-0.091 m, docs/deploy.md section 2a). Without the
    privilege to raise priority (not root, no CAP_SYS_NICE) ``nice`` says so in ``px4.log`` and PX4 runs at
    normal priority; 0 leaves it alone.
    """

    NAME = "PX4 SITL"
    LOG_NAME = "px4.log"
    ERROR = Px4SitlError

    params: dict[str, float] = field(default_factory=dict)
    nice: int = -10
    #: PX4_SIM_MODEL: the SIH quadrotor (default), or ``px4_hil.HIL_MODEL`` for an external simulator on TCP
    #: 4560 + instance (``sim_bridge.sitl.px4_hil``: the vehicle with its slung load)
    model: str = SIH_MODEL
    _own_workdir: bool = field(default=False, init=False, repr=False)
    #: local monotonic time (s) at which the PX4 process was started: PX4's boot clock (ULog timestamps,
    #: MAVLink time_boot_ms) runs from about then, in real time (SIH is not lockstepped)
    started_monotonic: float | None = field(default=None, init=False)

    # ------------------------------------------------------------------------------------------ facts ---
    @property
    def connection_url(self) -> str:
        """The companion computer's side of the offboard link (``slung fly --connect``)."""
        return f"udpin:127.0.0.1:{OFFBOARD_PORT_BASE + self.instance}"

    @property
    def system_id(self) -> int:
        """MAVLink system id of this instance (instance + 1)."""
        return self.instance + 1

    def ulogs(self) -> list[Path]:
        """The ULog files written so far (one per arming), oldest first."""
        if self.workdir is None:
            return []
        return sorted((self.workdir / "log").glob("*/*.ulg"), key=lambda p: (p.stat().st_mtime, p.name))

    # -------------------------------------------------------------------------------------- lifetime ---
    def start(self) -> Px4Sitl:
        """Start PX4 and wait until it is ready for take-off; :class:`Px4SitlError` if it is absent or not ready."""
        root = self.root or default_sitl_path()
        why = why_no_px4_sitl(root)
        if why is not None:
            raise Px4SitlError(why)
        self.root = root
        if self.workdir is None:
            self.workdir = Path(tempfile.mkdtemp(prefix=f"slung-px4-{self.instance}-"))
            self._own_workdir = True
        self.workdir.mkdir(parents=True, exist_ok=True)
        bin_dir = make_bin_dir(root / "bin", self.workdir / "bin")
        env = dict(os.environ)
        env.update(PATH=f"{bin_dir}{os.pathsep}{env.get('PATH', '')}", PX4_SIM_MODEL=self.model)
        if self.model == SIH_MODEL:
            env["PX4_SIMULATOR"] = "sihsim"
        else:  # PX4's rcS then starts simulator_mavlink, which connects to the external simulator
            env.pop("PX4_SIMULATOR", None)
        for name, value in self.params.items():
            env[f"PX4_PARAM_{name}"] = repr(value) if isinstance(value, float) else str(value)
        cmd = [str(bin_dir / "px4"), "-d", "-i", str(self.instance), "-w", str(self.workdir), str(root / "etc")]
        if self.nice != 0 and shutil.which("nice"):
            cmd = ["nice", "-n", str(self.nice), *cmd]  # niceness before exec: every PX4 thread inherits it
        return self._launch(cmd, env)

    def _started(self, t0: float) -> None:
        self.started_monotonic = t0

    def _wait_ready(self, t0: float) -> None:
        assert self._proc is not None
        while time.monotonic() - t0 < self.ready_timeout_s:
            if READY_TEXT in self.log_text():
                return
            if self._proc.poll() is not None:
                raise self._exited()
            time.sleep(0.1)
        raise Px4SitlError(
            f"PX4 SITL instance {self.instance} not ready within {self.ready_timeout_s:g} s; "
            f"log {self.log_path}: {self._tail()}"
        )

    def run_for(self, seconds: float, wall_limit_s: float | None = None) -> float:
        """Let PX4 run by itself for ``seconds`` of its own boot clock, read from the ``time_boot_ms`` of what it
        sends on the offboard link (nobody else may be listening there: call it between flights). Gives up after
        ``wall_limit_s`` of the wall clock (default ``3 * seconds + 10``) or when PX4 exits. Returns the seconds of
        PX4's clock that passed while it listened (0.0 if PX4 sent nothing with a time), for the caller to judge."""
        limit = 3.0 * seconds + 10.0 if wall_limit_s is None else wall_limit_s
        deadline = time.monotonic() + limit
        conn = mavutil.mavlink_connection(self.connection_url, source_system=255)
        first: float | None = None
        passed = 0.0
        try:
            while time.monotonic() < deadline and self.running:
                msg = conn.recv_match(blocking=True, timeout=0.5)
                boot_ms = getattr(msg, "time_boot_ms", None) if msg is not None else None
                if boot_ms is None:
                    continue
                now = float(boot_ms) * 1e-3
                first = now if first is None else first
                passed = max(passed, now - first)
                if passed >= seconds:
                    break
        finally:
            conn.close()
        return passed

    def cleanup(self) -> None:
        """Stop and remove the working folder if this object made it."""
        self.stop()
        if self._own_workdir and self.workdir is not None:
            shutil.rmtree(self.workdir, ignore_errors=True)


__all__ = [
    "ENV_SITL",
    "READY_TEXT",
    "Px4Sitl",
    "Px4SitlError",
    "default_sitl_path",
    "find_px4_sitl",
    "make_bin_dir",
    "why_no_px4_sitl",
]
