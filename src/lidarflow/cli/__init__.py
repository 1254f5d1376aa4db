"""The ``lidarflow`` command: argument parsing only.

Every sub-command turns lidarflow errors into one line on stderr and exit status 1; usage errors
exit with 2 (typer/click's convention). Set ``LIDARFLOW_DEBUG=1`` to see tracebacks.

Conventions every sub-command keeps (tests/test_cli_conventions.py walks them all, and a new
sub-command must be declared there): what it writes is named by ``-o/--output``, refused where
it exists unless ``--force``, and written whole or not at all (:mod:`lidarflow.atomic`; SIGTERM
stops a run as Ctrl-C does, so nothing half-written stays); ``-m/--model`` is a trained model;
a command that runs a model takes ``--threads`` (default 1, :data:`app.DEFAULT_THREADS`); a
command's help is a few lines, an option's a line or two.
"""

from __future__ import annotations

import inspect
import os
import signal
import sys
import threading
from typing import Any

import typer

from lidarflow.cli.app import app
from lidarflow.errors import LidarflowError
from lidarflow.extras import missing_extra

# Importing the command modules registers their commands on ``app``; --help lists them in this
# order.
# isort: off
from lidarflow.cli import recordings, scoring, prediction, live, robot, training, simulation, tuning  # noqa: F401
# isort: on

__all__ = ["app", "main", "stop_on_sigterm"]


def _reflow(text: str) -> str:
    """``text`` with the line breaks inside each paragraph joined: typer's rich help keeps them,
    so a docstring's own wrapping and the terminal's would break lines twice."""
    return "\n\n".join(" ".join(p.split()) for p in inspect.cleandoc(text).split("\n\n"))


for _command in app.registered_commands:
    _command.help = _reflow(_command.help or inspect.getdoc(_command.callback) or "")


def _bare_flags() -> None:
    """Show flags bare in ``--help``: typer's rich help (0.29) labels every flag ``<bool>``, as
    if it took a value, which ``--verbose true`` is then refused for. Nothing where this typer
    renders help otherwise."""
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
    except LidarflowError as err:
        if debug:
            raise
        typer.echo(f"lidarflow: error: {err}", err=True)
        sys.exit(1)
    except KeyboardInterrupt:
        typer.echo("lidarflow: interrupted", err=True)
        sys.exit(130)
    except SystemExit as done:
        # typer turns Ctrl-C into a silent exit 130 (KeyboardInterrupt -> Exit(130) -> here), so
        # say so, with what the command added about it (train: how to resume)
        interrupt = getattr(done.__context__, "__cause__", None)
        if done.code == 130 and isinstance(interrupt, KeyboardInterrupt):
            detail = f": {interrupt}" if str(interrupt) else ""
            typer.echo(f"lidarflow: interrupted{detail}", err=True)
        raise
    except OSError as err:  # the file system said no (permissions, a file where a folder
        if debug:  # should be, a full disk): the user's to fix, not a bug to report
            raise
        where = f"{err.filename}: " if err.filename else ""
        typer.echo(f"lidarflow: error: {where}{err.strerror or err}", err=True)
        sys.exit(1)
    except Exception as err:  # a bug: still one line, with the way to the traceback
        if debug:
            raise
        # unless it is a package of an extra this install lacks: then say which extra
        words = [a for a in (sys.argv[1:] if argv is None else argv) if not a.startswith("-")]
        what = f"`lidarflow {words[0]}`" if words else "this"
        missing = missing_extra(err, what) if isinstance(err, ImportError) else None
        if missing is not None:
            typer.echo(f"lidarflow: error: {missing}", err=True)
            sys.exit(1)
        typer.echo(
            f"lidarflow: internal error: {type(err).__name__}: {err} "
            "(rerun with LIDARFLOW_DEBUG=1 for the traceback, and please report it)",
            err=True,
        )
        sys.exit(1)
