"""Project rules that a reviewer would otherwise check by hand: lint, package layering, README vs CI."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from collections import deque
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("estimators", "offboard", "sim_bridge")

#: The live flight path, by folder: the packages ``slung fly`` loads on a companion computer (control laws and
#: references, the link and the loop, the run records it writes) and the log tools that run beside it.
FLIGHT_PACKAGES = ("offboard.control", "offboard.flight", "offboard.logs")
#: What no module of the flight path may load, directly, lazily inside a function, or through another module.
FORBIDDEN_FROM_FLIGHT = ("sim_bridge", "offboard.harness")
#: What the flight path loads only after the flight (inside functions): the reports. Never at import time.
AFTER_FLIGHT = ("offboard.report",)
#: Everything the flight path may reach at all: the shared bottom layer, its own packages, the reports and the
#: command-line helpers shared by every ``slung`` command.
FLIGHT_REACHABLE = ("estimators", *FLIGHT_PACKAGES, *AFTER_FLIGHT, "offboard.outputs", "offboard.cli_args")


def _package_modules(package: str) -> list[str]:
    """Every module under ``package``'s folder (sub-packages included), by dotted name."""
    base = ROOT.joinpath(*package.split("."))
    names = [".".join(p.relative_to(ROOT).with_suffix("").parts) for p in sorted(base.rglob("*.py"))]
    return [n.removesuffix(".__init__") for n in names]


FLY_PATH = tuple(m for p in FLIGHT_PACKAGES for m in _package_modules(p))


