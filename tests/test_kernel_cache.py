"""The compile-once cache of the kernel packages (``estimators.kernels.drop_stale_cache``): a package's compiled
files are kept while none of its sources changed, and thrown away when any did, whether the package's own file or
another one whose code it compiles in (numba keys a cached kernel by its own file only)."""

from __future__ import annotations

from pathlib import Path

from estimators.kernels import drop_stale_cache


def _package(tmp: Path) -> tuple[Path, list[Path]]:
    """A kernel package with one module and one shared source outside it."""
    pkg = tmp / "pkg"
    pkg.mkdir()
    own = pkg / "kernels.py"
    own.write_text("x = 1\n")
    shared = tmp / "scalar.py"
    shared.write_text("def f(a):\n    return a\n")
    return pkg, [own, shared]


def _compiled(pkg: Path) -> list[Path]:
    """Stand-ins for numba's cache files, written as numba would after a compile."""
    files = [pkg / "__pycache__" / "kernels.f-1.py311.nbi", pkg / "__pycache__" / "kernels.f-1.py311.1.nbc"]
    for f in files:
        f.write_bytes(b"compiled")
    return files


def test_the_cache_stays_while_its_sources_do_and_goes_when_any_changes(tmp_path: Path) -> None:
    pkg, sources = _package(tmp_path)
    assert drop_stale_cache(pkg, sources)  # first time: no stamp, so stale
    files = _compiled(pkg)
    assert not drop_stale_cache(pkg, sources)
    assert all(f.exists() for f in files)
    for changed in sources:  # the package's own module, then the shared source it compiles in
        changed.write_text(changed.read_text() + "# edited\n")
        assert drop_stale_cache(pkg, sources)
        assert not any(f.exists() for f in files)
        files = _compiled(pkg)
        assert not drop_stale_cache(pkg, sources)


def test_a_read_only_cache_folder_is_no_error(tmp_path: Path) -> None:
    """Where the package's folder cannot be written (an installed copy), the judge says stale and raises nothing."""
    pkg, sources = _package(tmp_path)
    pkg.chmod(0o555)
    try:
        assert drop_stale_cache(pkg, sources)
    finally:
        pkg.chmod(0o755)
