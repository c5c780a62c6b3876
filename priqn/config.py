"""Typed configuration: TOML files and ``--set key=value`` overrides into dataclasses.

Every config in priqn is a (nested) dataclass whose fields carry a docstring on the
line below them. This module turns plain dicts (from TOML or the CLI) into those
dataclasses, rejecting unknown keys and wrong types with one line that names the
file and field, and back into dicts for the resolved config a run folder records.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import itertools
import json
import textwrap
import tomllib
import types
import typing
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import tomli_w

from priqn.errors import PriqnError

T = TypeVar("T")


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML file; a missing or malformed file is a one-line :class:`PriqnError`."""
    p = Path(path)
    if not p.is_file():
        raise PriqnError(f"{p}: file not found")
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise PriqnError(f"{p}: malformed TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise PriqnError(f"{p}: not a UTF-8 text file") from exc


def dumps_toml(data: Mapping[str, Any]) -> str:
    """Serialise a dict (e.g. from :func:`to_dict`) as TOML; ``None`` values are omitted."""
    return tomli_w.dumps(_drop_none(data))


def toml_value(value: Any) -> str:
    """A scalar or list as the TOML text a ``--set KEY=VALUE`` override takes."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    return repr(value)


def to_dict(obj: Any) -> Any:
    """Dataclass → plain dict/list/scalars (tuples become lists, Paths strings)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, Mapping):
        return {str(k): to_dict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    return obj


def from_dict(cls: type[T], data: Mapping[str, Any], where: str) -> T:
    """Build dataclass ``cls`` from ``data``; ``where`` names the source in errors.

    Unknown keys, wrong types and missing required fields raise :class:`PriqnError`
    such as ``scenarios/x.toml [traffic]: unknown key 'max_actor' (valid: ...)``.
    """
    if not isinstance(data, Mapping):
        raise PriqnError(f"{where}: expected a table, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise PriqnError(
            f"{where}: unknown key {unknown[0]!r} (valid: {', '.join(sorted(fields))})"
        )
    kwargs = {}
    for name, value in data.items():
        kwargs[name] = _coerce(value, hints[name], f"{where}.{name}" if where else name)
    missing = [
        n
        for n, f in fields.items()
        if n not in kwargs
        and f.default is dataclasses.MISSING
        and f.default_factory is dataclasses.MISSING
    ]
    if missing:
        raise PriqnError(f"{where}: missing required key {missing[0]!r}")
    try:
        return cls(**kwargs)
    except (ValueError, TypeError) as exc:
        if isinstance(exc, PriqnError):
            raise
        raise PriqnError(f"{where}: {exc}") from exc


def apply_overrides(cfg: T, overrides: Sequence[str], where: str = "--set") -> T:
    """Return a copy of ``cfg`` with ``key.sub=value`` overrides (values parsed as TOML)."""
    data = to_dict(cfg)
    for item in overrides:
        if "=" not in item:
            raise PriqnError(f"{where} {item!r}: expected KEY=VALUE, e.g. learner.lr=1e-4")
        key, raw = item.split("=", 1)
        value = _parse_value(raw.strip())
        node = data
        parts = key.strip().split(".")
        for part in parts[:-1]:
            if not isinstance(node.get(part), dict):
                raise PriqnError(f"{where} {item!r}: {key!r} is not a config field")
            node = node[part]
        if parts[-1] not in node:
            valid = ", ".join(sorted(node))
            raise PriqnError(f"{where} {item!r}: unknown key {key!r} (valid here: {valid})")
        node[parts[-1]] = value
    return from_dict(type(cfg), data, where)


def field_docs(cls: type) -> dict[str, str]:
    """Field name → the docstring written on the line(s) under that field."""
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    body = ast.parse(source).body[0]
    docs: dict[str, str] = {}
    stmts = getattr(body, "body", [])
    for stmt, nxt in itertools.pairwise(stmts):
        if (
            isinstance(stmt, ast.AnnAssign)
            and isinstance(stmt.target, ast.Name)
            and isinstance(nxt, ast.Expr)
            and isinstance(nxt.value, ast.Constant)
            and isinstance(nxt.value.value, str)
        ):
            docs[stmt.target.id] = " ".join(nxt.value.value.split())
    return docs


def describe(cls: type, prefix: str = "") -> list[tuple[str, str, str]]:
    """Rows (key, default, doc) for every field, nested dataclasses flattened."""
    rows = []
    docs = field_docs(cls)
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        key = f"{prefix}{f.name}"
        tp = hints[f.name]
        if dataclasses.is_dataclass(tp):
            rows.extend(describe(tp, key + "."))
            continue
        if f.default is not dataclasses.MISSING:
            default = repr(to_dict(f.default))
        elif f.default_factory is not dataclasses.MISSING:
            default = repr(to_dict(f.default_factory()))
        else:
            default = "(required)"
        rows.append((key, default, docs.get(f.name, "")))
    return rows


# --------------------------------------------------------------------------- internals


def _parse_value(raw: str) -> Any:
    try:
        return tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        return raw  # a bare word is a string: agent=pr-iqn


def _drop_none(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {k: _drop_none(v) for k, v in obj.items() if v is not None}
    if isinstance(obj, list):
        return [_drop_none(v) for v in obj]
    return obj


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _coerce(value: Any, tp: Any, where: str) -> Any:  # noqa: C901 - one switch over kinds
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        if len(options) == 1:  # Optional[X]: X's own error is the precise one
            return _coerce(value, options[0], where)
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, where)
            except PriqnError as exc:
                errors.append(str(exc))
        names = " or ".join(_type_name(a) for a in args if a is not type(None))
        raise PriqnError(f"{where}: expected {names}, got {value!r}")
    if origin is typing.Literal:
        if value not in args:
            raise PriqnError(
                f"{where}: expected one of {', '.join(map(repr, args))}, got {value!r}"
            )
        return value
    if dataclasses.is_dataclass(tp):
        if dataclasses.is_dataclass(value):
            return value
        return from_dict(tp, value, where)
    if origin in (tuple, list, Sequence) or tp in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise PriqnError(f"{where}: expected a list, got {value!r}")
        if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
            items = [_coerce(v, args[0], f"{where}[{i}]") for i, v in enumerate(value)]
        elif origin is tuple and args:
            if len(args) != len(value):
                raise PriqnError(f"{where}: expected {len(args)} values, got {len(value)}")
            items = [
                _coerce(v, a, f"{where}[{i}]")
                for i, (v, a) in enumerate(zip(value, args, strict=True))
            ]
        else:
            sub = args[0] if args else Any
            items = [_coerce(v, sub, f"{where}[{i}]") for i, v in enumerate(value)]
        return list(items) if origin is list or tp is list else tuple(items)
    if origin is dict or tp is dict:
        if not isinstance(value, Mapping):
            raise PriqnError(f"{where}: expected a table, got {value!r}")
        vt = args[1] if len(args) == 2 else Any
        return {str(k): _coerce(v, vt, f"{where}.{k}") for k, v in value.items()}
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise PriqnError(f"{where}: expected true or false, got {value!r}")
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise PriqnError(f"{where}: expected an integer, got {value!r}")
    if tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise PriqnError(f"{where}: expected a number, got {value!r}")
    if tp is str:
        if isinstance(value, str):
            return value
        raise PriqnError(f"{where}: expected a string, got {value!r}")
    if tp is Path:
        if isinstance(value, (str, Path)):
            return Path(value)
        raise PriqnError(f"{where}: expected a path string, got {value!r}")
    return value


def flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dict → ``{"a.b": value}``."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, Mapping):
            out.update(flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def config_differences(
    old: Mapping[str, Any], new: Mapping[str, Any], ignore: Iterable[str] = ()
) -> list[tuple[str, Any, Any]]:
    """``(dotted key, old value, new value)`` for every key that differs, sorted by key.

    The one config comparison of priqn: ``--resume`` (a run's config.toml against the
    flags), ``priqn sweep`` (a cell's recorded config against the grid) and
    ``priqn evaluate`` (an evaluation's recorded settings against the new ones).
    Nested tables compare key by key (``env.family``); ``ignore`` names dotted keys.
    """
    fa, fb = flatten(old), flatten(new)
    skip = set(ignore)
    return [
        (k, fa.get(k), fb.get(k))
        for k in sorted(set(fa) | set(fb))
        if k not in skip and fa.get(k) != fb.get(k)
    ]
