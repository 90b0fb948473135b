"""Report: significance logic, paired vs unpaired, Δ against the paper, ablations, heatmaps, CLI."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from mission.experiments import paper
from mission.cli import main
from mission.experiments.report import Sample, best_of, build_report, p_greater, p_greater_paired
from mission.experiments.store import ResultStore, utc_now
from mission.experiments.sweep import (
    ConfigSpec,
    canonical_json,
    paper_ablations_grid,
    paper_table_grid,
)

N_SEEDS = 30


def _sample(method: str, tu1, tu2=None) -> Sample:
    s = Sample(ConfigSpec("S", 0.01, method))
    tu2 = tu1 if tu2 is None else tu2
    for seed, (a, b) in enumerate(zip(tu1, tu2)):
        s.by_seed["tu1"][seed] = float(a)
        s.by_seed["tu2"][seed] = float(b)
    return s


def _rows(
    spec: ConfigSpec, tu1_pct, tu2_pct, grid: str = "paper-table", errors: int = 0
) -> list[dict]:
    """Store rows for a spec as a sweep would write them (config key faked: one per spec)."""
    rows = []
    base = {
        "config_key": "cfg-" + spec.spec_key,
        "spec_key": spec.spec_key,
        "grid": grid,
        "label": spec.label,
        "size": spec.size,
        "attrition": spec.attrition,
        "reading": spec.reading,
        "method": spec.method,
        "spec_json": canonical_json(spec.spec_dict()),
        "config_json": "{}",
        "wall_s": 0.1,
        "final_alive": 5,
        "final_active": 4,
        "code_version": "phireman test src 0",
        "host": "h",
        "created_utc": utc_now(),
    }
    for seed, (a, b) in enumerate(zip(tu1_pct, tu2_pct)):
        rows.append(
            {
                **base,
                "run_key": f"{spec.spec_key}-{seed}",
                "seed": seed,
                "status": "ok",
                "error": None,
                "tu1": a / 100,
                "tu2": b / 100,
            }
        )
    for k in range(errors):
        rows.append(
            {
                **base,
                "run_key": f"{spec.spec_key}-e{k}",
                "seed": 1000 + k,
                "status": "error",
                "error": "ValueError: boom",
                "tu1": None,
                "tu2": None,
                "final_alive": None,
                "final_active": None,
            }
        )
    return rows


# ----------------------------------------------------------------------------------------------
# Statistics
# ----------------------------------------------------------------------------------------------


def test_bold_needs_the_best_to_beat_both_others(rng):
    a = _sample("phireman", 80 + rng.normal(0, 3, N_SEEDS))
    b = _sample("dccrs", 70 + rng.normal(0, 3, N_SEEDS))
    c = _sample("mccst", 60 + rng.normal(0, 3, N_SEEDS))
    v = best_of({"phireman": a, "dccrs": b, "mccst": c}, "tu1")
    assert v.best == "phireman" and v.significant and v.p < 1e-6

    close = _sample("dccrs", 79.8 + rng.normal(0, 3, N_SEEDS))  # beats MCCST, not ΦIREMAN
    v = best_of({"phireman": a, "dccrs": close, "mccst": c}, "tu1")
    assert v.best in ("phireman", "dccrs") and not v.significant

    # one method only: nothing to compare, never bold
    assert best_of({"phireman": a, "dccrs": None, "mccst": None}, "tu1").best is None


def test_paired_test_sees_what_the_unpaired_test_cannot(rng):
    # Large scenario-to-scenario variance shared by both methods (common random numbers), and a
    # small consistent gain: the paired test detects it, the paper's unpaired test does not.
    scenario = 60 + rng.normal(0, 15, N_SEEDS)
    a = _sample("phireman", scenario + 1.0 + rng.normal(0, 0.3, N_SEEDS))
    b = _sample("dccrs", scenario + rng.normal(0, 0.3, N_SEEDS))
    assert p_greater(a, b, "tu1") > 0.05
    assert p_greater_paired(a, b, "tu1") < 1e-6
    # one-tailed: the other direction is not significant
    assert p_greater_paired(b, a, "tu1") > 0.5
    # identical samples: no evidence, no crash
    assert p_greater(a, a, "tu1") > 0.4 and p_greater_paired(a, a, "tu1") == 1.0


def test_paper_data_matches_the_papers_caption():
    assert len(paper.TABLE_II) == 25
    bold = paper.TABLE_II_BOLD
    assert sum(1 for b in bold if b[2] == "tu1" and b[3] == "phireman") == 13
    assert sum(1 for b in bold if b[2] == "tu2" and b[3] == "phireman") == 10
    assert {b for b in bold if b[3] != "phireman"} == {("M", 0.05, "tu2", "mccst")}
    assert paper.paper_value("S", 0.01, "phireman", "tu1") == (80.83, 1.63)
    assert paper.paper_value("XL", 0.05, "mccst", "tu2") == (42.96, 0.57)
    assert (
        paper.paper_bold("M", 0.05, "tu2") == "mccst" and paper.paper_bold("S", 0.0, "tu1") is None
    )
    assert [r.label for r in paper.ABLATIONS] == [
        v.label for v in paper_ablations_grid(seeds=[]).configs
    ]


# ----------------------------------------------------------------------------------------------
# The rendered report on a synthetic store
# ----------------------------------------------------------------------------------------------


@pytest.fixture
def synthetic_store(tmp_path, rng):
    """S / 1 %, S / 0.5 %, XS / 0 % for the three methods, and the ablations, with known answers."""
    path = tmp_path / "synthetic.sqlite"
    table = {(c.size, c.attrition, c.method): c for c in paper_table_grid(seeds=[]).configs}
    rows = []
    # S / 1 %: ΦIREMAN exactly the paper + 1.00 (✓), DCCRS paper − 6 (✗), MCCST far below; ΦIREMAN
    # clearly best -> bold (the paper bolds it too).
    for method, shift in (("phireman", 1.0), ("dccrs", -6.0), ("mccst", 0.0)):
        (t1, _), (t2, _) = (paper.paper_value("S", 0.01, method, m) for m in paper.METRICS)
        noise = rng.normal(0, 2, N_SEEDS)
        noise -= noise.mean()
        rows += _rows(table[("S", 0.01, method)], t1 + shift + noise, t2 + shift + noise)
    # S / 0.5 %: a small consistent gain hidden in shared variance: paired-only significance.
    scenario = 93 + rng.normal(0, 4, N_SEEDS)
    rows += _rows(table[("S", 0.005, "phireman")], scenario + 0.8, scenario + 0.8)
    rows += _rows(
        table[("S", 0.005, "dccrs")],
        scenario + rng.normal(0, 0.2, N_SEEDS),
        scenario + rng.normal(0, 0.2, N_SEEDS),
    )
    rows += _rows(table[("S", 0.005, "mccst")], scenario - 15, scenario - 10)
    # XS / 0 %: ΦIREMAN 10 pp below the paper (a miss), baselines on the paper; two failed runs.
    for method, shift in (("phireman", -10.0), ("dccrs", 0.0), ("mccst", 0.0)):
        (t1, _), (t2, _) = (paper.paper_value("XS", 0.0, method, m) for m in paper.METRICS)
        rows += _rows(
            table[("XS", 0.0, method)],
            t1 + shift + rng.normal(0, 1, N_SEEDS),
            t2 + shift + rng.normal(0, 0.5, N_SEEDS),
            errors=2 if method == "mccst" else 0,
        )
    # Ablations: Þ = 0 clearly below the default, v = 0.2 the same as the default.
    abl = {c.label: c for c in paper_ablations_grid(seeds=[]).configs}
    default = [r for r in rows if r["spec_key"] == abl["default"].spec_key]
    assert len(default) == N_SEEDS  # the table's ΦIREMAN S / 1 % is the ablations' default
    d1 = np.array([r["tu1"] * 100 for r in default])
    d2 = np.array([r["tu2"] * 100 for r in default])
    rows += _rows(abl["Þ = 0"], d1 - 6, d2 - 6, grid="paper-ablations")
    rows += _rows(
        abl["v = 0.2"],
        d1 + rng.normal(0, 0.1, N_SEEDS),
        d2 + rng.normal(0, 0.1, N_SEEDS),
        grid="paper-ablations",
    )
    # Something from a tuning run.
    tuned = ConfigSpec("S", 0.01, "phireman", params={"step_size": 0.3}, label="step_size=0.3")
    rows += _rows(tuned, 70 + rng.normal(0, 1, 5), 75 + rng.normal(0, 1, 5), grid="tune")
    with ResultStore(path) as store:
        assert store.insert_runs(rows) == len(rows)
    return path


def test_report_on_a_synthetic_store(synthetic_store, tmp_path):
    out = tmp_path / "report"
    result = build_report(synthetic_store, out)
    md = result.markdown.read_text()

    # Table II: ΦIREMAN bold at S / 1 % on both metrics, the others not.
    s1 = next(line for line in md.splitlines() if line.startswith("| S | 1 |"))
    cells = [c.strip() for c in s1.strip("|").split("|")]
    assert cells[2].startswith("**81.83 ±") and cells[3].startswith("**86.34 ±")
    assert not cells[4].startswith("**") and not cells[6].startswith("**")
    assert cells[8].startswith("**ΦIREMAN** p=")
    # S / 0.5 %: not bold by the paper's unpaired test, significant by the paired one.
    s05 = next(line for line in md.splitlines() if line.startswith("| S | 0.5 |"))
    cells = [c.strip() for c in s05.strip("|").split("|")]
    assert not any(c.startswith("**") for c in cells[2:8])
    assert cells[8].startswith("**ΦIREMAN**")

    # Δ against the paper, with the tolerance marks.
    assert "81.83 vs 80.83 (+1.00 ✓)" in md
    assert "72.21 vs 78.21 (-6.00 ✗)" in md
    # Summary and misses: XS / 0 % misses for ΦIREMAN and is listed with a diagnosis.
    # only the 3 paper configurations with data are counted (and listed): not "1 of 20"
    assert "within 3 pp of the paper at 0–2 % attrition: **1 of 3** configurations with data" in md
    assert "| M | 1 |" not in md
    misses = md.split("## Configurations that miss")[1].split("## The 5 % column")[0]
    xs = next(line for line in misses.splitlines() if line.startswith("- XS / 0 %: TU1 Δ -"))
    assert "exceeds the combined 95 % CIs" in xs and "specific to this planner" in xs
    assert "- S / 1 %" in misses.split("**DCCRS**")[1]  # DCCRS −6 misses its 5 pp
    # No 5 % data in this store: no 5 % section of empty cells.
    assert "## The 5 % column" not in md
    # Bold agreement: the paper bolds ΦIREMAN at S / 0.5 %, our unpaired test does not.
    agreement = md.split("## Significance against the paper's bolding")[1]
    assert "LaTeX" in agreement
    assert "S / 0.5 % TU1: paper bolds ΦIREMAN, we bold none" in agreement
    # Ablations: Þ = 0 below on both (the paper agrees), v = 0.2 not below (agrees).
    abl = md.split("## Ablations")[1]
    thorn = next(line for line in abl.splitlines() if line.startswith("| Þ = 0 |"))
    assert thorn.count("**below**") == 2 and thorn.rstrip(" |").endswith("✓ ✓")
    v02 = next(line for line in abl.splitlines() if line.startswith("| v = 0.2 |"))
    assert "n.s." in v02 and v02.rstrip(" |").endswith("✓ ✓")
    assert "| σ = 0 | – |" in abl  # no data
    # Header: reading and code version; other configurations and failures are listed.
    assert "reading: **scaled**" in md and "`phireman test src 0`" in md
    assert "step_size=0.3" in md.split("## Other configurations in the store")[1]
    assert "ValueError: boom" in md.split("## Failed runs")[1]

    # Heatmaps exist and are PNGs; the CSV holds every configuration.
    assert {p.name for p in result.figures} == {
        "fig3_phireman_minus_dccrs.png",
        "fig3_phireman_minus_mccst.png",
        "fig3_phireman_minus_best_baseline.png",
        "delta_vs_paper.png",
    }
    for p in result.figures:
        data = p.read_bytes()
        assert len(data) > 10_000 and data[:8] == b"\x89PNG\r\n\x1a\n"
    with open(result.csv) as fh:
        rows = list(csv.DictReader(fh))
    s1_phi = next(
        r
        for r in rows
        if (r["size"], r["attrition"], r["method"], r["label"]) == ("S", "0.01", "phireman", "")
    )
    assert (
        float(s1_phi["delta_tu1_pp"]) == pytest.approx(1.0, abs=1e-6)
        and s1_phi["within_tolerance"] == "True"
    )
    xs_m = next(
        r for r in rows if (r["size"], r["attrition"], r["method"]) == ("XS", "0.0", "mccst")
    )
    assert xs_m["n_ok"] == str(N_SEEDS) and xs_m["n_error"] == "2"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["agreement"]["phireman"]["within_both"] == 1


def test_report_command(synthetic_store, tmp_path, capsys):
    out = tmp_path / "cli"
    notes = tmp_path / "notes.md"
    notes.write_text("XS / 0 % misses because of a synthetic shift.")
    assert (
        main(
            [
                "report",
                str(synthetic_store),
                "--out",
                str(out),
                "--notes",
                str(notes),
                "--no-figures",
            ]
        )
        == 0
    )
    assert (
        "within 3 pp of the paper at 0-2 %: 1 of 3 paper configurations with data"
        in capsys.readouterr().out
    )
    md = (out / "report.md").read_text()
    assert md.rstrip().endswith("XS / 0 % misses because of a synthetic shift.")
    assert not list(out.glob("*.png"))
    assert main(["report", str(tmp_path / "missing.sqlite"), "--out", str(out)]) == 2


def test_central_information_section(tmp_path, rng):
    """With phireman-central runs on a paper-table configuration, the report compares both
    information models with the paper; without them the section is absent."""
    path = tmp_path / "central.sqlite"
    table = {(c.size, c.attrition, c.method): c for c in paper_table_grid(seeds=[]).configs}
    central = {
        (c.size, c.attrition): c
        for c in paper_table_grid(seeds=[], methods=("phireman-central",)).configs
    }
    (t1, _), (t2, _) = (paper.paper_value("M", 0.02, "phireman", m) for m in paper.METRICS)
    noise = rng.normal(0, 1, N_SEEDS)
    noise -= noise.mean()
    rows = _rows(table[("M", 0.02, "phireman")], t1 - 4.0 + noise, t2 - 4.0 + noise)  # a miss
    with ResultStore(path) as store:
        store.insert_runs(rows)
    md = build_report(path, tmp_path / "a", figures=False).markdown.read_text()
    assert "asynchronous and central" not in md
    rows = _rows(central[("M", 0.02)], t1 - 0.5 + noise, t2 + 0.5 + noise)  # within 3
    with ResultStore(path) as store:
        store.insert_runs(rows)
    result = build_report(path, tmp_path / "b", figures=False)
    md = result.markdown.read_text()
    section = md.split("asynchronous and central information against the paper")[1]
    line = next(ln for ln in section.splitlines() if ln.startswith("| M | 2 |"))
    assert "(-4.00)" in line and "(-0.50 ✓)" in line and "(+0.50 ✓)" in line
    assert result.summary["central_vs_async"] == {"async": 0, "central": 1, "configs": 1}


def test_per_baseline_split_of_the_paper_bolds(rng):
    """Where the paper bolds ΦIREMAN, the split counts the cells ours is significantly above each
    baseline separately: a DCCRS that ties ΦIREMAN must show up as 0 above DCCRS and all above
    MCCST, and no bold."""
    from mission.experiments.report import Cell, _phireman_vs_each

    bolded = [
        (size, att)
        for (size, att) in paper.TABLE_II
        if paper.paper_bold(size, att, "tu1") == "phireman"
        and paper.paper_bold(size, att, "tu2") == "phireman"
    ][:3]
    assert bolded, "the paper bolds ΦIREMAN on both metrics somewhere"
    cells = []
    for size, att in bolded:
        noise = rng.normal(0, 3, N_SEEDS)
        cells.append(
            Cell(
                size,
                att,
                {
                    "phireman": _sample("phireman", 80 + noise),
                    "dccrs": _sample("dccrs", 80 + noise[::-1]),
                    "mccst": _sample("mccst", 60 + rng.normal(0, 3, N_SEEDS)),
                },
            )
        )
    text, stats = _phireman_vs_each(cells)
    assert stats["paper_bolds_phireman"] == 2 * len(bolded)
    assert stats["above_mccst"] == stats["above_mccst_paired"] == 2 * len(bolded)
    assert stats["above_dccrs"] == 0 and stats["bold_both"] == 0
    assert f"above MCCST in **{2 * len(bolded)}**" in text and "above DCCRS in **0**" in text


def test_extra_method_is_paired_against_phireman(synthetic_store, tmp_path):
    """--method mine: a planner run on the paper's configurations gets a column in Table II and a
    paired comparison with ΦIREMAN (two-sided ttest_rel on the shared seeds)."""
    table = {(c.size, c.attrition, c.method): c for c in paper_table_grid(seeds=[]).configs}
    with ResultStore(synthetic_store, readonly=True) as store:
        base = {
            (r["size"], r["attrition"], r["seed"]): (r["tu1"] * 100, r["tu2"] * 100)
            for r in store.runs()
            if r["method"] == "phireman" and r["grid"] == "paper-table"
        }
    rows = []
    for size, att, shift in (("S", 0.01, 0.5), ("S", 0.005, 0.0)):
        spec = table[(size, att, "phireman")]
        mine = ConfigSpec(spec.size, spec.attrition, "mine")
        t1 = np.array([base[(size, att, s)][0] for s in range(N_SEEDS)])
        t2 = np.array([base[(size, att, s)][1] for s in range(N_SEEDS)])
        gain = shift * (1 + 0.1 * np.cos(np.arange(N_SEEDS)))  # S / 1 %: about +0.5; S / 0.5 %: 0
        rows += _rows(mine, t1 + gain, t2 + gain)
    with ResultStore(synthetic_store) as store:
        store.insert_runs(rows)
    md = build_report(synthetic_store, tmp_path / "r", extra_methods=("mine",), figures=False)
    text = md.markdown.read_text()
    part = text.split("## `mine` against ΦIREMAN, paired by seed")[1].split("\n## ")[0]
    s1 = next(line for line in part.splitlines() if line.startswith("| S | 1 ‡ |"))
    assert "+0.50 (" in s1 and s1.rstrip(" |").endswith(f"better (both) | {N_SEEDS}")
    s05 = next(line for line in part.splitlines() if line.startswith("| S | 0.5 ‡ |"))
    assert "+0.00 (1.000)" in s05 and "n.s." in s05
    assert "better on both TU1 and TU2 in **1 of 2**" in part


# ----------------------------------------------------------------------------------------------
# Too few seeds to grade (issue 28 point 10)
# ----------------------------------------------------------------------------------------------


def test_report_command_says_when_there_are_too_few_seeds(tmp_path, rng, monkeypatch):
    """A 5-seed store: where our 95 % CI is wider than the tolerance the grade is 'too few
    seeds', not ✓ / ✗, the top of report.md says so, and a noisy cell does not set the heatmaps'
    colour scale; where the CI is narrow the grade stands."""
    import subprocess
    import sys

    from mission.experiments.report import figures

    n = 5
    table = {(c.size, c.attrition, c.method): c for c in paper_table_grid(seeds=[]).configs}
    rows = []

    def add(size, att, method, shift, sd):
        (t1, _), (t2, _) = (paper.paper_value(size, att, method, m) for m in paper.METRICS)
        noise = rng.normal(0, sd, n)
        noise = noise - noise.mean()  # exact means: the grades below are known
        rows.extend(_rows(table[(size, att, method)], t1 + shift + noise, t2 + shift + noise))

    # S / 1 %: wide intervals (sd 8 over 5 seeds: CI ± ~10 pp); MCCST +20 pp but noise (sd 15).
    add("S", 0.01, "phireman", 1.0, 8.0)
    add("S", 0.01, "dccrs", 0.0, 8.0)
    add("S", 0.01, "mccst", 20.0, 15.0)
    # M / 0 %: narrow intervals: ΦIREMAN +1 (✓), DCCRS −6 (✗, beyond its 5 pp), MCCST on it.
    add("M", 0.0, "phireman", 1.0, 0.1)
    add("M", 0.0, "dccrs", -6.0, 0.1)
    add("M", 0.0, "mccst", 0.0, 0.1)
    store = tmp_path / "five.sqlite"
    with ResultStore(store) as s:
        s.insert_runs(rows)

    out = tmp_path / "r"
    res = subprocess.run(
        [sys.executable, "-m", "mission.cli", "report", str(store), "--out", str(out)]
        + ["--no-figures", "--no-progress"],
        capture_output=True,
        text=True,
    )
    assert res.returncode == 0, res.stderr
    assert "too few seeds to grade 6 of 12 comparisons" in res.stdout
    md = (out / "report.md").read_text()
    top = md.split("## Summary")[0]
    assert "**Too few seeds to grade against the paper: 6 of 12**" in top
    assert "This store has 5 seeds per configuration" in top
    vs = md.split("## Ours against the paper")[1].split("\n## ")[0]
    s1 = next(line for line in vs.splitlines() if line.startswith("| S | 1 |"))
    assert s1.count("too few seeds") == 6 and "✓" not in s1 and "✗" not in s1
    m0 = next(line for line in vs.splitlines() if line.startswith("| M | 0 |"))
    assert "(+1.00 ✓)" in m0 and "(-6.00 ✗)" in m0 and "too few seeds" not in m0
    summary_line = next(line for line in md.splitlines() if line.startswith("- **ΦIREMAN** within"))
    assert "**1 of 2**" in summary_line and "**1 with too few seeds to tell**" in summary_line
    misses = md.split("## Configurations that miss")[1].split("\n## ")[0]
    assert "- too few seeds to tell: S / 1 %" in misses
    assert "- M / 0 %: TU1 Δ -6.00" in misses.split("**DCCRS**")[1]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["too_few_seeds"]["too_few_seeds"] == 6
    assert summary["too_few_seeds"]["seeds_needed_max"] > 5
    assert summary["agreement"]["phireman"]["too_few_seeds"] == 1

    # Heatmaps: the noisy +20 pp (within the combined CIs) is drawn white and does not set the
    # scale of ours − paper; DCCRS's −6 pp at M / 0 % (significant) does.
    calls = []
    real = figures._heatmap

    def spy(ax, z, marks, sizes, levels, title, vmax=None, significant=None):
        calls.append((title, vmax, z, significant))
        return real(ax, z, marks, sizes, levels, title, vmax, significant)

    monkeypatch.setattr(figures, "_heatmap", spy)
    build_report(store, tmp_path / "figs", progress=None)
    delta = [(v, z, sig) for t, v, z, sig in calls if "ours − paper" in t]
    assert len(delta) == 6
    assert all(v == pytest.approx(6.0, abs=1e-6) for v, _, _ in delta)
    mccst_tu1 = next(z for t, v, z, sig in calls if t.startswith("MCCST TU1: ours − paper"))
    sig = next(sig for t, v, z, sig in calls if t.startswith("MCCST TU1: ours − paper"))
    assert np.nanmax(mccst_tu1) == pytest.approx(20.0, abs=1e-6) and not sig.any()
