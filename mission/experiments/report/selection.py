"""Selecting a configuration's rows from the results store (:class:`Selector`)."""

from __future__ import annotations

import json
from collections import Counter

from mission.experiments.report.stats import Sample
from mission.experiments.sweep import ConfigSpec, resolve


class Selector:
    """Finds the rows of a configuration in a store: by spec key, or by resolved configuration key.

    When a configuration's rows come from several resolved configurations (the defaults changed
    between sweeps), the most recent one is used and the others are noted.
    """

    def __init__(self, rows: list[dict]) -> None:
        self.rows = rows
        self.by_spec: dict[str, list[dict]] = {}
        self.by_config: dict[str, list[dict]] = {}
        for r in rows:
            self.by_spec.setdefault(r["spec_key"], []).append(r)
            self.by_config.setdefault(r["config_key"], []).append(r)
        self.used: set[str] = set()

    def sample(self, spec: ConfigSpec) -> Sample | None:
        found = {r["run_key"]: r for r in self.by_spec.get(spec.spec_key, [])}
        try:
            ck = resolve(spec).config_key
            found.update({r["run_key"]: r for r in self.by_config.get(ck, [])})
        except Exception:  # an invalid spec has only its spec-key rows
            pass
        if not found:
            return None
        rows = sorted(found.values(), key=lambda r: r["id"])
        configs = Counter(r["config_key"] for r in rows)
        sample = Sample(spec)
        if len(configs) > 1:
            latest = rows[-1]["config_key"]
            dropped = sum(n for k, n in configs.items() if k != latest)
            sample.notes.append(
                f"{dropped} older rows with a different resolved configuration ignored"
            )
            rows = [r for r in rows if r["config_key"] == latest]
        for r in rows:
            self.used.add(r["run_key"])
            sample.code_versions[r["code_version"]] += 1
            if r["status"] != "ok":
                sample.n_error += 1
                sample.errors[r["error"] or "?"] += 1
                continue
            sample.by_seed["tu1"][r["seed"]] = 100.0 * r["tu1"]
            sample.by_seed["tu2"][r["seed"]] = 100.0 * r["tu2"]
        return sample


def _spec_from_row(r: dict) -> ConfigSpec:
    d = json.loads(r["spec_json"])
    return ConfigSpec(
        d["size"],
        d["attrition"],
        d["method"],
        d["reading"],
        d.get("params", {}),
        d.get("problem_overrides", {}),
        r.get("label") or "",
    )
