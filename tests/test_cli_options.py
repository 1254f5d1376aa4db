"""A command's options as one record (lidarflow.cli.options): typer sees the fields as the
parameters they stand for, and the command gets the record."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import pytest
import typer
from typer.testing import CliRunner

from lidarflow.cli.options import command_options


@dataclass(frozen=True)
class Greeting:
    name: Annotated[str, typer.Argument(help="Who.")]
    loud: Annotated[bool, typer.Option("--loud", help="Shout.")] = False
    times: Annotated[int, typer.Option(help="How often.", min=1)] = 1
    accent: Annotated[str, typer.Option(help="Only the second command's.")] = "plain"


def _app() -> tuple[typer.Typer, list[Greeting]]:
    app, got = typer.Typer(), []

    @app.command()
    @command_options(Greeting)
    def greet(options: Greeting) -> None:
        """Say hello."""
        got.append(options)

    @app.command()
    @command_options(Greeting, omit=("accent",))
    def nod(options: Greeting) -> None:
        """Nod."""
        got.append(options)

    return app, got


def test_the_command_gets_the_record_the_command_line_makes():
    app, got = _app()
    result = CliRunner().invoke(app, ["greet", "Ann", "--loud", "--times", "2", "--accent", "x"])
    assert result.exit_code == 0, result.output
    assert got == [Greeting("Ann", loud=True, times=2, accent="x")]


def test_options_keep_their_checks_help_and_order():
    app, _ = _app()
    runner = CliRunner()
    assert runner.invoke(app, ["greet", "Ann", "--times", "0"]).exit_code == 2  # min=1
    text = runner.invoke(app, ["greet", "--help"], env={"COLUMNS": "100"}).output
    assert "Say hello." in text and "How often." in text
    assert text.index("--loud") < text.index("--times") < text.index("--accent")


def test_an_omitted_field_is_no_option_and_keeps_its_default():
    app, got = _app()
    runner = CliRunner()
    assert "--accent" not in runner.invoke(app, ["nod", "--help"]).output
    assert runner.invoke(app, ["nod", "Bo", "--accent", "x"]).exit_code == 2
    assert runner.invoke(app, ["nod", "Bo"]).exit_code == 0
    assert got == [Greeting("Bo")]


def test_omitting_a_field_the_record_lacks_is_refused():
    with pytest.raises(ValueError, match="no field of Greeting"):
        command_options(Greeting, omit=("volume",))
