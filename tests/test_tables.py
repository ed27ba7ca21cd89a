"""cdf_mj.analysis.tables: the experiment's tables as text for a person and as the docs' Markdown."""

from __future__ import annotations

import pytest
from test_records import episode

from cdf_mj.analysis.metrics import planner_metrics, scenario_summary
from cdf_mj.analysis.tables import PAPER_PLANNERS, experiment_tables, format_scenario_summary
from cdf_mj.config import CDFConfig
from cdf_mj.experiments.experiment import run_experiment
from cdf_mj.records import FAILED

#: Two planners on five seeds with known outcomes, and a failed episode.
RECORDS = [
    episode(0, "cdf", "Cutoff", brake=0.9, entered=2.0, predicted="Cutoff", min_gap=4.0, time_lost=2.5),
    episode(0, "reactive", "Cutoff", brake=2.0, entered=2.0, collision="obstacle", time_lost=0.3),
    episode(1, "cdf", "Cutoff", brake=1.0, entered=1.9, collision="obstacle", predicted="Cutoff"),
    episode(1, "reactive", "Cutoff", brake=1.9, entered=1.9, min_gap=0.8, time_lost=1.0),
    episode(2, "cdf", "Yield", brake=0.9, collision="obstacle", predicted="Cutoff"),
    episode(2, "reactive", "Yield", time_lost=0.0),
    episode(3, "cdf", "Yield", predicted="Yield", time_lost=0.1),
    episode(3, "reactive", "Yield", time_lost=0.0),
    episode(4, "cdf", "Right", predicted="Right", min_gap=6.0, time_lost=0.0),
    episode(4, "reactive", "Right", brake=1.5, time_lost=3.0),
    {"seed": 5, "planner": "cdf", "status": FAILED, "error": "RuntimeError: boom", "traceback": ""},
]

#: experiment_tables(RECORDS) as the Markdown of docs/RESULTS.md was printed before the
#: text format existed (derived once, from the version of commit de8a0eb), with the hard-brake
#: false alarms so named and the table of every intervention (issue 35) added; these records
#: carry no ``intervention``, and the table says so.
MARKDOWN = r"""CDF predictions (5 episodes): ours | paper

| scenario \ prediction | Cutoff | Yield | Right | total |
|---|---|---|---|---|
| Cutoff | 2 \| 417 | 0 \| 0 | 0 \| 0 | 2 \| 417 |
| Yield | 1 \| 13 | 1 \| 334 | 0 \| 0 | 2 \| 347 |
| Right | 0 \| 0 | 0 \| 0 | 1 \| 236 | 1 \| 236 |

Cutoff recall: 100.0 % [34.2, 100.0] (2/2) (paper 100 %)

| planner | collisions imminent | collisions occurred | avoided (95 % CI) | (imminent - occurred) / imminent | paper: imminent / occurred / avoided | hard-brake false alarms (95 % CI) | median lead time [s] | median min gap [m] | mean time lost, no collision [s] |
|---|---|---|---|---|---|---|---|---|---|
| cdf | 2 | 2 | 50.0 % [9.5, 90.5] (1/2) | 0.0 % | 417 / 9 / 98 % | 20.0 % [3.6, 62.4] (1/5) | 1.00 | 2.00 | 0.87 |
| reactive | 2 | 1 | 50.0 % [9.5, 90.5] (1/2) | 50.0 % | 404 / 213 / 47 % | 20.0 % [3.6, 62.4] (1/5) | 0.00 | 2.00 | 1.00 |

Every intervention:

| planner | hard-brake false alarms, of all episodes (95 % CI) | interventions, not Cutoff (95 % CI) | time lost at the fixed point vs constant, not Cutoff [s] (seeds) | median peak deceleration, intervening, not Cutoff [m/s²] | interventions, Yield (95 % CI) | interventions, Right (95 % CI) | interventions in Cutoff: recall (95 % CI) | hard subset avoided (Cutoffs `constant` hits) |
|---|---|---|---|---|---|---|---|---|
| cdf | 20.0 % [3.6, 62.4] (1/5) | - | - | - | - | - | - | - |
| reactive | 20.0 % [3.6, 62.4] (1/5) | - | - | - | - | - | - | - |

Interventions: episodes in which the planner's command held the ego below its own controller (speed hold and car following) by more than 10 % of the car's full brake on some tick, hard brake or not. False alarms count hard brakes only (the hard-brake false alarms). Time lost at the fixed point: when the ego passes timing.label_distance beyond the conflict point, minus when the same seed's `constant` ego (which follows too) does, pairs without a collision (an ego that never got there is extrapolated at its nominal speed: a lower bound).

No `constant` episodes in these records: no time lost at the fixed point and no hard subset ('-').

Records without `intervention` (written before it was kept): cdf 5, reactive 5; the intervention columns count the others ('-' where none).

'-' in a cell: nothing to measure there (no episode of that label or subset, no intervention for a peak deceleration, or no same-seed `constant` episode for the time lost). `constant` is the reference: it never intervenes, and its time lost is 0 by definition.

1 failed episode(s) left out of these tables (their records hold the error and traceback)."""  # noqa: E501


