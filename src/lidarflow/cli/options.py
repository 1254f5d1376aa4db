"""A command's options as one record: a typer callback built from a frozen dataclass whose
fields are annotated with their ``typer.Option`` or ``typer.Argument``:

    @dataclass(frozen=True)
    class GreetOptions:
        name: Annotated[str, typer.Argument(help="Who.")]
        loud: Annotated[bool, typer.Option("--loud", help="Shout.")] = False

    @app.command()
    @command_options(GreetOptions)
    def greet(options: GreetOptions) -> None:
        '''Say hello.'''
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import typing
from collections.abc import Callable, Collection
from typing import Any, TypeVar

__all__ = ["command_options"]

R = TypeVar("R")


def command_options(
    record: type[R], omit: Collection[str] = ()
) -> Callable[[Callable[[R], None]], Callable[..., None]]:
    """Decorate ``run(options: R)`` into a typer callback whose parameters are the fields of
    the dataclass ``record`` (but those in ``omit``, which keep their defaults), calling
    ``run`` with the ``record`` they make."""
    hints = typing.get_type_hints(record, include_extras=True)
    fields = [f for f in dataclasses.fields(record) if f.name not in omit]  # type: ignore[arg-type]
    unknown = set(omit) - {f.name for f in dataclasses.fields(record)}  # type: ignore[arg-type]
    if unknown:
        raise ValueError(f"omit names no field of {record.__name__}: {sorted(unknown)}")
    parameters = [
        inspect.Parameter(
            f.name,
            inspect.Parameter.POSITIONAL_OR_KEYWORD,
            default=inspect.Parameter.empty if f.default is dataclasses.MISSING else f.default,
            annotation=hints[f.name],
        )
        for f in fields
    ]

    def decorate(run: Callable[[R], None]) -> Callable[..., None]:
        @functools.wraps(run)
        def callback(**values: Any) -> None:
            run(record(**values))

        callback.__signature__ = inspect.Signature(parameters, return_annotation=None)  # type: ignore[attr-defined]
        callback.__annotations__ = {p.name: p.annotation for p in parameters}
        return callback

    return decorate
