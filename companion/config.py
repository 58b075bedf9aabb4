"""Strict loading of frozen dataclasses from TOML tables.

One mechanism for every config file (vehicle, mission, controller gains): unknown keys, missing required
keys, wrong types and non-physical values are refused with a :class:`ConfigError` that names the file and
the key, e.g. ``config/vehicle.toml: [vehicle] m: must be > 0, got -1.0``.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import math
import tomllib
import types
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

from companion.errors import ConfigError

T = TypeVar("T")

#: The package that holds the shipped config files (the repository's ``config/`` folder, see pyproject.toml).
CONFIG_PACKAGE = "companion.configs"


def shipped_config(relative: str) -> Path:
    """Path of a shipped config file, e.g. ``shipped_config("missions/forest.toml")``.

    Read with importlib.resources, so it works from a source tree, an editable install and a wheel alike.
    """
    return Path(str(importlib.resources.files(CONFIG_PACKAGE).joinpath(relative)))


def shipped_files(folder: str, suffix: str = ".toml") -> dict[str, Path]:
    """The shipped files of a config folder (``missions``, ``worlds``), by name (file stem), sorted."""
    root = importlib.resources.files(CONFIG_PACKAGE).joinpath(folder)
    return {Path(e.name).stem: Path(str(e)) for e in sorted(root.iterdir(), key=lambda e: e.name)
            if e.name.endswith(suffix)}


def resolve_shipped(arg: str | Path, folder: str, kind: str, hint: str = "") -> Path:
    """A file argument: an existing file wins, else a shipped one of ``folder`` by name (``forest``,
    ``forest.toml``); :class:`ConfigError` naming the shipped ones otherwise (``kind``: "mission", "world")."""
    p = Path(arg)
    if p.is_file():
        return p
    shipped = shipped_files(folder)
    name = p.stem if p.suffix == ".toml" and p.parent == Path(".") else str(arg)
    if name in shipped:
        return shipped[name]
    raise ConfigError(f"{arg}: no such {kind} file, and no shipped {kind} of that name (shipped: "
                      f"{', '.join(shipped)}{hint})")


def shipped_missions() -> dict[str, Path]:
    """The missions that ship with slungpilot, by name (file stem): ``{"forest": Path, "group1": Path, ...}``."""
    return shipped_files("missions")


def resolve_obstacles(arg: str | Path) -> Path:
    """An obstacle file argument: an existing path wins, else a shipped one by name (``trunk`` →
    ``config/obstacles/trunk.json``); :class:`ConfigError` naming the shipped ones otherwise."""
    p = Path(arg)
    if p.exists():
        return p
    folder = importlib.resources.files(CONFIG_PACKAGE).joinpath("obstacles")
    shipped = {Path(e.name).stem: Path(str(e)) for e in folder.iterdir() if e.name.endswith(".json")}
    if p.stem in shipped and p.parent == Path("."):
        return shipped[p.stem]
    raise ConfigError(f"{arg}: file not found, and no shipped obstacle file of that name (shipped: "
                      f"{', '.join(shipped)})")


def resolve_mission(arg: str | Path) -> Path:
    """A mission argument as a file: an existing path wins, else a shipped mission by name (``forest``,
    ``group1.toml``); :class:`ConfigError` naming the known missions otherwise."""
    return resolve_shipped(arg, "missions", "mission", "; `slungpilot missions` lists them")


def read_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file, turning I/O and syntax errors into :class:`ConfigError`."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{p}: file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read: {exc}") from None


def _type_ok(value: Any, hint: Any) -> tuple[bool, Any]:
    """Check ``value`` against a simple type hint; return (ok, coerced value).

    Supports float (ints accepted and converted), int, bool, str, tuple[float, ...] / tuple[float, float, float],
    and ``X | None``.
    """
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(hint)
        if value is None and type(None) in args:
            return True, None
        for a in args:
            if a is type(None):
                continue
            ok, v = _type_ok(value, a)
            if ok:
                return True, v
        return False, value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            return False, value
        return True, float(value)
    if hint is int:
        return (isinstance(value, int) and not isinstance(value, bool)), value
    if hint is bool:
        return isinstance(value, bool), value
    if hint is str:
        return isinstance(value, str), value
    if origin is tuple:
        args = typing.get_args(hint)
        if not isinstance(value, list | tuple):
            return False, value
        if len(args) == 2 and args[1] is Ellipsis:
            elem_hints = [args[0]] * len(value)
        else:
            if len(value) != len(args):
                return False, value
            elem_hints = list(args)
        out = []
        for v, h in zip(value, elem_hints, strict=True):
            ok, cv = _type_ok(v, h)
            if not ok:
                return False, value
            out.append(cv)
        return True, tuple(out)
    return True, value


def dataclass_from_table(
    cls: type[T],
    table: Mapping[str, Any],
    *,
    where: str,
    base: T | None = None,
) -> T:
    """Build frozen dataclass ``cls`` from a TOML table.

    ``where`` names the place for error messages (``"config/vehicle.toml: [vehicle]"``). Fields missing from
    the table take their value from ``base`` if given, else the dataclass default; a field with neither is
    required. After construction the dataclass's ``validate()`` method (if any) is called and any
    ``ValueError`` it raises is reported as ``where key: message`` (the message starts with the key).
    """
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where}: expected a table, got {type(table).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    hints = typing.get_type_hints(cls)
    unknown = sorted(set(table) - set(fields))
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r} (known keys: {', '.join(sorted(fields))})")
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        if name in table:
            ok, v = _type_ok(table[name], hints[name])
            if not ok:
                raise ConfigError(
                    f"{where} {name}: expected {_hint_name(hints[name])}, got {table[name]!r}"
                )
            if isinstance(v, float) and not math.isfinite(v):
                raise ConfigError(f"{where} {name}: must be finite, got {v!r}")
            kwargs[name] = v
        elif base is not None:
            kwargs[name] = getattr(base, name)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{where}: missing required key {name!r}")
    try:
        obj = cls(**kwargs)
        validate: Callable[[], None] | None = getattr(obj, "validate", None)
        if validate is not None:
            validate()
    except ValueError as exc:
        raise ConfigError(f"{where} {exc}") from None
    return obj


def _hint_name(hint: Any) -> str:
    return getattr(hint, "__name__", None) or str(hint).replace("typing.", "")
