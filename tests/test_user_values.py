"""One reader of what a user types (:mod:`cdf_mj.config.user_values`): ``--set``, a preset
file and a falsification space file take and refuse the same key and value alike, with
the same words (a number for an integer, true for a number, NaN, a string for a number, a
value out of range, an unknown key), read an old flat key the same way (a FlatKeyWarning
in the source's own spelling; a one-line note on the command line), and tell a path from a
name by one rule (a backslash is a path everywhere)."""

from __future__ import annotations

import json
import math
import os
import warnings
from pathlib import Path
from typing import Any

import pytest
from cli_helpers import assert_one_line_error, run_cli

from cdf_mj import cli
from cdf_mj.config import SCENARIO_KEYS, FlatKeyWarning, ScenarioConfig
from cdf_mj.config.user_values import (
    UserValueError,
    apply_values,
    coerce_value,
    dotted_key,
    flat_key_notes,
    read_value,
)
from cdf_mj.falsify.space import SpaceError, load_space
from cdf_mj.inputs import is_path
from cdf_mj.presets import PresetError, load_preset, preset_names, read_preset

HUGE = "9" * 400  # a number too large for a float

#: (key as typed, the value as --set takes it, the value as TOML writes it, outcome): the
#: value every reader gives, or the core of every reader's one-line refusal.
CASES: list[tuple[str, str, str, Any]] = [
    ("ego.speed", "12", "12", 12.0),
    ("ego.speed", "true", "true", "ego.speed must be a number, got true"),
    ("ego.speed", "fast", '"fast"', "ego.speed must be a number, got 'fast'"),
    ("ego.speed", "NaN", "nan", "ego.speed=nan is out of range: must be > 0 and <= 100 [m/s]"),
    ("ego.speed", "500", "500", "ego.speed=500.0 is out of range: must be > 0 and <= 100 [m/s]"),
    ("timing.duration", HUGE, HUGE, "timing.duration=9999999999999999999999999999999999999999...(400 characters) "
                                    "is out of range: must be in [dt = 0.1, 600] [s]"),
    ("sensing.latency", "2", "2", 2),
    ("sensing.latency", "true", "true", "sensing.latency must be an integer, got true"),
    ("sensing.latency", "1.0", "1.0", "sensing.latency must be an integer, got 1.0"),
    ("sensing.latency", "200", "200", "sensing.latency=200 is out of range: must be in [0, 100] [tick]"),
    ("ego.follow", "false", "false", False),
    ("ego.follow", "1", "1", "ego.follow must be true or false, got 1"),
    ("obstacle.family", "aggressive", '"aggressive"', "aggressive"),
    ("obstacle.family", "3", "3", "obstacle.family must be a string, got 3"),
    ("obstacle.family", "drunk", '"drunk"', "obstacle.family='drunk' is out of range"),
    ("obstacle.critcal_gap", "3", "3",
     "unknown field 'obstacle.critcal_gap' (did you mean 'obstacle.critical_gap'?); valid fields: timing.dt"),
    ("ego.start_spread", "[-4, 4]", "[-4, 4]", (-4.0, 4.0)),
    ("ego.start_spread", "[1, 2, 3]", "[1, 2, 3]",
     "ego.start_spread must be an array of 2 numbers, e.g. [-8, 8], got [1, 2, 3]"),
    ("ego.start_spread", "[5, -5]", "[5, -5]", "ego.start_spread=(5.0, -5.0) is out of range"),
]


def _preset_text(key: str, toml: str) -> str:
    group, dot, field = key.partition(".")
    table = f"[scenario.{group}]\n{field}" if dot else f"[scenario]\n{key}"
    return f'description = "One value, read from a preset."\n{table} = {toml}\n'


def via_set(key: str, text: str) -> Any:
    """The value ``--set KEY=TEXT`` gives its field on the command line (config_from_args)."""
    args = cli.build_parser().parse_args(["episode", "--set", f"{key}={text}"])
    return cli.config_from_args(args).get(key)


def via_preset(tmp_path: Path, key: str, toml: str) -> Any:
    """The value a preset file with ``KEY = TOML`` gives its field."""
    path = tmp_path / "preset.toml"
    path.write_text(_preset_text(key, toml))
    return load_preset(path).get(key)


