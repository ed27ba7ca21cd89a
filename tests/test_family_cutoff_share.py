"""scripts/family_cutoff_share.py: the Cutoff share of a family over real episodes, and bad
input as one line with exit status 2."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_helpers import load_script

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "family_cutoff_share.py"
share = load_script(SCRIPT, "family_cutoff_share_script")


def test_it_counts_cutoffs_of_left_turners_against_the_constant_ego(capsys):
    assert share.main(["--family", "distracted,gap-acceptance", "--seed", "0", "--episodes", "12"]) == 0
    rows = {line.split(" | ")[0].strip("| "): line for line in capsys.readouterr().out.splitlines()
            if line.startswith("| ") and "/12 |" in line}
    assert set(rows) == {"distracted", "gap-acceptance"}
    cut = {name: int(row.split(" | ")[1].split("/")[0]) for name, row in rows.items()}
    assert cut["distracted"] >= 1 and cut["gap-acceptance"] == 0  # looks continuously: it never cuts off here


@pytest.mark.parametrize(("argv", "needle"), [
    (["--family", "nope"], "unknown family 'nope'"),
    (["--scene", "/no/such/scene.xml"], "scene file not found"),
    (["--episodes", "0"], "--episodes"),
    (["--set", "obstacle.beta=1.5"], "obstacle.beta"),
])
def test_bad_input_is_one_line(capsys, argv, needle):
    with pytest.raises(SystemExit) as exit_:
        share.main(argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("family_cutoff_share: error: ") and needle in err and err.count("\n") == 1
