"""Project rules that a reviewer would otherwise check by hand: lint, package layering, README vs CI."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


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


def test_layering_estimators_import_neither_offboard_nor_sim_bridge() -> None:
    bad = [(f, m) for f, m in _imports("estimators") if m in ("offboard", "sim_bridge")]
    assert bad == []


def test_layering_emulator_never_imports_the_controller() -> None:
    bad = [(f, m) for f, m in _imports("sim_bridge") if m == "offboard"]
    assert bad == []


def test_ruff_is_clean() -> None:
    proc = subprocess.run([sys.executable, "-m", "ruff", "check", "--output-format", "concise", str(ROOT)],
                          capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_ci_runs_the_readme_test_command() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    command = 'pip install -e ".[test]" && pytest'
    assert command in readme
    assert command.replace("pip install", "pip install --quiet") in ci


def test_bench_reports_figures() -> None:
    """`slung bench` measures (tiny repeat counts here: this checks it runs and reports, not the speed)."""
    from offboard.bench_cli import measure

    r = measure(repeat=200, runs=1)
    for name in ("plant_rk4_step", "reference_sample", "controller_step", "baseline_solve_ivp_rk45_step"):
        assert 0.0 < r["micro"][name]["median_us"] <= r["micro"][name]["p99_us"]
    assert r["paper_run"]["realtime_factor"] > 0.5  # generous sanity bound, not a performance assertion


def test_vehicle_file_example_in_usage_docs_loads(tmp_path: Path) -> None:
    from estimators.vehicle import load_vehicle

    text = (ROOT / "docs" / "usage.md").read_text(encoding="utf-8")
    block = text.split("```toml\n", 1)[1].split("```", 1)[0]
    path = tmp_path / "v.toml"
    path.write_text(block, encoding="utf-8")
    v = load_vehicle(path)
    assert v.name == "my-quad" and v.mass_load == 0.2 and v.cable_length == 0.3
