"""The ``lidarflow`` command: argument parsing only.

Errors are one line on stderr and exit status 1 (usage errors 2, typer's convention);
``LIDARFLOW_DEBUG=1`` shows tracebacks. The conventions every sub-command keeps (``-o``,
``--force``, ``-m``, ``--threads``) are checked by tests/test_cli_conventions.py, where a new
sub-command must be declared.
"""

from __future__ import annotations

import inspect
import os
import signal
import sys
import threading
from typing import Any

import typer

from lidarflow.cli.app import app, error_text

# Importing the command modules registers their commands on ``app``; --help lists them in this
# order.
# isort: off
from lidarflow.cli import recordings, scoring, prediction, live, robot, training, simulation, tuning  # noqa: F401
# isort: on

__all__ = ["app", "main", "stop_on_sigterm"]


def _reflow(text: str) -> str:
    """``text`` with each paragraph on one line: typer's rich help keeps a docstring's breaks."""
    return "\n\n".join(" ".join(p.split()) for p in inspect.cleandoc(text).split("\n\n"))


for _command in app.registered_commands:
    _command.help = _reflow(_command.help or inspect.getdoc(_command.callback) or "")


def _bare_flags() -> None:
    """Show flags bare in ``--help``, where typer's rich help (0.29) labels each ``<bool>`` as
    if it took a value."""
    from typer import core

    option = getattr(core, "TyperOption", None)
    shown = getattr(option, "display_type_rich", None)
    if option is None or shown is None:
        return

    def display_type_rich(self: Any, ctx: Any) -> str | None:
        return None if getattr(self, "is_flag", False) else shown(self, ctx)

    option.display_type_rich = display_type_rich


_bare_flags()


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(f"stopped by signal {signal.Signals(signum).name}")


def stop_on_sigterm() -> None:
    """Make SIGTERM (``kill``, a scheduler's stop) stop the process as Ctrl-C does, so that a
    file being written is removed (:mod:`lidarflow.atomic`) rather than left half-written."""
    if threading.current_thread() is threading.main_thread():  # signals go to that one only
        signal.signal(signal.SIGTERM, _interrupt)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the console script."""
    debug = os.environ.get("LIDARFLOW_DEBUG") == "1"
    stop_on_sigterm()
    try:
        app(args=argv, prog_name="lidarflow", standalone_mode=True)
    except KeyboardInterrupt:
        typer.echo("lidarflow: interrupted", err=True)
        sys.exit(130)
    except SystemExit as done:
        if done.code in (0, None):  # ran to its end: what compiles is kept for the next run
            from lidarflow.compiled import finish

            finish()
        # typer turns Ctrl-C into a silent exit 130 (KeyboardInterrupt -> Exit(130) -> here), so
        # say so, with what the command added about it (train: how to resume)
        interrupt = getattr(done.__context__, "__cause__", None)
        if done.code == 130 and isinstance(interrupt, KeyboardInterrupt):
            detail = f": {interrupt}" if str(interrupt) else ""
            typer.echo(f"lidarflow: interrupted{detail}", err=True)
        raise
    except Exception as err:
        if debug:
            raise
        words = [a for a in (sys.argv[1:] if argv is None else argv) if not a.startswith("-")]
        text = error_text(err, f"`lidarflow {words[0]}`" if words else "this")
        if text is not None:  # the user's to fix, not a bug to report
            typer.echo(f"lidarflow: error: {text}", err=True)
        else:  # a bug: still one line, with the way to the traceback
            typer.echo(
                f"lidarflow: internal error: {type(err).__name__}: {err} "
                "(rerun with LIDARFLOW_DEBUG=1 for the traceback, and please report it)",
                err=True,
            )
        sys.exit(1)
