"""The one line that says the compiled kernels are being compiled (issue 35): numba compiles a kernel the first time
it is called on a machine and keeps it in its cache (``layout``: ``cache=True``), so a first run waits for the
compiler and later runs load the kernels in a moment. Said on stderr once per process, when numba starts compiling
a kernel it did not find in its cache (its ``numba:compile`` event, which a cache hit does not raise): never when
the cache is warm, and wherever the kernels are first called from.
"""

from __future__ import annotations

import sys
from typing import Any

from numba.core import event

#: what a cold cache costs: every kernel of the sweep's seven controllers and the filter compiled on 2 cores shared
#: with other work (``slung sweep --runs 1 --workers 0``, 8 Dec 2026, load average 3.4: 129 s cold, 13 s warm)
COLD_COMPILE_MIN = 2
LINE = (
    f"compiling slung's kernels once for this machine (about {COLD_COMPILE_MIN} min on 2 busy cores; later runs "
    "load them)..."
)


class _FirstCompile(event.Listener):  # type: ignore[misc]
    """Prints :data:`LINE` at the first compilation of this process, then nothing."""

    def __init__(self) -> None:
        self.said = False

    def on_start(self, ev: Any) -> None:
        if not self.said:
            self.said = True
            print(LINE, file=sys.stderr, flush=True)

    def on_end(self, ev: Any) -> None:
        pass


event.register("numba:compile", _FirstCompile())