@pytest.fixture(scope="module")
def real_records(tmp_path_factory):
    """Seeds 0-3 (Right, Cutoff, Right, Yield) with the CDF and the reactive planner."""
    out = tmp_path_factory.mktemp("tables")
    return run_experiment(out, range(4), ("cdf", "reactive"), cdf=CDFConfig(n_particles=300), progress=False,
                          workers=1).records


def test_markdown_is_the_docs_format_unchanged():
    assert experiment_tables(RECORDS, fmt="markdown") == MARKDOWN


def test_text_tables_fit_100_columns_with_one_avoided_figure_explained(real_records):
    for records in (RECORDS, real_records):
        text = experiment_tables(records)
        lines = text.splitlines()
        assert max(map(len, lines)) <= 100
        assert "\\|" not in text and "|---" not in text  # no Markdown
        # One "avoided" column; the paper's formula beside it, each defined in one line.
        header = next(line for line in lines if line.startswith("planner ") and "occurred" in line)
        assert header.count("avoided") == 1 and "paper's formula" in header
        assert any(line.startswith("avoided: Cutoff episodes without a collision with the obstacle")
                   for line in lines)
        assert any(line.startswith("paper's formula: (imminent - occurred) / imminent") for line in lines)
        assert "docs/RESULTS.md" in lines[-1] or "docs/RESULTS.md" in lines[-3]


def test_text_rows_hold_the_metrics(real_records):
    text = experiment_tables(real_records)
    for name, m in planner_metrics(real_records).items():
        collisions = next(line for line in text.splitlines() if line.startswith(f"{name} ") and "%" in line)
        assert collisions.split()[1:3] == [str(m.imminent), str(m.collisions)]
        assert str(m.avoided) in collisions
    for name, (imminent, occurred) in PAPER_PLANNERS.items():
        row = next(line for line in text.splitlines() if line.startswith(f"paper: {name} "))
        assert row.split()[2:4] == [str(imminent), str(occurred)]
    text = experiment_tables(RECORDS)
    assert "20.0 % [3.6, 62.4] (1/5)" in text and "1 failed episode(s) left out" in text
    row = next(line for line in text.splitlines() if line.startswith("cdf ") and "(1/2)" in line)
    assert row.endswith("0.0 %")  # the paper's formula charges the collision of seed 2 (a Yield)


def test_tables_without_cdf_records_and_a_bad_format():
    reactive = [r for r in RECORDS if r["planner"] == "reactive"]
    assert "CDF predictions" not in experiment_tables(reactive)
    assert "paper: cdf" not in experiment_tables(reactive)
    with pytest.raises(ValueError, match="unknown table format 'html': choose one of text, markdown"):
        experiment_tables(RECORDS, fmt="html")  # type: ignore[arg-type]


def test_scenario_summary_table_has_the_papers_shares():
    table = format_scenario_summary(scenario_summary(RECORDS), "cdf")
    assert "| Cutoff share | 40.0 % [16.8, 68.7] (4/10) | 41.7 % |" in table
    assert "| Yield share |" in table and "34.7 %" in table and "23.6 %" in table
    assert "98 % (cdf), 47 % (reactive)" in table
