"""A search space checked as a whole before any episode (issue 39, cause 6): dimensions
valid alone but not together (the episode's duration against a sensing latency), a range
over ``timing.dt`` (values between its ends a scene refuses), and values the run's scene
refuses (a ``timing.dt`` that is not a whole multiple of its timestep) are one line naming
the file and the dimensions, before the first episode."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_helpers import assert_one_line_error, run_cli

from cdf_mj.falsify.evaluate import JOURNAL_FILE
from cdf_mj.falsify.run import estimate, falsify
from cdf_mj.falsify.space import SpaceError, load_space, space_names

FAST = '''description = "The default world, ended at 6 s."

[scenario.timing]
until_clear = false
end_distance = 30.0
duration = 6.0
'''

HEAD = '''description = "A space of two options."
preset = "fast.toml"

[failure]
margin = "gap"
threshold = 0.0
'''

#: Each valid alone (a 1 s episode without latency; 30 ticks of latency in a 6 s episode),
#: not together: a 1 s episode has 10 ticks.
DURATION_LATENCY = HEAD + '''
[dims."timing.duration"]
range = [1.0, 6.0]

[dims."sensing.latency"]
range = [0, 30]
'''
DT_RANGE = HEAD + '''
[dims."timing.dt"]
range = [0.05, 0.1]
'''
#: 0.1003 s passes the config (0 < dt <= 1) but is no whole multiple of the scene's 5 ms.
DT_OFF_GRID = HEAD + '''
[dims."timing.dt"]
choices = [0.1, 0.1003]
'''


def _space(tmp_path: Path, text: str) -> Path:
    (tmp_path / "fast.toml").write_text(FAST)
    path = tmp_path / "space.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(("text", "needles"), [
    (DURATION_LATENCY, ('[dims."timing.duration"] = 1.0', '[dims."sensing.latency"] = 30',
                        "fewer ticks than the episode's 10")),
    (DT_RANGE, ('[dims."timing.dt"]', "give its values as choices")),
    (DT_OFF_GRID, ('[dims."timing.dt"] = 0.1003', "not a whole multiple of the timestep")),
])
@pytest.mark.parametrize("run", [falsify, estimate])
def test_a_space_the_world_refuses_as_a_whole_is_one_line_before_any_episode(tmp_path, text, needles, run):
    path = _space(tmp_path, text)
    out = tmp_path / "out"
    kwargs = {"figure": False} if run is falsify else {"method": "mc"}
    with pytest.raises(SpaceError) as info:
        run(load_space(path), "reactive", 8, out, workers=1, **kwargs)
    message = str(info.value)
    assert "\n" not in message and str(path) in message, message
    for needle in needles:
        assert needle in message, (needle, message)
    journal = out / JOURNAL_FILE
    assert not journal.exists() or journal.read_bytes() == b""  # no episode ran


def test_the_command_line_says_it_in_one_line(tmp_path, capsys):
    path = _space(tmp_path, DURATION_LATENCY)
    status, out, err = run_cli(capsys, "falsify", "--space", str(path), "--planner", "reactive", "--workers", "1",
                               "--out", str(tmp_path / "out"), "--quiet", "--no-figure")
    assert_one_line_error(status, out, err, str(path), '[dims."sensing.latency"] = 30')


@pytest.mark.parametrize("name", space_names())
def test_every_shipped_space_passes_as_a_whole(name, scene):
    from cdf_mj.falsify.space_check import check_joint, check_on_scene

    space = load_space(name)
    check_joint(space)
    check_on_scene(space, scene)


def test_a_long_choice_is_probed_at_its_ends_and_extremes():
    from cdf_mj.falsify.space import Choice, Range
    from cdf_mj.falsify.space_check import MAX_PROBES, probes

    assert probes(Range("ego.speed", 5.0, 12.0)) == [5.0, 12.0]
    assert probes(Choice("sensing.latency", tuple(range(40)), (1 / 40,) * 40)) == [0.0, 39.0]
    values = (3, 9, 0, 5, 1, 2, 4, 6, 7, 8)
    assert len(values) > MAX_PROBES
    assert probes(Choice("sensing.latency", values, (0.1,) * 10)) == [0.0, 1.0, 2.0, 9.0]


# ----------------------------------------------------------------- the minor cases
BIG = "1" + "0" * 400


@pytest.mark.parametrize(("text", "needle"), [
    (HEAD + f'\n[dims."ego.speed"]\nrange = [5.0, {BIG}]\n', '[dims."ego.speed"]: range must be [low, high]'),
    (HEAD.replace("threshold = 0.0", f"threshold = {BIG}") + '\n[dims."ego.speed"]\nrange = [5.0, 9.0]\n',
     "threshold must be a finite number"),
    (HEAD + f'\n[dims."obstacle.family"]\nchoices = ["model", "aggressive"]\nweights = [1, {BIG}]\n',
     "weights must be 2 finite numbers"),
])
def test_a_400_digit_number_is_one_line_naming_the_file(tmp_path, text, needle):
    path = _space(tmp_path, text)
    with pytest.raises(SpaceError) as info:
        load_space(path)
    assert str(path) in str(info.value) and needle in str(info.value)


def test_weights_of_1e308_are_read_as_the_shares_they_are(tmp_path):
    path = _space(tmp_path, HEAD + '\n[dims."obstacle.family"]\nchoices = ["model", "aggressive"]\n'
                                   'weights = [1e308, 1e308]\n')
    assert load_space(path).dims[0].weights == (0.5, 0.5)


def test_a_search_of_one_dimension_is_one_line_of_ours(tmp_path):
    path = _space(tmp_path, HEAD + '\n[dims."obstacle.family"]\nchoices = ["model"]\n')
    with pytest.raises(SpaceError, match="the search \\(CMA-ES\\) needs at least 2 dimensions, this space has 1"):
        falsify(load_space(path), "reactive", 8, tmp_path / "out", workers=1, figure=False)


def test_a_space_files_name_is_printed_as_what_it_is(tmp_path):
    (tmp_path / "fast.toml").write_text(FAST)
    path = tmp_path / "a\x1b[31mb\nc.toml"
    path.write_text(HEAD + '\n[dims."ego.speed"]\nrange = [5.0, 9.0]\n')
    name = load_space(path).name
    assert name == "a\\x1b[31mb\\x0ac" and name.isprintable()
