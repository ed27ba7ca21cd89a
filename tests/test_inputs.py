"""The input layer (:mod:`cdf_mj.inputs`): regular files only, checked before they are
opened; a size bound before and while reading; a nesting bound before the JSON and TOML
parsers recurse; control characters escaped for the terminal. Real files: FIFOs,
``/dev/zero``, directories, links, and values 5000 levels deep built here."""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from pathlib import Path

import pytest

from cdf_mj.inputs import (
    MAX_DEPTH,
    InputError,
    NotRegularFileError,
    TOMLDecodeError,
    check_regular,
    is_path,
    packaged_files,
    parse_json,
    parse_toml,
    printable,
    read_named,
    read_regular,
    read_text,
)

needs_fifo = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
DEEP = 5000  # levels: past Python's recursion limit (1000), as in issue 28


@pytest.fixture
def deadline():
    """Every read here returns at once: a FIFO opened for a blocking read would hang."""
    start = time.monotonic()
    yield
    assert time.monotonic() - start < 10


# ------------------------------------------------------------------ regular files only
def test_a_regular_file_is_read_whole(tmp_path, deadline):
    path = tmp_path / "p.toml"
    path.write_bytes(b"x = 1\n\xc3\xa9")
    assert read_regular(path, "preset file", 100) == b"x = 1\n\xc3\xa9"
    assert read_text(str(path), "preset file", 100) == "x = 1\né"
    assert read_regular(path, "preset file", 8) == b"x = 1\n\xc3\xa9"  # exactly the bound


@needs_fifo
def test_a_fifo_is_refused_without_blocking(tmp_path, deadline):
    fifo = tmp_path / "p.toml"
    os.mkfifo(fifo)
    refused = rf"^preset file {fifo} is a FIFO \(named pipe\), not a regular file$"
    with pytest.raises(NotRegularFileError, match=refused):
        read_regular(fifo, "preset file", 100)
    link = tmp_path / "link.toml"
    link.symlink_to(fifo)  # a link is followed, and what it points to checked
    with pytest.raises(NotRegularFileError, match="is a FIFO") as err:
        read_text(link, "trace", 100)
    assert err.value.kind == "a FIFO (named pipe)"


@needs_fifo
def test_a_fifo_with_a_writer_is_refused_too(tmp_path, deadline):
    """Even a FIFO that would deliver data (a writer holds it open) is never read."""
    fifo = tmp_path / "trace.jsonl"
    os.mkfifo(fifo)
    writer = threading.Thread(target=lambda: fifo.write_text("{}\n" * 10), daemon=True)
    writer.start()
    with pytest.raises(NotRegularFileError):
        read_regular(fifo, "trace", 100)
    fd = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)  # let the writer finish
    writer.join(5)
    os.close(fd)


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="no /dev/zero")
def test_a_device_is_refused_before_any_byte_is_read(deadline):
    with pytest.raises(NotRegularFileError, match=r"^trace /dev/zero is a character device, not a regular file$"):
        read_regular("/dev/zero", "trace", 1 << 20)


def test_a_directory_is_refused_and_os_errors_pass_through(tmp_path, deadline):
    with pytest.raises(NotRegularFileError, match="is a directory, not a regular file"):
        read_regular(tmp_path, "names file", 100)
    with pytest.raises(InputError, match="is a directory"):
        check_regular(tmp_path, "names file")
    with pytest.raises(FileNotFoundError):
        read_regular(tmp_path / "none.json", "names file", 100)
    assert check_regular(__file__, "this test").st_size > 0


def test_the_size_bound_is_checked_before_reading(tmp_path, deadline):
    path = tmp_path / "big.toml"
    path.write_bytes(b"#" * 1001)
    with pytest.raises(InputError, match=rf"^preset file {path} is 1001 bytes, larger than the bound of 1000 bytes$"):
        read_regular(path, "preset file", 1000)
    path.write_bytes(b"#" * (2 << 20))
    with pytest.raises(InputError, match="larger than the bound of 1 MiB"):
        read_regular(path, "preset file", 1 << 20)


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="no /proc")
def test_a_file_that_reads_longer_than_its_size_is_cut_at_the_bound(deadline):
    """Files of /proc say they hold 0 bytes and then deliver more, as a file that grows
    between the check and the read would: the bound holds while reading too."""
    assert os.stat("/proc/self/status").st_size == 0
    with pytest.raises(InputError, match=r"^status file /proc/self/status grew past the bound of 100 bytes while"):
        read_regular("/proc/self/status", "status file", 100)
    assert len(read_regular("/proc/self/status", "status file", 1 << 20)) > 100


def test_a_file_that_grows_while_being_read_is_cut_at_the_bound(tmp_path, monkeypatch, deadline):
    """A writer that appends between the size check and the read: the read stops one byte
    past the bound and refuses."""
    import cdf_mj.inputs as inputs

    path = tmp_path / "trace.jsonl"
    path.write_bytes(b"{}\n")
    real_open = os.open

    def open_then_grow(*args, **kwargs):
        fd = real_open(*args, **kwargs)
        with path.open("ab") as fh:  # the writer, after the check
            fh.write(b"{}\n" * 10_000)
        return fd

    monkeypatch.setattr(inputs.os, "open", open_then_grow)
    with pytest.raises(InputError, match="grew past the bound of 1000 bytes while being read"):
        read_regular(path, "trace", 1000)


# ------------------------------------------------------------------ nesting
@pytest.mark.parametrize("text", ["[" * DEEP + "]" * DEEP, '{"a":' * DEEP + "1" + "}" * DEEP,
                                  "[" * DEEP, '{"obstacle": {"beta": ' + "[" * DEEP + "]" * DEEP + "}}"])
