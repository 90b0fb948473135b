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


# ----------------------------------------------------------------------------------------------
# No circle of imports (issue 24)
# ----------------------------------------------------------------------------------------------

PACKAGES = ("planner", "mavedge", "vehicle_emu", "gcs", "mission")


def import_cycles(edges: dict[str, set[str]]) -> list[tuple[list[str], list[str]]]:
    """The circles of an import graph: each strongly connected component of two or more modules
    (or a module importing itself), as (its modules sorted, one closed path through some of them)."""
    import networkx as nx

    graph = nx.DiGraph()
    graph.add_nodes_from(edges)
    graph.add_edges_from((a, b) for a, targets in edges.items() for b in targets)
    found = []
    for component in nx.strongly_connected_components(graph):
        first = min(component)
        if len(component) == 1 and not graph.has_edge(first, first):
            continue
        path = [a for a, _ in nx.find_cycle(graph.subgraph(component), source=first)]
        found.append((sorted(component), path + [path[0]]))
    return sorted(found)


def our_import_graph() -> dict[str, set[str]]:
    """Module -> the modules of ours it imports, by any ``import`` statement in it: at module level,
    inside a function, or under ``if TYPE_CHECKING`` (grimp, the library import-linter runs on).

    What counts: an explicit import of one of our modules by another. A function-level import
    runs later than a module-level one, but it still means each module needs the other, and a
    ``TYPE_CHECKING`` import makes no runtime circle but the same circle for a reader and for mypy;
    both are counted. An import by name counts too: ``mission.cli`` loads each subcommand's module
    with ``importlib`` (grimp cannot see it, so the edges are added here from ``COMMANDS``). Not
    counted: the implicit import of a package's ``__init__`` that any import of its submodules
    triggers (a package re-exporting its children would otherwise always be a circle)."""
    import grimp

    from mission.cli import COMMANDS

    graph = grimp.build_graph(*PACKAGES, cache_dir=None)
    edges = {m: set(graph.find_modules_directly_imported_by(m)) for m in graph.modules}
    edges["mission.cli"] |= {f"mission.commands.{m}" for m in COMMANDS.values()}
    return edges


def test_cycle_finder_finds_circles():
    edges = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": {"e"}, "f": set()}
    assert import_cycles(edges) == [
        (["a", "b", "c"], ["a", "b", "c", "a"]),
        (["e"], ["e", "e"]),
    ]
    assert import_cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycles():
    """No module of ours imports, directly or through others, a module that imports it back
    (docs/design/architecture.md §1.3): shared definitions move down into a module both import."""
    graph = our_import_graph()
    assert len(graph) > 100 and "gcs.link" in graph  # the graph was built
    cycles = import_cycles(graph)
    assert not cycles, "import cycles:\n" + "\n".join(
        f"{len(members)} modules ({', '.join(members)}), e.g. {' -> '.join(path)}"
        for members, path in cycles
    )
