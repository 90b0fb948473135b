"""The dependency rules of docs/design/architecture.md §1.2, enforced on every run."""

import ast
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
FORBIDDEN_IN_PURE = {"socket", "asyncio", "trio", "time", "random", "threading"}


def _imports(path: pathlib.Path) -> set[str]:
    tree = ast.parse(path.read_text())
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def test_pure_modules_do_no_io_and_read_no_clock():
    # The sans-I/O cores: the station's and the vehicle's link, and the modules they are cut into.
    pure = (
        list((ROOT / "planner").glob("*.py"))
        + list(ROOT.glob("*/link.py"))
        + list((ROOT / "gcs").glob("link_*.py"))
        + list((ROOT / "vehicle_emu").glob("core_*.py"))
    )
    assert pure, "no pure modules found"
    for path in pure:
        bad = _imports(path) & FORBIDDEN_IN_PURE
        assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


def test_import_contracts_hold():
    exe = pathlib.Path(sys.executable).with_name("lint-imports")
    result = subprocess.run([str(exe)], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "KEPT" in result.stdout
