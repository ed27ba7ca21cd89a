"""scripts/particle_count.py over real episodes: every candidate beside the reference on the
same ticks, the closed loop's paired rows with the null and the streams' spread, the
candidates' names, and bad input as one line."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_helpers import load_script

from cdf_mj.config import AdaptiveConfig, CDFConfig

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "particle_count.py"
counts = load_script(SCRIPT, "particle_count_script")


def test_a_candidate_is_a_fixed_count_or_an_adaptive_range():
    assert counts.candidate("300") == CDFConfig(n_particles=300)
    assert counts.candidate("adaptive:100-800") == CDFConfig(n_particles=800, adaptive=AdaptiveConfig(n_min=100))
    assert counts._shown("300") == "N = 300" and counts._shown("adaptive:100-800") == "adaptive 100-800"


def test_both_parts_on_real_episodes(capsys):
    assert counts.main(["--seeds", "830000-830001", "--presets", "default", "--counts", "100,adaptive:100-400",
                        "--reference", "400", "--streams", "3", "--workers", "1"]) == 0
    out = capsys.readouterr().out
    agreement = [line for line in out.splitlines() if line.startswith(("| N = 100 | ", "| adaptive 100-400 | "))]
    assert len(agreement) == 2
    for line in agreement:  # shares in [0, 100] %, two episodes, errors, a mean count within the candidate's range
        cells = line.strip("|").split(" | ")
        assert 0.0 <= float(cells[1].rstrip("%")) <= 100.0 and cells[2].endswith("/2")
        assert 100 <= float(cells[5]) <= 400
    paired = [line for line in out.splitlines() if line.startswith(("| default | ", "| all, pooled | "))]
    # per preset and pooled: the null (N = 1000 on another stream) and each candidate
    assert [line.split(" | ")[1] for line in paired] == ["N = 1000, another stream", "N = 100", "adaptive 100-400"] * 2
    assert all(line.endswith(("| yes |", "| **no** |")) for line in paired)
    assert "The declared bar for changing the default (pooled: no more collisions than the shipped count and " \
           "every p >= 0.5) is met by: " in out
    spread = [line for line in out.splitlines() if line.startswith("| default: ")]
    assert [line.split(" | ")[0] for line in spread] == ["| default: collisions", "| default: non-Cutoff interventions",
                                                         "| default: non-Cutoff hard brakes"]


@pytest.mark.parametrize(("argv", "word"), [
    (["--counts", "250,many"], "--counts"),
    (["--counts", "adaptive:900-100"], "--counts"),
    (["--seeds", "9-3"], "--seeds"),
    (["--streams", "1"], "--streams"),
    (["--reference", "adaptive:100-400"], "--reference"),
    (["--parts", "open"], "--parts"),
    (["--presets", "no-such-preset"], "no-such-preset"),
])
def test_bad_input_is_one_line(argv, word, capsys):
    with pytest.raises(SystemExit) as exit_:
        counts.main(argv)
    assert exit_.value.code == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith("particle_count: error: ") and word in last
