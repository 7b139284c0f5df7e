"""Every option of the CLI that takes a real number refuses what is no number for it (NaN,
±inf, words, values out of its range) when the options are parsed: one line, exit 2, no
traceback, before anything runs. The options are found by walking the command tree, so a
new one cannot slip past."""

from __future__ import annotations

from collections.abc import Iterator

import click
import pytest

from tests.conftest import run_cli
from wftool.cli import cli
from wftool.cli.number import Number
from wftool.errors import EXIT_USAGE, UsageError

NOT_NUMBERS = ("nan", "inf", "-inf", "NaN", "-nan", "1e999", "abc")
EDGES = ("0", "-1", "-0.5")


def float_options(
    command: click.Command = cli, path: tuple[str, ...] = ()
) -> Iterator[tuple[tuple[str, ...], click.Parameter]]:
    """(command path, parameter) of every parameter of the CLI that converts to a float."""
    if isinstance(command, click.Group):
        for name, sub in command.commands.items():
            yield from float_options(sub, (*path, name))
        return
    for param in command.params:
        if isinstance(param.type, click.types.FloatParamType):
            yield path, param


OPTIONS = sorted(float_options(), key=lambda found: (found[0], found[1].opts[0]))
IDS = [" ".join((*path, param.opts[0])) for path, param in OPTIONS]


def test_the_walk_finds_the_options_named_in_bug_reports() -> None:
    found = set(IDS)
    for expected in ("ros2 --command-max-age", "sitl --command-max-age", "bench command --seconds",
                     "bench command --lead-ms", "preflight --limit-ms", "verify --uplink-lead",
                     "verify --max-outage", "record msp --duration"):  # fmt: skip
        assert expected in found
    assert len(found) >= 40


@pytest.mark.parametrize(("path", "param"), OPTIONS, ids=IDS)
def test_each_float_option_is_a_number_with_a_range(
    path: tuple[str, ...], param: click.Parameter
) -> None:
    assert isinstance(param.type, Number), f"{' '.join(path)} {param.opts[0]} is {param.type!r}"
    if isinstance(param.default, (int, float)):
        assert param.type.admits(param.default), "its default is in its range"


def refused(param: click.Parameter, value: str) -> bool:
    """Whether the option's type refuses `value` (as the parser will)."""
    try:
        param.type.convert(value, param, None)
    except UsageError:
        return True
    return False


@pytest.mark.parametrize(("path", "param"), OPTIONS, ids=IDS)
def test_each_float_option_refuses_what_is_no_number_in_one_line(
    path: tuple[str, ...], param: click.Parameter, capsys: pytest.CaptureFixture[str]
) -> None:
    option = param.opts[0]
    for value in (*NOT_NUMBERS, *EDGES):
        if value in EDGES and not refused(param, value):
            continue  # in its range: the command would run with it
        code, out, err = run_cli(capsys, *path, f"{option}={value}")
        assert code == EXIT_USAGE, (value, out, err)
        assert out == "" and "Traceback" not in err, (value, err)
        assert err.count("\n") == 1 and err.startswith(f"error: {option} must be "), (value, err)


def test_a_bench_that_is_no_length_starts_no_fc(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """`bench command --seconds 0` once started the FC, sent nothing and said "goal missed"."""
    import wftool.bench.command

    def started(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("the bench started a virtual FC")

    monkeypatch.setattr(wftool.bench.command, "run_command_bench", started)
    for value in ("0", "-5", "nan", "inf"):
        code, _, err = run_cli(capsys, "bench", "command", "--seconds", value, "--binary", __file__)
        assert (code, err) == (
            EXIT_USAGE,
            f"error: --seconds must be a positive number of seconds, not {float(value):g}\n",
        )
    code, _, err = run_cli(capsys, "bench", "command", "--lead-ms", "nan", "--binary", __file__)
    assert (code, err) == (
        EXIT_USAGE,
        "error: --lead-ms must be a number from 0 to 40 ms, not nan\n",
    )


@pytest.mark.parametrize(
    "args",
    [
        ("ros2", "--port", "socket://127.0.0.1:9", "--accept-commands", "--command-max-age", "nan"),
        ("sitl", "--binary", __file__, "--ros2", "--accept-commands", "--command-max-age", "nan"),
        ("preflight", "--sitl", "--binary", __file__, "--limit-ms", "nan"),
    ],
    ids=["ros2", "sitl --ros2", "preflight"],
)
def test_the_options_of_the_bug_reports_refuse_nan(
    args: tuple[str, ...], capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run_cli(capsys, *args)
    assert (code, out) == (EXIT_USAGE, "") and err.count("\n") == 1, err
    assert err.startswith(f"error: {args[-2]} must be ") and err.endswith(", not nan\n"), err
