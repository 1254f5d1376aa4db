"""Training configurations in and out: dicts, JSON/TOML files, command-line overrides.

Layers, later ones winning (:func:`build_config`): a named recipe, a config file, command-line
flags, then ``--set section.field=value``. Every value is checked against its field's type,
naming the field in the error. ``config.json`` reloads to the same object
(:func:`config_from_dict`).
"""

from __future__ import annotations

import dataclasses
import json
import tomllib
import types
import typing
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from lidarflow.errors import TrainError
from lidarflow.models.config import ModelSpec
from lidarflow.train.config import TrainConfig
from lidarflow.train.recipes import recipe

__all__ = [
    "apply_overrides",
    "build_config",
    "config_from_dict",
    "config_to_dict",
    "load_config_file",
]

#: Settings removed (measured without gain), with the value that left them off: a config giving
#: that value still reads; one turning a setting on is refused.
REMOVED_SETTINGS: dict[tuple[str, str], Any] = {("data", "slower_copies"): []}


def config_to_dict(config: TrainConfig) -> dict[str, Any]:
    return dataclasses.asdict(config)


def _coerce(value: Any, hint: Any, where: str) -> Any:
    """``value`` (from JSON/TOML/CLI) checked and converted to the type ``hint``."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(hint)
        if value is None and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return _coerce(value, inner, where)
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, dict):
            raise TrainError(f"config {where}: expected a table of settings, got {value!r}")
        return _from_dict(hint, value, where)
    if origin in (tuple, list):  # tuple[X, ...] too: a list in JSON, TOML and on the command line
        inner = typing.get_args(hint)[0]
        if isinstance(value, str | int | float) and not isinstance(value, bool):
            value = [value]
        if not isinstance(value, list | tuple):
            raise TrainError(f"config {where}: expected a list, got {value!r}")
        return origin(_coerce(v, inner, f"{where}[{i}]") for i, v in enumerate(value))
    if origin is dict:
        if not isinstance(value, dict):
            raise TrainError(f"config {where}: expected a table, got {value!r}")
        return dict(value)
    if hint is bool:
        if isinstance(value, bool):
            return value
    elif hint is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif hint is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
    elif hint is str:
        if isinstance(value, str):
            return value
    elif hint is Any:
        return value
    raise TrainError(f"config {where}: expected {getattr(hint, '__name__', hint)}, got {value!r}")


def _from_dict(cls: type, data: dict[str, Any], where: str = "") -> Any:
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise TrainError(
            f"config {where or 'top level'}: unknown setting(s) {', '.join(unknown)}; "
            f"known: {', '.join(sorted(names))}"
        )
    kwargs = {k: _coerce(v, hints[k], f"{where}.{k}".lstrip(".")) for k, v in data.items()}
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as err:
        raise TrainError(f"config {where or 'top level'}: {err}") from err


def _merge(base: Any, data: dict[str, Any], where: str = "") -> Any:
    """A copy of dataclass ``base`` with the (possibly partial, nested) settings of ``data``."""
    if isinstance(base, TrainConfig):
        data = _without_removed(_flat_model_read(base, data))
    hints = typing.get_type_hints(type(base))
    names = {f.name for f in dataclasses.fields(base)}
    changes: dict[str, Any] = {}
    for key, value in data.items():
        path = f"{where}.{key}".lstrip(".")
        if key not in names:
            raise TrainError(
                f"config: unknown setting {path!r}; known here: {', '.join(sorted(names))}"
            )
        current = getattr(base, key)
        if dataclasses.is_dataclass(current) and isinstance(value, dict):
            changes[key] = _merge(current, value, path)
        else:
            changes[key] = _coerce(value, hints[key], path)
    try:
        return dataclasses.replace(base, **changes)
    except (TypeError, ValueError) as err:  # a section's own checks (e.g. LossConfig's)
        raise TrainError(f"config {where or 'top level'}: {err}") from err


def _without_removed(data: dict[str, Any]) -> dict[str, Any]:
    """``data`` without the :data:`REMOVED_SETTINGS` it gives at their off value."""
    out = dict(data)
    for (section, key), off in REMOVED_SETTINGS.items():
        table = out.get(section)
        if not isinstance(table, dict) or key not in table:
            continue
        if table[key] != off:
            raise TrainError(
                f"config {section}.{key} was measured without gain and removed "
                "(docs/research/options_without_gain); drop it from the config"
            )
        out[section] = {k: v for k, v in table.items() if k != key}
    return out


def _flat_model_read(base: TrainConfig, data: dict[str, Any]) -> dict[str, Any]:
    """``data`` with a flat ``model.kwargs`` table (the whole model in ``build_model``'s keyword
    form, decision keys included) read as the typed model settings and ``decision`` section."""
    model = data.get("model")
    if not isinstance(model, dict) or "kwargs" not in model:
        return data
    model = dict(model)
    kwargs = model.pop("kwargs") or {}
    if not isinstance(kwargs, dict):
        raise TrainError(f"config model.kwargs: expected a table, got {kwargs!r}")
    name = str(model.get("name", base.model.name))
    try:
        spec, decision = ModelSpec.from_kwargs(name, kwargs)
    except (TypeError, ValueError) as err:
        raise TrainError(f"config model.kwargs: {err}") from err
    model.update(
        flow=None if spec.flow is None else dataclasses.asdict(spec.flow),
        head=None if spec.head is None else dataclasses.asdict(spec.head),
        ego_motion=spec.ego_motion,
        poses_optional=spec.poses_optional,
        options=spec.options,
    )
    out = {**data, "model": model}
    if decision:
        section = dict(data.get("decision") or {})
        if "decision_offset" in decision:
            section["offset"] = decision["decision_offset"]
        if "online_decision" in decision:
            section["online"] = decision["online_decision"]
        out["decision"] = section
    return out


def config_from_dict(data: dict[str, Any]) -> TrainConfig:
    """Inverse of :func:`config_to_dict`: missing settings keep the named recipe's values."""
    base = recipe(str(data.get("recipe", "paper")))
    return _merge(base, data)


