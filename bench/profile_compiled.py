"""Where a compiled sweep's CPU goes, by kernel: ``perf`` on ``slung sweep``'s compiled engine with numba's machine
code named.

numba's JIT code has no symbols, so ``perf report`` shows bare addresses for most of a sweep. This script compiles
the engine's kernels, writes ``/tmp/perf-PID.map`` (the JIT map ``perf report`` reads: start, size and
name of every compiled function of the engine and the kernel packages it composes), prints its PID, waits
``--wait`` s for a profiler to attach, then flies ``--runs`` runs of the default sweep file for ``--controller``:

    python bench/profile_compiled.py --runs 2000 &
    perf record -F 4000 -p PID -o perf.data -- sleep 10
    perf report -i perf.data --no-children --sort sym

Functions numba inlined (``layout.inline_kernel``) count in their caller. Only functions compiled in this process
have addresses numba can give: a kernel loaded from numba's cache has none, so the script runs with a cache
directory of its own, empty, removed at the end (``NUMBA_CACHE_DIR``, set before numba is imported; a minute of
compiling).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

#: the packages whose numba functions the map names: the engine and the kernels it composes
KERNEL_MODULES = (
    "estimators.kernels",
    "estimators.filters.compiled",
    "offboard.control.compiled",
    "offboard.harness.compiled",
    "sim_bridge.inner.compiled",
    "sim_bridge.plant.compiled",
)


def perf_map_lines() -> list[str]:
    """``perf``'s JIT map lines (hex start, hex size, name) of every function numba compiled in this process for
    the engine's modules and the kernel packages it composes (:data:`KERNEL_MODULES`); a function's size is the
    distance to the next one (at most 4 KB past the last)."""
    from numba.core.registry import CPUDispatcher

    entries: dict[str, int] = {}
    for name, module in list(sys.modules.items()):
        if not name.startswith(KERNEL_MODULES):
            continue
        for obj in vars(module).values():
            if not isinstance(obj, CPUDispatcher):
                continue
            for compiled in obj.overloads.values():
                library = compiled.library
                for fn in library._final_module.functions:  # (numba keeps no public list of a library's symbols)
                    if fn.is_declaration or fn.name in entries:
                        continue
                    address = library.get_pointer_to_function(fn.name)
                    if address:
                        entries[fn.name] = address
    ordered = sorted((address, name) for name, address in entries.items())
    lines = []
    for i, (address, name) in enumerate(ordered):
        gap = ordered[i + 1][0] - address if i + 1 < len(ordered) else 4096
        lines.append(f"{address:x} {min(gap, 1 << 20):x} {readable(name)}")
    return lines


def readable(mangled: str) -> str:
    """``module.function`` of a numba symbol (``_ZN8offboard7harness8compiled5plant13rk4_step_trigB4v547B52...``:
    length-prefixed parts, then the overload and its signature), the symbol itself when it is not one."""
    parts, rest = [], mangled.split("compiled", 1)[-1]
    while rest[:1].isdigit() and len(parts) < 2:
        digits = len(rest) - len(rest.lstrip("0123456789"))
        n = int(rest[:digits])
        parts.append(rest[digits : digits + n])
        rest = rest[digits + n :]
    return ".".join(parts) if len(parts) == 2 else mangled[:100]


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="slung-profile-numba-") as cache:
        # before numba's import (the laws' names below import it): compile here, so every function has an address
        os.environ["NUMBA_CACHE_DIR"] = cache
        return _profile()


def _profile() -> int:
    from offboard.harness.compiled.inputs import COMPILED_LAWS

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=2000, help="runs of the default sweep file to fly")
    parser.add_argument("--controller", default="smc", choices=COMPILED_LAWS, help="the sweep's row to fly")
    parser.add_argument("--wait", type=float, default=3.0, help="seconds to wait for a profiler to attach")
    args = parser.parse_args()
    if args.runs < 1 or args.wait < 0.0:
        parser.error("--runs must be at least 1 and --wait not negative")

    from offboard.harness import sweep
    from offboard.harness.compiled import engine

    config = sweep.load_config(None)
    engine.run_batch(config, args.controller, [0])  # compile
    lines = perf_map_lines()
    Path(f"/tmp/perf-{os.getpid()}.map").write_text("\n".join(lines) + "\n", encoding="ascii")
    print(
        f"PID {os.getpid()}: {len(lines)} functions in /tmp/perf-{os.getpid()}.map; flying in {args.wait} s", flush=True
    )
    time.sleep(args.wait)
    cpu0, wall0 = time.process_time(), time.perf_counter()
    engine.run_batch(config, args.controller, list(range(args.runs)))
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    print(f"{args.runs} runs of {args.controller}: {wall:.2f} s wall, {cpu:.2f} s CPU", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
