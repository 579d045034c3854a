"""What the two real-autopilot launchers share (``sim_bridge.sitl.px4_sitl``, ``sim_bridge.sitl.ardupilot_sitl``):
finding the prebuilt SITL folder, and one SITL process's lifetime.

:class:`SitlProcess` is one autopilot process started in its own process group (so that stopping it reaches every
child) with stdout and stderr in a log file of its working folder; :meth:`SitlProcess._launch` starts it and waits
until the launcher's ``_wait_ready`` says it can fly (stopping it when that fails); :meth:`SitlProcess.stop` sends
SIGTERM to the group, SIGKILL after ``stop_timeout_s`` (and to the children a dead parent left). As a context manager
it starts on entry and stops on exit. A launcher subclasses it with its own command, environment and readiness.
This is a test and benchmark harness, not the flight path.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import ClassVar, TypeVar

_S = TypeVar("_S", bound="SitlProcess")


def shared_folder(name: str, env_var: str, marker: str) -> Path:
    """``$env_var`` if set, else ``<repo>/../shared/<name>`` looked for beside each folder above the repository (a
    git worktree at ``work/wt/NAME`` finds ``work/shared/<name>``): the first that holds the file ``marker``
    (relative to the folder); ``<repo>/../shared/<name>`` when none does."""
    env = os.environ.get(env_var)
    if env:
        return Path(env)
    repo = Path(__file__).resolve().parents[2]
    candidates = [parent / "shared" / name for parent in (repo, *repo.parents)]
    return next((c for c in candidates if (c / marker).is_file()), candidates[1])


@dataclass
class SitlProcess:
    """One SITL process (see the module docstring). instance: 0-9; workdir: the process's working folder (the
    launcher makes a temporary one when None); root: the SITL folder (the launcher's default when None)."""

    #: the autopilot's name in messages ("PX4 SITL"), its console log's file name, its error class
    NAME: ClassVar[str] = "SITL"
    LOG_NAME: ClassVar[str] = "sitl.log"
    ERROR: ClassVar[type[RuntimeError]] = RuntimeError

    instance: int = 0
    workdir: Path | None = None
    root: Path | None = None
    ready_timeout_s: float = 60.0
    stop_timeout_s: float = 10.0
    _proc: subprocess.Popen[bytes] | None = field(default=None, init=False, repr=False)
    _log_fh: object = field(default=None, init=False, repr=False)
    #: wall-clock seconds from the process start to readiness
    ready_after_s: float | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        if not (0 <= self.instance <= 9):
            raise ValueError(f"{self.NAME} instance must be 0..9, got {self.instance}")

    @property
    def log_path(self) -> Path:
        """The autopilot's console output (stdout and stderr)."""
        assert self.workdir is not None, "start() first"
        return self.workdir / self.LOG_NAME

    def log_text(self) -> str:
        """The autopilot's console output so far."""
        try:
            return self.log_path.read_text(encoding="utf-8", errors="replace")
        except (OSError, AssertionError):
            return ""

    @property
    def running(self) -> bool:
        """Whether the autopilot process is alive."""
        return self._proc is not None and self._proc.poll() is None

    def _launch(self: _S, cmd: list[str], env: dict[str, str]) -> _S:
        """Start ``cmd`` in the working folder with ``env`` and wait until ready (``_wait_ready``); stopped again
        when that fails. Sets ``ready_after_s``."""
        assert self.workdir is not None
        self._log_fh = open(self.log_path, "wb", buffering=0)  # noqa: SIM115 - closed in stop()
        t0 = time.monotonic()
        self._started(t0)
        self._proc = subprocess.Popen(
            cmd,
            cwd=self.workdir,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=self._log_fh,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        try:
            self._wait_ready(t0)
        except BaseException:
            self.stop()
            raise
        self.ready_after_s = time.monotonic() - t0
        return self

    def _started(self, t0: float) -> None:
        """Called with the local monotonic time (s) just before the process starts."""

    def _wait_ready(self, t0: float) -> None:
        """Return once the autopilot can fly; raise ``ERROR`` (with :meth:`_exited` when the process is gone)."""
        raise NotImplementedError

    def _exited(self) -> RuntimeError:
        """The error of a process that exited before it was ready, with the log's tail."""
        assert self._proc is not None
        return self.ERROR(
            f"{self.NAME} instance {self.instance} exited with code {self._proc.returncode} before it was ready; "
            f"log {self.log_path}: {self._tail()}"
        )

    def _tail(self, lines: int = 5) -> str:
        return " | ".join(self.log_text().strip().splitlines()[-lines:])

    def _before_stop(self) -> None:
        """What a launcher closes before its process is signalled."""

    def stop(self) -> int | None:
        """SIGTERM to the process group, SIGKILL after ``stop_timeout_s``; the exit code (None if never started).
        Idempotent."""
        self._before_stop()
        proc = self._proc
        code = None
        if proc is not None:
            if proc.poll() is None:
                _signal_group(proc, signal.SIGTERM)
                try:
                    proc.wait(self.stop_timeout_s)
                except subprocess.TimeoutExpired:
                    _signal_group(proc, signal.SIGKILL)
                    proc.wait(5.0)
            else:
                _signal_group(proc, signal.SIGKILL)  # children left by a dead parent
            code = proc.returncode
        fh = self._log_fh
        if fh is not None:
            fh.close()  # type: ignore[attr-defined]
            self._log_fh = None
        return code

    def start(self: _S) -> _S:
        """Start the autopilot and wait until it can fly (the launcher's)."""
        raise NotImplementedError

    def __enter__(self: _S) -> _S:
        return self.start() if not self.running else self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()


def _signal_group(proc: subprocess.Popen[bytes], sig: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, sig)  # start_new_session: the group id is the process' id


__all__ = ["SitlProcess", "shared_folder"]