def load_config_file(path: str | Path) -> dict[str, Any]:
    """Read settings from a ``.json`` or ``.toml`` file (partial settings are fine)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise TrainError(f"{path}: cannot read the config file ({err})") from err
    except UnicodeDecodeError as err:  # a recording or weights file given by mistake
        raise TrainError(f"{path}: not a config file (not text: {err.reason})") from err
    toml = path.suffix.lower() == ".toml"  # anything else is read as JSON: say so, not ".txt"
    try:
        data = tomllib.loads(text) if toml else json.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as err:
        raise TrainError(f"{path}: not valid {'TOML' if toml else 'JSON'} ({err})") from err
    if not isinstance(data, dict):
        raise TrainError(f"{path}: a config file must hold a table of settings")
    return data


def _parse_value(text: str) -> Any:
    """CLI value: JSON where it parses (numbers, true/false, null, lists), else a string."""
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        if "," in text:
            return [_parse_value(part.strip()) for part in text.split(",")]
        return text


def apply_overrides(config: TrainConfig, overrides: Iterable[str]) -> TrainConfig:
    """Apply ``section.field=value`` strings, e.g. ``optim.lr=0.003``, ``loss.smoothness=0.1``,
    ``data.mix=0.7,0.3``, ``data.topic=null``."""
    for item in overrides:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise TrainError(f"--set expects section.field=value, got {item!r}")
        config = _merge(config, _nested(key.strip(), _parse_value(text.strip())))
    return config


def _nested(key: str, value: Any) -> dict[str, Any]:
    """``"a.b.c", v`` -> ``{"a": {"b": {"c": v}}}``."""
    for part in reversed(key.split(".")):
        value = {part: value}
    return value


def build_config(
    recipe_name: str | None = None,
    file: str | Path | None = None,
    flags: dict[str, Any] | None = None,
    overrides: Iterable[str] = (),
) -> TrainConfig:
    """Layer a config: recipe, then file, then ``flags`` (``{"optim.lr": 0.003}``; ``None``
    values are ignored), then ``--set`` overrides. A ``recipe`` argument beats the file's."""
    data = load_config_file(file) if file is not None else {}
    name = recipe_name or str(data.get("recipe", "paper"))
    config = _merge(recipe(name), {**data, "recipe": name})
    for key, value in (flags or {}).items():
        if value is not None:
            config = _merge(config, _nested(key, value))
    return apply_overrides(config, overrides).validate()