def test_deep_json_is_one_line_never_a_recursion_error(text):
    with pytest.raises(InputError, match=rf"^--set obstacle.beta is nested deeper than {MAX_DEPTH} levels"):
        parse_json(text, "--set obstacle.beta")
    with pytest.raises(InputError, match="nested deeper"):
        parse_json(text.encode(), "a settings file")


@pytest.mark.parametrize("text", [
    "x = " + "[" * DEEP + "]" * DEEP,  # arrays
    "x = " + "{a = " * DEEP + "1" + "}" * DEEP,  # inline tables
    "a" + ".a" * DEEP + " = 1",  # a dotted key
    "[" + ".".join(["t"] * DEEP) + "]\nx = 1\n",  # a table header
    '"q"' + '."q"' * DEEP + " = 1",  # quoted key parts
    "[" + ".".join(["t"] * 40) + "]\n" + ".".join(["k"] * 40) + " = 1\n",  # 81 levels, each part short
])
def test_deep_toml_is_one_line_never_a_recursion_error(text):
    start = time.monotonic()
    with pytest.raises(InputError, match=rf"^preset p.toml is nested deeper than {MAX_DEPTH} levels"):
        parse_toml(text, "preset p.toml")
    assert time.monotonic() - start < 2


def test_values_up_to_the_bound_parse_as_json_and_toml_do():
    deep = "[" * MAX_DEPTH + "]" * MAX_DEPTH
    assert parse_json(deep, "x") == json.loads(deep)
    in_string = json.dumps(["[" * 100 + '"[', "{" * 100])  # brackets inside strings do not nest
    assert parse_json(in_string, "x") == json.loads(in_string)
    text = ('description = """A driver [[[[ who waits.\n"quoted" """\n# [[[[[[[[[[[[[[[[[[[[[[[[[[[[[\n'
            "\"x.y\".'z' = 'a [ b'\n" + "".join(f"v{i} = {i}.5\n" for i in range(100))
            + "[scenario.obstacle]\nstop_dwell = [1.0, 3.0]  # [s] " + "[" * 100 + "\n")
    data = parse_toml(text, "x")
    assert data["scenario"]["obstacle"]["stop_dwell"] == [1.0, 3.0] and data["v99"] == 99.5
    assert data["x.y"]["z"] == "a [ b"
    with pytest.raises(json.JSONDecodeError):
        parse_json("[1, 2", "x")
    with pytest.raises(TOMLDecodeError):
        parse_toml("x = [1, 2", "x")


@pytest.mark.parametrize("text", ['"' + '\\"' * (1 << 19) + "[" * 100, '"' + "a" * (8 << 20) + '"' + "[" * 100,
                                  "x" * (1 << 20) + "[" * 100])
def test_the_nesting_scan_is_linear_on_hostile_text(text):
    """Unclosed strings full of escaped quotes, long strings, long words: one pass each."""
    start = time.monotonic()
    for parse in (parse_json, parse_toml):
        with pytest.raises(ValueError, match=r"nested deeper|Unterminated|Invalid|Expecting|Extra data"):
            parse(text, "x")
    assert time.monotonic() - start < 5


# ------------------------------------------------------------------ names or paths
class _NamedError(ValueError):
    pass


def test_one_rule_tells_a_users_file_from_a_shipped_name():
    """A path object, a ``.toml`` ending or a directory part, ``/`` or ``\\``, is a file."""
    assert [is_path(t) for t in ("default", "stop-and-wait", "a.toml", "a/b", "a\\b", Path("a"))] == [
        False, False, True, True, True, True]
    assert is_path("a.json", suffix=".json") and not is_path("a.toml", suffix=".json")


def test_a_named_file_is_the_users_or_the_packages(tmp_path):
    names = list(packaged_files("cdf_mj.presets"))
    assert names == sorted(names) and "default" in names
    shipped = read_named("default", "preset", "cdf_mj.presets", _NamedError)
    assert (shipped.name, shipped.source, shipped.path) == ("default", "default (cdf_mj/presets/default.toml)", None)
    space = read_named("default", "space", "cdf_mj.falsify", _NamedError, folder="spaces")
    assert space.source == "default (cdf_mj/falsify/spaces/default.toml)" and space.text
    mine = tmp_path / "mine.toml"
    mine.write_text("x = 1\n")
    assert read_named(mine, "preset", "cdf_mj.presets", _NamedError) == ("mine", str(mine), "x = 1\n", mine)
    with pytest.raises(_NamedError, match=r"^unknown preset 'nope': choose from .*default.*, or give the path of"):
        read_named("nope", "preset", "cdf_mj.presets", _NamedError)
    with pytest.raises(_NamedError, match=r"^preset file .*none.toml does not exist; give the path of a .toml file"):
        read_named(tmp_path / "none.toml", "preset", "cdf_mj.presets", _NamedError)


# ------------------------------------------------------------------ printing
def test_control_characters_are_escaped_for_the_terminal():
    text = "a \x1b[31mred\x1b[0m \x00 nul \x07 \x7f \x85 \u202e txt\n\tend é ü 日本"
    shown = printable(text)
    assert shown == "a \\x1b[31mred\\x1b[0m \\x00 nul \\x07 \\x7f \\x85 \\u202e txt\\x0a\\x09end é ü 日本"
    assert printable(text, keep="\n\t").endswith("txt\n\tend é ü 日本")
    assert all(c.isprintable() or c in "\n\t" for c in printable(text, keep="\n\t"))
    assert printable("plain text") == "plain text"


def test_the_layer_imports_nothing_of_the_package():
    import subprocess

    code = ("import sys, cdf_mj; before = set(sys.modules); import cdf_mj.inputs\n"
            "print(sorted(m for m in set(sys.modules) - before if m.startswith('cdf_mj')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "['cdf_mj.inputs']"  # beside what the package's facade loads