def via_space(tmp_path: Path, key: str, toml: str) -> Any:
    """The value a space file's one choice ``TOML`` of ``[dims."KEY"]`` gives its field
    (a pair option's choice is the range [v, v]: a space pins pairs)."""
    path = tmp_path / "space.toml"
    path.write_text(f'description = "One value, read from a space."\n[dims."{key}"]\nchoices = [{toml}]\n')
    space = load_space(path)
    return space.config([0.0]).get(space.keys[0])


def _outcome(read: Any, *args: Any) -> tuple[str, Any]:
    """("value", the value) or ("error", the one-line message)."""
    try:
        return "value", read(*args)
    except ValueError as exc:
        message = str(exc)
        assert "\n" not in message
        return "error", message


@pytest.mark.parametrize(("key", "text", "toml", "outcome"), CASES,
                         ids=[f"{k}={t[:12]}" for k, t, _, _ in CASES])
def test_set_presets_and_spaces_take_and_refuse_alike(tmp_path, key, text, toml, outcome):
    """The same key and value: the same value, or refusals of one line with the same
    core, each naming its source (``--set`` or the file) and the key."""
    pair = isinstance(ScenarioConfig().get(key) if key in SCENARIO_KEYS else None, tuple)
    got = {"--set": _outcome(via_set, key, text), "preset": _outcome(via_preset, tmp_path, key, toml)}
    if not pair:  # a space varies a pair by a range, never by choices (test_falsify)
        got["space"] = _outcome(via_space, tmp_path, key, toml)
    for source, (kind, value) in got.items():
        if isinstance(outcome, str) and kind == "error":
            assert outcome in value, (source, value)
            assert value.startswith("--set: " if source == "--set" else f"{source} {tmp_path}")
        else:
            assert (kind, value) == ("value", outcome), source
            assert type(value) is type(outcome)


def test_a_flat_key_is_read_alike_with_a_warning_in_each_sources_words(tmp_path):
    """``beta`` (version 0.1) is ``obstacle.beta`` everywhere, with a FlatKeyWarning (a
    DeprecationWarning) that says how the same source writes it now."""
    expected = {
        "--set": "--set beta is now --set obstacle.beta",
        "preset": f"preset {tmp_path / 'preset.toml'}: [scenario] beta is now [scenario.obstacle] beta",
        "space": f'space {tmp_path / "space.toml"}: [dims."beta"] is now [dims."obstacle.beta"]'}
    for source, read in (("--set", lambda: read_value("beta", 0.2, lambda k: f"--set {k}")[1]),
                         ("preset", lambda: via_preset(tmp_path, "beta", "0.2")),
                         ("space", lambda: via_space(tmp_path, "beta", "0.2"))):
        with pytest.warns(FlatKeyWarning) as got:
            assert read() == 0.2
        assert issubclass(FlatKeyWarning, DeprecationWarning)
        assert expected[source] in {str(w.message) for w in got}, source


def test_the_command_line_shows_a_flat_key_as_one_note_and_an_error_as_one_line(tmp_path, capsys):
    """On the command line each flat key (of ``--set`` and of a preset file) is one note on
    stderr; with a mistake as well, the error is the only line."""
    path = tmp_path / "old.toml"
    path.write_text(_preset_text("critical_gap", "4"))
    argv = ["episode", "--seed", "2", "--no-label", "--planner", "constant", "--preset", str(path)]
    status, _, err = run_cli(capsys, *argv, "--set", "beta=0")
    assert status == 0 and sorted(err.splitlines()) == [
        "cdf-mj: note: --set beta is now --set obstacle.beta",
        f"cdf-mj: note: preset {path}: [scenario] critical_gap is now [scenario.obstacle] critical_gap"]
    assert_one_line_error(*run_cli(capsys, *argv, "--set", "beta=2"), "--set: obstacle.beta=2.0 is out of range")


