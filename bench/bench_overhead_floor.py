"""Issue 16: how much of a small run is per-tick Python overhead, and so how much batching seeds in
one process could save at most.

Batching B seeds of a small problem in one process (one set of NumPy / Numba calls per tick for
all B worlds, stacked) removes per-call overhead; it cannot remove the arithmetic. This bench
splits one run's profiled time into

* ``python``: time inside Python functions (ours, and NumPy / SciPy's Python wrappers) - what
  batching B worlds would pay once instead of B times;
* ``compiled``: time inside Numba kernels and C functions (ufuncs, sorts, the QP solver) - the
  arithmetic, which grows with B;

and reports, per size and method, the CPU seconds per run (least of ``--seeds`` runs, one BLAS
thread), Python function calls per tick, the two shares, and the upper bound on what batching
saves of the paper's Table II: the size's share of the table's time (``mission.experiments.sweep``'s
measured run times) times its Python share, i.e. as if batching removed every Python call.
cProfile adds its own cost to every call, so its Python share is an upper bound (used for the
bound); ``python (est.)`` also subtracts the profiler's whole cost (the profiled run's CPU minus
the same seed's unprofiled CPU) from the Python time, a lower estimate.

    .venv/bin/python bench/bench_overhead_floor.py
    .venv/bin/python bench/bench_overhead_floor.py --sizes XS S --methods phireman --seeds 3
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from mission.experiments.sim import run_episode  # noqa: E402
from mission.experiments.sweep import METHOD_COST_FACTOR, MEASURED_RUN_S  # noqa: E402
from planner.problem import problem_preset  # noqa: E402

SIZES = ("XS", "S", "M", "L", "XL")
LEVELS = (0.0, 0.005, 0.01, 0.02, 0.05)
METHODS = ("phireman", "dccrs", "mccst")


def _jitted_code() -> set[tuple[str, int]]:
    """(file, first line) of every Numba-compiled function of ours: cProfile shows a call of one
    as a frame of its Python source, though no Python body runs."""
    import importlib
    import pkgutil

    import planner

    out: set[tuple[str, int]] = set()
    for info in pkgutil.iter_modules(planner.__path__):
        if "kernels" not in info.name:
            continue
        mod = importlib.import_module(f"planner.{info.name}")
        for obj in vars(mod).values():
            py_func = getattr(obj, "py_func", None)  # a Numba dispatcher
            code = getattr(py_func, "__code__", None)
            if code is not None:
                out.add((code.co_filename, code.co_firstlineno))
    return out


def _compiled(filename: str, line: int, name: str, jitted: set[tuple[str, int]]) -> bool:
    """A profile entry whose own time is compiled code: C builtins and extension methods
    (cProfile names them ``~`` / ``{...}``) and our Numba kernels."""
    return filename == "~" or name.startswith(("<built-in", "{")) or (filename, line) in jitted


def split(problem, method: str, seed: int) -> tuple[float, float, int, float]:
    """(python s, compiled s, calls, CPU s) of one profiled run."""
    prof = cProfile.Profile()
    c0 = time.process_time()
    prof.enable()
    run_episode(problem, method, {}, seed)
    prof.disable()
    cpu_s = time.process_time() - c0
    st = pstats.Stats(prof)
    jitted = _jitted_code()
    py = comp = 0.0
    calls = 0
    for (filename, line, name), (_cc, nc, tt, _ct, _callers) in st.stats.items():  # type: ignore[attr-defined]
        calls += nc
        if _compiled(filename, line, name, jitted):
            comp += tt
        else:
            py += tt
    return py, comp, calls, cpu_s


def table_share() -> dict[str, float]:
    """Each size's share of the whole table's run time (3 methods x 5 levels), from the
    measured per-run times the sweep's --dry-run uses."""
    cost = {
        size: sum(MEASURED_RUN_S[(size, lv)] for lv in LEVELS)
        * sum(METHOD_COST_FACTOR[m] for m in METHODS)
        for size in SIZES
    }
    total = sum(cost.values())
    return {size: c / total for size, c in cost.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--sizes", nargs="+", default=list(SIZES), choices=SIZES)
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--attrition", type=float, default=0.01)
    ap.add_argument("--seeds", type=int, default=3, help="timed runs per cell (least CPU kept)")
    args = ap.parse_args(argv)

    for method in args.methods:  # warm-up: imports, Numba's cache
        run_episode(problem_preset("XS", 0.01), method, {}, 10_000)
    share = table_share()
    print(
        f"{'size':4} {'method':9} {'CPU s/run':>9} {'ms/tick':>8} {'calls/tick':>10} "
        f"{'python':>7} {'(est.)':>7}"
    )
    bound_s = {}
    for size in args.sizes:
        problem = problem_preset(size, args.attrition)
        fracs = []
        for method in args.methods:
            cpu = []
            for seed in range(args.seeds):
                c0 = time.process_time()
                run_episode(problem, method, {}, seed)
                cpu.append(time.process_time() - c0)
            py, comp, calls, cpu_prof_s = split(problem, method, 0)
            frac = py / (py + comp)
            est = max(0.0, py - (cpu_prof_s - cpu[0])) / cpu[0]
            fracs.append(frac)
            print(
                f"{size:4} {method:9} {min(cpu):9.3f} {1e3 * min(cpu) / problem.n_steps:8.2f} "
                f"{calls / problem.n_steps:10.0f} {frac:7.0%} {est:7.0%}"
            )
        bound_s[size] = share[size] * sum(fracs) / len(fracs)
    print()
    print("Upper bound on what batching seeds could save of Table II's time (size's share x its")
    print("Python share; as if every Python call were gone):")
    for size, b in bound_s.items():
        print(f"  {size:3}: table share {share[size]:5.1%}  -> at most {b:5.1%} of the table")
    print(f"  sum over the sizes measured: at most {sum(bound_s.values()):.1%}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
