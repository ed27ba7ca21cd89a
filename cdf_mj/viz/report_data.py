"""Reading an experiment directory for the report: its settings and completed records
(:func:`load_experiment`), and the scenario and planners they describe, rebuilt for a
re-run. :class:`ReportError` is every report's one-line refusal. ::

    from cdf_mj.viz.report_data import load_experiment
    exp = load_experiment("results/experiment")
    exp.planners, exp.by_planner("cdf")
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cdf_mj.config import ScenarioConfig, SceneNames
from cdf_mj.planners.registry import PLANNERS, PlannerSpec, bind_planner, stored_planner_arguments
from cdf_mj.records import FAILED, RECORDS_FILE, read_records, read_settings

__all__ = ["Experiment", "ReportError", "load_experiment"]


class ReportError(ValueError):
    """An experiment directory that cannot be reported on, or missing packages (one line)."""


@dataclass
class Experiment:
    """The completed records of an experiment directory and its settings."""

    path: Path
    settings: dict[str, Any]
    records: list[dict[str, Any]]  # completed episodes only
    failed: int = 0  # records with "status": "failed", skipped
    unreadable: int = 0  # 1 if the file ends in a half-written line (a run killed or still writing), skipped
    planners: list[str] = field(default_factory=list)  # those with completed records, in settings order

    def by_planner(self, name: str) -> list[dict[str, Any]]:
        """The completed records of one planner."""
        return [r for r in self.records if r.get("planner") == name]



def load_experiment(path: str | Path) -> Experiment:
    """Read ``settings.json`` and ``episodes.jsonl``; failed records and a half-written last
    line are counted and skipped. :class:`ReportError` (one line) if either file is missing,
    a settings key is not of its kind (:func:`cdf_mj.records.read_settings`, naming the
    key), a line is not a record of the run (:func:`cdf_mj.records.read_records`, naming
    the file, the line and the field: of another seed or planner, or an episode twice),
    or no episode completed."""
    path = Path(path)
    settings_path, records_path = path / "settings.json", path / RECORDS_FILE
    for p in (settings_path, records_path):
        if not p.is_file():
            raise ReportError(f"{path} is not an experiment directory: {p.name} is missing "
                              f"(write one with: cdf-mj experiment --out {path})")
    try:  # every key and every line checked before any work: one line naming the file and the key or line
        settings = read_settings(settings_path)
        found = read_records(records_path, seeds=range(*settings["seeds"]), planners=settings["planners"])
    except ValueError as exc:
        raise ReportError(str(exc)) from None
    records = [r for r in found.records if r.get("status") != FAILED]
    failed, unreadable = len(found.records) - len(records), int(found.partial)
    if not records:
        raise ReportError(f"{records_path} holds no completed episode "
                          f"({failed} failed, {unreadable} half-written line(s))")
    planners = [p for p in settings["planners"] if any(r["planner"] == p for r in records)]
    return Experiment(path, settings, records, failed, unreadable, planners)


# ----------------------------------------------------------------- settings -> objects
def _tuples(value: Any) -> Any:
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


def _scenario(settings: dict[str, Any]) -> ScenarioConfig:
    raw = dict(settings["scenario"])  # an object (read_settings checked it), names one too
    names = raw.pop("names", None)
    fields = {k: _tuples(v) for k, v in raw.items()}
    try:
        if names:
            fields["names"] = SceneNames(**names)
        return ScenarioConfig.from_dict(fields)  # nested, or the flat settings of version 0.1
    except (TypeError, ValueError) as exc:
        raise ReportError(" ".join(f"settings.json: scenario settings this version cannot read ({exc})"
                                   .split())) from None


def _planner_factory(settings: dict[str, Any], name: str) -> PlannerSpec:
    """Planner ``name`` as the run built it: its stored arguments (``planner_args``, or
    for an older run what it took of the stored ``cdf`` settings). ValueError for a
    planner not registered in this process; ReportError for arguments this version
    cannot read."""
    try:
        arguments = stored_planner_arguments(settings).get(name, {})
        spec = bind_planner(name, arguments=arguments)
        spec.make()  # arguments the planner does not take, or out of range
    except (TypeError, ValueError) as exc:
        if name not in PLANNERS:
            raise ValueError(f"unknown planner {name!r}") from None
        raise ReportError(" ".join(f"settings.json: arguments of planner {name} this version cannot read ({exc})"
                                   .split())) from None
    return spec

