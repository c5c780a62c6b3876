"""Typed configuration: TOML files, typed values and ``--set key=value`` overrides into dataclasses.

Every config in priqn is a (nested) dataclass whose fields carry a docstring on the
line below them. This module turns plain dicts (from TOML or the CLI) into those
dataclasses and sets typed ``(dotted key, value)`` pairs on them (:func:`apply_values`;
a ``--set`` string is parsed once on its way in), rejecting unknown keys and wrong types
with one line that names the file and field, and turns them back into dicts for the
resolved config a run folder records.
"""

from __future__ import annotations

import ast
import dataclasses
import datetime
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

from priqn.errors import PriqnError, did_you_mean

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
    """A value as TOML text (``toml_value(["a", 1])`` is ``["a", 1]``): what a
    ``--set KEY=VALUE`` string carries, parsed back to an equal value. Only for text another
    program reads: the ``overrides`` a cell's spec keeps for a child at an older commit
    (:meth:`priqn.sweep.cells.Cell.to_spec`); in priqn itself values stay typed
    (:func:`apply_values`)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):  # a TOML basic string; DEL is the one character JSON leaves raw
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        items = (f"{toml_value(str(k))} = {toml_value(v)}" for k, v in value.items())
        return "{" + ", ".join(items) + "}"
    if isinstance(value, (datetime.date, datetime.time)):
        return value.isoformat()
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
    upgrade = getattr(cls, UPGRADE_HOOK, None)
    if upgrade is not None:  # a table recorded in an older form, as the current one
        data = upgrade(data)
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise PriqnError(
            f"{where}: unknown key {unknown[0]!r} (valid: {', '.join(sorted(fields))})"
            + did_you_mean(unknown[0], fields)
        )
    kwargs = {}
    for name, value in data.items():
        tp, label = hints[name], field_label(where, name)
        if dataclasses.is_dataclass(tp) and not (
            isinstance(value, Mapping) or dataclasses.is_dataclass(value)
        ):
            hint = fields[name].metadata.get(NAMED_HINT)
            raise PriqnError(
                f"{label}: expected a table of {name}.* fields, got {value!r}"
                + (f"; {hint.format(value=value)}" if hint else "")
            )
        kwargs[name] = _coerce(value, tp, label)
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
        raise PriqnError(_check_message(where, str(exc), fields)) from exc


def _check_message(where: str, text: str, fields: Iterable[str]) -> str:
    """A dataclass's own check ``text`` (``"family: unknown pool ..."``) as one line
    naming ``where``; after a flag, one that begins with a field's name is named as that
    field (``--set env.family: unknown pool ...``, not ``--set env: family: ...``)."""
    name, sep, rest = text.partition(":")
    if sep and where.startswith("-") and name in set(fields):
        return f"{field_label(where, name)}:{rest}"
    return f"{where}: {text}"


UPGRADE_HOOK = "upgrade_table"
"""Name of the classmethod a config dataclass may have that turns a table of an older
recorded form into the current one (``TrafficBehaviour``: a run folder's flat ``path_*``
keys); :func:`from_dict` calls it first, so old run folders load as they were."""

MOVED_KEYS = "MOVED_KEYS"
"""Name of the class attribute (``{old key: new key}``, relative to the class) of a config
dataclass whose keys moved: a ``--set`` of an old key is a one-line error naming the new one."""

NAMED_HINT = "named_hint"
"""Field metadata key: on a table field that a named setting fills (``EnvConfig.traffic``:
``--traffic NAME``), the hint an error adds when the field is given a bare value instead
(``{value}`` is that value)."""


def field_label(where: str, name: str) -> str:
    """How an error names field ``name`` of the table ``where``: ``--set learner.lr``
    after a flag, ``train_paper.toml.learner.lr`` after a file, ``name`` alone without
    ``where``."""
    if not where:
        return name
    if where.startswith("-") and " " not in where:  # a flag: '--set' -> '--set learner'
        return f"{where} {name}"
    return f"{where}.{name}"


ConfigValues = Mapping[str, Any] | Iterable[tuple[str, Any]]
"""Typed config values: ``(dotted key, value)`` pairs in the order they apply
(``("agent.eps", 0.2)``, ``("checkpoint.keep_at", (60000,))``), or a mapping of them."""


def value_pairs(values: ConfigValues) -> tuple[tuple[str, Any], ...]:
    """``values`` as ``(dotted key, value)`` pairs in order, every list a tuple (a tuple
    written as JSON comes back as a list: the pairs of both are equal)."""
    items = values.items() if isinstance(values, Mapping) else values
    return tuple((key, _frozen(value)) for key, value in map(_pair, items))


def parse_override(item: str, where: str = "--set") -> tuple[str, Any]:
    """One ``KEY=VALUE`` string as ``(key, value)``: VALUE parsed once as TOML (a bare word
    is a string: ``agent=pr-iqn``); no ``=`` is a one-line error naming ``item``."""
    if "=" not in item:
        raise PriqnError(f"{where} {item!r}: expected KEY=VALUE, e.g. learner.lr=1e-4")
    key, raw = item.split("=", 1)
    return key.strip(), _parse_value(raw.strip())


def apply_values(
    cfg: T, values: ConfigValues | Iterable[tuple[str, Any] | str], where: str = "--set"
) -> T:
    """A copy of ``cfg`` with ``values`` set in order, checked together by :func:`from_dict`.

    Each item is a typed ``(dotted key, value)`` pair, or a ``KEY=VALUE`` string (a
    ``--set`` override: VALUE parsed once, :func:`parse_override`; its errors name it).
    A key that is not a field is a one-line error naming ``where`` and the valid keys at
    that level: ``--set 'learner.lrr=1': unknown key 'learner.lrr' (valid here: ...)``.
    """
    if isinstance(values, str):
        raise PriqnError(f"{where}: expected a list of values, got the string {values!r}")
    data = to_dict(cfg)
    for item in values.items() if isinstance(values, Mapping) else values:
        if isinstance(item, str):
            key, value = parse_override(item, where)
            _set_value(data, key, value, f"{where} {item!r}", type(cfg))
        else:
            key, value = _pair(item, where)
            _set_value(data, key, value, where, type(cfg))
    return from_dict(type(cfg), data, where)


def apply_overrides(cfg: T, overrides: Sequence[str], where: str = "--set") -> T:
    """A copy of ``cfg`` with ``key.sub=value`` overrides, each VALUE parsed once as TOML
    (:func:`apply_values` with strings only)."""
    return apply_values(cfg, list(overrides), where)


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
        table = _dataclass_of(tp)
        if table is not None:  # an optional table (None = off): its keys when given
            rows.extend(describe(table, key + "."))
    return rows


# --------------------------------------------------------------------------- internals


def _parse_value(raw: str) -> Any:
    try:
        return tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        return raw  # a bare word is a string: agent=pr-iqn


def _pair(item: Any, where: str = "config values") -> tuple[str, Any]:
    """``item`` as ``(dotted key, value)``; anything else is a one-line error."""
    if not (isinstance(item, (list, tuple)) and len(item) == 2 and isinstance(item[0], str)):
        raise PriqnError(f"{where}: expected (KEY, VALUE) pairs, got {item!r}")
    return item[0], item[1]


def _set_value(data: dict[str, Any], key: str, value: Any, where: str, cls: Any = None) -> None:
    """Set ``data[a][b] = value`` for the dotted ``key`` ``a.b``; an unknown key is one line
    (naming its new place where ``cls``, the dataclass ``data`` is of, says it moved)."""
    moved = _moved_key(cls, key)
    if moved is not None:
        raise PriqnError(f"{where}: {key!r} is now {moved!r}")
    node = data
    parts = key.split(".")
    for i, part in enumerate(parts[:-1]):
        if node.get(part) is True and _table_at(cls, parts[: i + 1]) is not None:
            node[part] = {}  # an optional table given as true: its defaults
        if not isinstance(node.get(part), dict):
            if part in node and (node[part] is None or isinstance(node[part], bool)):
                table = ".".join(parts[: i + 1])  # an optional table, off or a shorthand
                state = "off" if node[part] in (None, False) else toml_value(node[part])
                raise PriqnError(
                    f"{where}: {table!r} is {state}; to set {key!r} give it a table first "
                    f"({table}={{}}: its defaults)"
                )
            tables = [k for k, v in node.items() if isinstance(v, dict)]
            raise PriqnError(f"{where}: {key!r} is not a config field{did_you_mean(part, tables)}")
        node = node[part]
    valid = set(node) | _fields_at(cls, parts[:-1])
    if parts[-1] not in valid:
        prefix = key[: -len(parts[-1])]  # the last name alone is matched: not the table's
        near = did_you_mean(parts[-1], sorted(valid), prefix)
        raise PriqnError(
            f"{where}: unknown key {key!r} (valid here: {', '.join(sorted(valid))}){near}"
        )
    node[parts[-1]] = value


def _dataclass_of(tp: Any) -> Any:
    """The dataclass of a field type: ``tp`` itself, or X of ``X | None``; else None."""
    if dataclasses.is_dataclass(tp):
        return tp
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        options = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(options) == 1 and dataclasses.is_dataclass(options[0]):
            return options[0]
    return None


def _table_at(cls: Any, parts: Sequence[str]) -> Any:
    """The dataclass of the table at dotted ``parts`` of dataclass ``cls``; None if unknown."""
    tp = _dataclass_of(cls)
    for part in parts:
        tp = _dataclass_of(typing.get_type_hints(tp).get(part)) if tp is not None else None
    return tp


def _fields_at(cls: Any, parts: Sequence[str]) -> set[str]:
    """The field names of the table at dotted ``parts`` of dataclass ``cls`` (none unknown):
    a table given as ``{}`` (its defaults) takes its keys one by one."""
    tp = _table_at(cls, parts)
    return {f.name for f in dataclasses.fields(tp)} if tp is not None else set()


def _moved_key(cls: Any, key: str) -> str | None:
    """Where the dotted ``key`` of dataclass ``cls`` is now, if a class on its way declares
    it moved (:data:`MOVED_KEYS`); else None."""
    parts = key.split(".")
    tp = cls
    for i, part in enumerate(parts):
        tp = _dataclass_of(tp)
        if tp is None:
            return None
        new = getattr(tp, MOVED_KEYS, {}).get(".".join(parts[i:]))
        if new is not None:
            return ".".join([*parts[:i], new])
        tp = typing.get_type_hints(tp).get(part)
    return None


def _frozen(value: Any) -> Any:
    """Lists (and tuples) as tuples, all the way down; tables keep their keys."""
    if isinstance(value, (list, tuple)):
        return tuple(_frozen(v) for v in value)
    if isinstance(value, Mapping):
        return {str(k): _frozen(v) for k, v in value.items()}
    return value


def _drop_none(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {k: _drop_none(v) for k, v in obj.items() if v is not None}
    if isinstance(obj, list):
        return [_drop_none(v) for v in obj]
    return obj


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _coerce(value: Any, tp: Any, where: str) -> Any:
    """``value`` (parsed TOML, or already typed) checked against, and converted to, the
    field type ``tp``; a mismatch is one line naming ``where``."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        return _coerce_union(value, args, where)
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
        return _coerce_sequence(value, tp, where)
    if origin is dict or tp is dict:
        if not isinstance(value, Mapping):
            raise PriqnError(f"{where}: expected a table, got {value!r}")
        vt = args[1] if len(args) == 2 else Any
        return {str(k): _coerce(v, vt, f"{where}.{k}") for k, v in value.items()}
    return _coerce_scalar(value, tp, where)