def test_parse_overrides_alone_says_a_flat_key_on_stderr(capsys):
    """A script's own parser (cdf_mj.cli.parse_overrides): the note as before."""
    assert cli.parse_overrides(["beta=0.1", "ego.start_spread=[-4, 4]"]) == {
        "obstacle.beta": 0.1, "ego.start_spread": (-4.0, 4.0)}
    assert capsys.readouterr().err == "cdf-mj: note: --set beta is now --set obstacle.beta\n"


@pytest.mark.parametrize("name", preset_names())
def test_every_shipped_preset_reads_the_same_through_set(name):
    """Each value of every shipped preset, given as ``--set`` JSON, builds the same config."""
    items = [f"{key}={json.dumps(value)}" for key, value in read_preset(name).scenario.items()]
    assert apply_values(ScenarioConfig(), cli.parse_overrides(items)) == load_preset(name)


@pytest.mark.parametrize("key", [k for k in SCENARIO_KEYS if isinstance(ScenarioConfig().get(k), (float, tuple))])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 10**400])
def test_every_number_has_a_range_that_refuses_what_is_not_finite(key, bad):
    """coerce_value leaves ranges to the config: every number field must have one that
    refuses NaN, infinities and a number too large for a float, naming the field."""
    value = coerce_value(key, (bad, bad) if isinstance(ScenarioConfig().get(key), tuple) else bad)
    with pytest.raises(UserValueError, match=rf"^{key}=.* is out of range"):
        apply_values(ScenarioConfig(), {key: value})


def test_keys_dotted_flat_and_unknown():
    assert dotted_key("obstacle.beta") == "obstacle.beta"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        dotted_key("ego.speed")  # no warning for a dotted key
        with pytest.raises(FlatKeyWarning, match=r"^ego_speed is now ego\.speed$"):
            dotted_key("ego_speed")
    for key in ("names", "obstacle", "", "obstacle.beta.x"):
        with pytest.raises(UserValueError, match=f"^unknown field {key!r}"):
            dotted_key(key)


def test_one_rule_tells_a_path_from_a_name():
    """A path object, a .toml ending or a directory part (``/`` or a Windows ``\\``)."""
    assert not is_path("stop-and-wait") and not is_path("default")
    for text in ("mine.toml", "dir/mine", "dir\\mine", Path("mine")):
        assert is_path(text)


def test_a_backslash_is_a_path_for_presets_and_spaces(tmp_path):
    """A name with a backslash is a file for both readers (not an unknown name)."""
    with pytest.raises(PresetError, match=r"preset file dir\\none does not exist"):
        read_preset("dir\\none")
    with pytest.raises(SpaceError, match=r"space file dir\\none does not exist"):
        load_space("dir\\none")


@pytest.mark.skipif(os.sep == "\\", reason="a backslash is a directory part here: the file would be in a folder")
def test_a_spaces_preset_with_a_backslash_is_read_beside_the_space(tmp_path, monkeypatch):
    (tmp_path / "my\\slow").write_text(_preset_text("ego.speed", "9.0"))
    (tmp_path / "space.toml").write_text('description = "x"\npreset = "my\\\\slow"\n'
                                         '[dims."obstacle.beta"]\nrange = [0.0, 0.5]\n')
    monkeypatch.chdir(tmp_path.parent)
    assert load_space(tmp_path / "space.toml").base.ego.speed == 9.0


def test_flat_key_notes_hold_flat_keys_until_the_block_ends_and_let_others_pass():
    shown: list[str] = []
    with warnings.catch_warnings(record=True) as other, flat_key_notes(shown.append):
        warnings.simplefilter("always")
        dotted_key("beta", lambda k: f"--set {k}")
        warnings.warn("another warning", UserWarning, stacklevel=1)
        assert shown == [] and [str(w.message) for w in other] == ["another warning"]  # at once; the note held
        with flat_key_notes(shown.append):  # an inner block leaves the notes to the outer one
            dotted_key("ego_speed")
        assert shown == []
    assert shown == ["--set beta is now --set obstacle.beta", "ego_speed is now ego.speed"]

    def flat_then_wrong() -> None:
        with flat_key_notes(shown.append):
            dotted_key("beta")
            dotted_key("nosuch")

    shown.clear()
    with pytest.raises(UserValueError, match="nosuch"):
        flat_then_wrong()
    assert shown == []  # an error is the only line