def _within(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


def _imports(package: str) -> set[tuple[str, str]]:
    found = set()
    for path in (ROOT / package).rglob("*.py"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                found |= {(str(path.relative_to(ROOT)), a.name.split(".")[0]) for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.add((str(path.relative_to(ROOT)), node.module.split(".")[0]))
    return found


def _module_path(name: str) -> Path | None:
    """The source file of project module ``name`` (a package's ``__init__.py``), None outside the project."""
    base = ROOT.joinpath(*name.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def _nodes(tree: ast.AST, top_level_only: bool) -> list[ast.AST]:
    """Every node of ``tree``; with ``top_level_only``, none inside a function (what runs when the module loads)."""
    if not top_level_only:
        return list(ast.walk(tree))
    found, todo = [], [tree]
    while todo:
        node = todo.pop()
        found.append(node)
        todo += [c for c in ast.iter_child_nodes(node) if not isinstance(c, (ast.FunctionDef, ast.AsyncFunctionDef))]
    return found


def _module_imports(name: str, path: Path, top_level_only: bool = False) -> set[str]:
    """Every module that the source of ``name`` may import, wherever the import statement is (top level, inside a
    function or a branch; with ``top_level_only``, outside functions only): ``import a.b``, ``from a import b``
    (``a`` and ``a.b``), relative imports, and ``importlib.import_module`` / ``__import__`` of a literal name."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in _nodes(ast.parse(path.read_text(encoding="utf-8")), top_level_only):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1])
                module = f"{base}.{node.module}" if node.module else base
            else:
                module = node.module or ""
            found.add(module)
            found |= {f"{module}.{a.name}" for a in node.names}
        elif (
            isinstance(node, ast.Call)
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
            and (
                (isinstance(node.func, ast.Attribute) and node.func.attr == "import_module")
                or (isinstance(node.func, ast.Name) and node.func.id in ("import_module", "__import__"))
            )
        ):
            found.add(node.args[0].value)
    return found


def _import_closure(roots: tuple[str, ...], top_level_only: bool = False) -> dict[str, list[str]]:
    """Every project module reachable from ``roots`` by imports (with their parent packages), each with a shortest
    chain of modules that leads to it (breadth first, in sorted order: the same chain every time). With
    ``top_level_only``, through imports outside functions only: what loading ``roots`` loads."""
    chains: dict[str, list[str]] = {}
    todo = deque((r, [r]) for r in roots)
    while todo:
        name, chain = todo.popleft()
        if name in chains or name.split(".")[0] not in PACKAGES:
            continue
        path = _module_path(name)
        if path is None:
            continue  # ``from package import function``: not a module
        chains[name] = chain
        parts = name.split(".")
        todo += [(".".join(parts[:i]), chain) for i in range(1, len(parts))]
        todo += [(m, [*chain, m]) for m in sorted(_module_imports(name, path, top_level_only))]
    return chains


def test_fly_path_imports_no_simulator_module_even_lazily() -> None:
    """Static: no import anywhere in the flight path's folders (functions included) reaches ``sim_bridge`` or the
    simulation harness, directly or through another project module; whatever it reaches lies in the folders it may
    use. The fly path must run on a companion computer without the simulator."""
    assert {
        "offboard.flight.fly_cli",
        "offboard.flight.loop",
        "offboard.logs.replay_cli",
        "offboard.control.smc",
    } <= set(FLY_PATH)
    assert {f"offboard.flight.link.{m}" for m in ("connection", "management", "telemetry", "setpoints")} <= set(
        FLY_PATH
    )
    chains = _import_closure(FLY_PATH)
    bad = {m: " -> ".join(c) for m, c in chains.items() if _within(m, FORBIDDEN_FROM_FLIGHT)}
    assert bad == {}
    stray = {m: " -> ".join(c) for m, c in chains.items() if m != "offboard" and not _within(m, FLIGHT_REACHABLE)}
    assert stray == {}
    assert set(FLY_PATH) <= set(chains)  # every listed module was found and read
    assert "offboard.report.report" in chains  # the report written after a flight is checked too


def test_fly_path_loads_the_reports_only_after_the_flight() -> None:
    """Static: importing the flight path's modules (imports outside functions) loads no report module: the reports
    (matplotlib, plotly) are imported inside the functions that write them, after the flight."""
    chains = _import_closure(FLY_PATH, top_level_only=True)
    early = {m: " -> ".join(c) for m, c in chains.items() if _within(m, AFTER_FLIGHT + FORBIDDEN_FROM_FLIGHT)}
    assert early == {}
    # the check can fail: the report folder's own modules load each other at import time
    assert "offboard.report.figures" in _import_closure(("offboard.report.report",), top_level_only=True)


def test_import_closure_sees_lazy_and_indirect_imports() -> None:
    """The checker above can fail: the simulation harness reaches the plant through a top-level import and the
    disturbances only through an import inside a function; ``offboard.harness.sim_cli`` reaches those through
    ``offboard.harness.sim``."""
    sim = _import_closure(("offboard.harness.sim",))
    assert {"sim_bridge.plant.dynamics", "sim_bridge.plant.sensors", "sim_bridge.plant.disturbances"} <= set(sim)
    assert sim["sim_bridge.plant.disturbances"] == ["offboard.harness.sim", "sim_bridge.plant.disturbances"]
    cli = _import_closure(("offboard.harness.sim_cli",))
    assert cli["sim_bridge.plant.disturbances"] == [
        "offboard.harness.sim_cli",
        "offboard.harness.sim",
        "sim_bridge.plant.disturbances",
    ]


def _sim_bridge_modules_after(code: str, timeout: float = 60.0) -> dict:
    """Run ``code`` in a fresh interpreter; it leaves a dict in ``out``. Returns it with ``sim_bridge``: the
    sim_bridge modules loaded by then."""
    tail = (
        "\nout['sim_bridge'] = sorted(m for m in sys.modules if m == 'sim_bridge' or m.startswith('sim_bridge.'))"
        "\nprint('RESULT ' + json.dumps(out))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", "import json, sys\nout = {}\n" + code + tail],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")][-1]
    return json.loads(line.removeprefix("RESULT "))


def test_fly_and_replay_load_no_simulator_module() -> None:
    """Dynamic, in a fresh interpreter: importing ``slung fly`` and ``slung replay`` and building the paper
    scenario's reference the way each of them does (plant-free ``offboard.control.scenarios``) loads no sim_bridge,
    harness or report module (the replay's report, imported next, still no sim_bridge one), while the simulation
    harness does (the check can fail)."""
    out = _sim_bridge_modules_after(
        "import argparse, offboard.flight.fly_cli, offboard.logs.replay_cli, offboard.logs.replay\n"
        "sc, dur = offboard.flight.fly_cli.make_reference(argparse.Namespace(scenario='paper', duration=None))\n"
        "ref = offboard.logs.replay.ReferenceSpec('paper').build()\n"
        "out['fly'] = [sc.name, dur, sc.disturbance_start, list(sc.reference.sample(12.5).fx[:3])]\n"
        "out['replay'] = list(ref.sample(12.5).fx[:3])\n"
        "out['early'] = sorted(m for m in sys.modules if m.startswith(('offboard.harness', 'offboard.report')))\n"
        "import offboard.report.replay_report\n"
    )
    assert out["sim_bridge"] == [] and out["early"] == []
    assert out["fly"][:3] == ["paper", 50.0, 25.0] and out["fly"][3] == out["replay"]
    assert abs(out["replay"][1]) > 0.0  # the figure-eight is moving at 12.5 s
    harness = _sim_bridge_modules_after("import offboard.harness.sim\n")
    assert "sim_bridge.plant.dynamics" in harness["sim_bridge"]


def test_flying_and_replaying_load_no_simulator_module(tmp_path: Path) -> None:
    """Dynamic, end to end: a fresh interpreter flies the paper scenario for 2 s with ``slung fly``'s own code
    (over real UDP on 127.0.0.1, against the bundled emulator running in THIS process), writes its report, replays
    its tlog with ``slung replay``'s code, and by then has loaded no sim_bridge module."""
    from offboard.harness.demo_cli import EmulatorThread, free_udp_port

    port = free_udp_port()
    emu = EmulatorThread("px4", port, lockstep=True, period=0.004).start()
    fly_argv = [
        "--connect",
        f"udpin:127.0.0.1:{port}",
        "--scenario",
        "paper",
        "--duration",
        "2",
        "--lockstep",
        "--no-figures",
        "--out",
        str(tmp_path / "fly"),
    ]
    replay_argv = [str(tmp_path / "fly" / "flight.tlog"), "--no-figures", "--out", str(tmp_path / "replay")]
    try:
        out = _sim_bridge_modules_after(
            "import argparse, contextlib, io\n"
            "from offboard.flight import fly_cli\n"
            "from offboard.logs import replay_cli\n"
            "def parse(mod, argv):\n"
            "    p = argparse.ArgumentParser()\n"
            "    mod.configure(p)\n"
            "    return p.parse_args(argv)\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            f"    out['fly'] = fly_cli.run(parse(fly_cli, {fly_argv!r}))\n"
            f"    out['replay'], m, _ = replay_cli.run_replay(parse(replay_cli, {replay_argv!r}))\n"
            "out['replayed'] = m['replayed']\n",
            timeout=120.0,
        )
    finally:
        emu.stop()
    assert out["fly"] == 0 and out["replay"] == 0 and out["replayed"] is True
    m = json.loads((tmp_path / "fly" / "metrics.json").read_text(encoding="utf-8"))
    assert m["scenario"] == "paper" and m["flight"]["ended_by"] == "completed"
    assert out["sim_bridge"] == []


def test_layering_estimators_import_neither_offboard_nor_sim_bridge() -> None:
    bad = [(f, m) for f, m in _imports("estimators") if m in ("offboard", "sim_bridge")]
    assert bad == []


def test_layering_emulator_never_imports_the_controller() -> None:
    bad = [(f, m) for f, m in _imports("sim_bridge") if m == "offboard"]
    assert bad == []


def test_no_module_over_500_lines_without_a_reason_at_its_top() -> None:
    """The project's rule: a module over 500 lines says at its top (its docstring) why it is one module."""
    long = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            text = path.read_text(encoding="utf-8")
            n = text.count("\n")
            doc = ast.get_docstring(ast.parse(text)) or ""
            if n > 500 and "500 lines" not in doc:
                long[str(path.relative_to(ROOT))] = n
    assert long == {}


def test_no_module_over_600_lines() -> None:
    """Issue 35's bound: no module of the product exceeds 600 lines, whatever its docstring says (a module that long
    does more than one job; split it by job)."""
    long = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            n = path.read_text(encoding="utf-8").count("\n")
            if n > 600:
                long[str(path.relative_to(ROOT))] = n
    assert long == {}


def test_filterpy_is_a_test_dependency_only() -> None:
    """No runtime module imports filterpy (it is the oracle of the filters' tests), so pyproject.toml lists it in the
    test extras, not among the runtime dependencies; the check can fail: the tests do import it."""
    runtime = [(f, m) for p in PACKAGES for f, m in _imports(p) if m == "filterpy"]
    assert runtime == []
    assert any(m == "filterpy" for _, m in _imports("tests"))
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert not any(d.startswith("filterpy") for d in project["dependencies"])
    assert any(d.startswith("filterpy") for d in project["optional-dependencies"]["test"])


def test_ruff_is_clean() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--output-format", "concise", str(ROOT)],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_ruff_format_is_clean() -> None:
    """The formatter (120 columns, pyproject.toml) leaves every file as it is; ruff is pinned so that CI agrees."""
    proc = subprocess.run(
        [sys.executable, "-m", "ruff", "format", "--check", str(ROOT)],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_ci_runs_the_readme_test_command() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    command = 'pip install -e ".[test]" && pytest'
    assert command in readme
    assert command.replace("pip install", "pip install --quiet") in ci


def test_bench_reports_figures() -> None:
    """`slung bench` measures (tiny repeat counts here: this checks it runs and reports, not the speed)."""
    from offboard.harness.bench_cli import measure

    r = measure(repeat=200, runs=1)
    for name in ("plant_rk4_step", "reference_sample", "controller_step", "baseline_solve_ivp_rk45_step"):
        assert 0.0 < r["micro"][name]["median_us"] <= r["micro"][name]["p99_us"]
    assert r["paper_run"]["realtime_factor"] > 0.5  # generous sanity bound, not a performance assertion


def test_vehicle_file_example_in_usage_docs_loads(tmp_path: Path) -> None:
    from estimators.model.vehicle import load_vehicle

    text = (ROOT / "docs" / "usage.md").read_text(encoding="utf-8")
    block = text.split("```toml\n", 1)[1].split("```", 1)[0]
    path = tmp_path / "v.toml"
    path.write_text(block, encoding="utf-8")
    v = load_vehicle(path)
    assert v.name == "my-quad" and v.mass_load == 0.2 and v.cable_length == 0.3