def _coerce_union(value: Any, args: tuple[Any, ...], where: str) -> Any:
    """``value`` as the first of the union's types ``args`` that takes it (None where
    the union allows it); ``Optional[X]`` reports X's own, more precise error."""
    if value is None and type(None) in args:
        return None
    options = [a for a in args if a is not type(None)]
    if len(options) == 1:  # Optional[X]: X's own error is the precise one
        return _coerce(value, options[0], where)
    for arg in options:
        try:
            return _coerce(value, arg, where)
        except PriqnError:
            continue
    names = " or ".join(_type_name(a) for a in options)
    raise PriqnError(f"{where}: expected {names}, got {value!r}")


def _coerce_sequence(value: Any, tp: Any, where: str) -> Any:
    """A TOML array as ``tuple[X, ...]``, a fixed ``tuple[X, Y]``, ``list[X]`` or
    ``Sequence[X]`` (a tuple unless ``tp`` is a list), each item coerced."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if not isinstance(value, (list, tuple)):
        raise PriqnError(f"{where}: expected a list, got {value!r}")
    if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
        items = [_coerce(v, args[0], f"{where}[{i}]") for i, v in enumerate(value)]
    elif origin is tuple and args:
        if len(args) != len(value):
            raise PriqnError(f"{where}: expected {len(args)} values, got {len(value)}")
        items = [
            _coerce(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args, strict=True))
        ]
    else:
        sub = args[0] if args else Any
        items = [_coerce(v, sub, f"{where}[{i}]") for i, v in enumerate(value)]
    return list(items) if origin is list or tp is list else tuple(items)


def _coerce_scalar(value: Any, tp: Any, where: str) -> Any:
    """``bool``, ``int``, ``float`` (an integer is taken), ``str`` or ``Path``: ``value``
    checked (a bool is no number); any other type passes ``value`` through."""
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
