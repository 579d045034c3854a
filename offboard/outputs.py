"""Writing results: atomically (write a temporary file beside the target, fsync, rename), so that a crash or
Ctrl-C never leaves a half-written metrics.json, time series or figure behind."""

from __future__ import annotations

import json
import logging
import math
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from estimators.errors import UserError

log = logging.getLogger(__name__)


def prepare_output_dir(path: str | Path) -> Path:
    """Create ``path`` if needed and check that it is a writable folder; UserError otherwise."""
    p = Path(path)
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create output folder {p}: {exc.strerror or exc}") from None
    if not p.is_dir():
        raise UserError(f"output path {p} exists and is not a folder")
    if not os.access(p, os.W_OK | os.X_OK):
        raise UserError(f"output folder {p} is not writable")
    return p


def user_file_mode() -> int:
    """The permission bits a new file gets from ``open()`` under this process's umask (0o666 & ~umask): what
    the tlogs get, and what the atomic writes give their files (``mkstemp`` alone would leave them 0600)."""
    mask = None
    try:  # Linux >= 4.7 tells the umask without changing it (os.umask would change it for every thread a moment)
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    mask = int(line.split()[1], 8)
                    break
    except OSError:
        pass
    if mask is None:
        mask = os.umask(0o022)
        os.umask(mask)
    return 0o666 & ~mask


def write_atomic(path: str | Path, writer: Callable[[Path], None]) -> Path:
    """Call ``writer(tmp_path)`` to produce the file, then rename it onto ``path`` in one step. The file gets the
    permissions of any file the user creates (:func:`user_file_mode`)."""
    target = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        writer(tmp_path)
        os.chmod(tmp_path, user_file_mode())
        with open(tmp_path, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp_path, target)
    except BaseException:
        tmp_path.unlink(missing_ok=True)
        raise
    return target


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write a text file atomically (UTF-8)."""
    return write_atomic(path, lambda p: p.write_text(text, encoding="utf-8"))


def _json_safe(obj: Any) -> Any:
    """JSON has no NaN or infinity: write them as null (documented in docs/usage.md)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_json_safe(v) for v in obj]
    return obj


def write_json_atomic(path: str | Path, data: dict[str, Any]) -> Path:
    """Write ``data`` as indented, strict JSON (non-finite numbers become null), atomically."""
    return write_text_atomic(path, json.dumps(_json_safe(data), indent=2, sort_keys=False, allow_nan=False) + "\n")


class OutputFailures:
    """The outputs of a run that could not be written (a full disk, a file-size limit, an I/O error): each is
    warned about on one line as it stops, the run goes on to write the others, and the caller reports them apart
    from the run's own result (the exit code of a flight is the flight's)."""

    def __init__(self) -> None:
        #: one line per failed output: "<name>: <reason>"
        self.failed: list[str] = []

    def attempt(self, name: str, write: Callable[[], Any]) -> bool:
        """Run ``write()``; False (warned and recorded) if it raised an OSError."""
        try:
            write()
        except OSError as exc:  # the file it names is the temporary one beside the target: name the target
            self.note(name, exc.strerror or str(exc))
            return False
        return True

    def note(self, name: str, reason: str) -> None:
        """Record (and warn about) an output that stopped for ``reason``."""
        why = f"{name}: {reason}"
        self.failed.append(why)
        log.warning("output stopped: %s", why)
