"""Loading plug-ins: the one importer of ``package.module:NAME`` paths and the one resolver
of names that are not shipped (an installed entry point, else a path), used by
:mod:`priqn.objectives` (objectives, their callables), :mod:`priqn.agents.config` (agents)
and :mod:`priqn.agents.rules` (rule functions). Every failure is one line naming where
the name came from.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterable, Mapping
from typing import Any

from priqn.errors import PriqnError, did_you_mean


def import_path(spec: str, where: str) -> Any:
    """The object ``"package.module:NAME"`` names (one-line errors naming ``where``): the one
    importer of plug-ins by path (objectives, agents, rule functions)."""
    module, sep, attr = str(spec).partition(":")
    if not sep or not module or not attr:
        raise PriqnError(f"{where}: expected 'package.module:NAME', got {spec!r}")
    try:
        obj: Any = importlib.import_module(module)
    except ImportError as exc:
        raise PriqnError(f"{where}: cannot import {module!r} for {spec!r} ({exc})") from None
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise PriqnError(f"{where}: module {module!r} has no {attr!r}")
        obj = getattr(obj, part)
    return obj


def import_plugin(
    name: str,
    shipped: Iterable[str],
    entry_points: Mapping[str, Any],
    where: str,
    what: str,
    listed: str,
    expected: str,
) -> Any:
    """A plug-in that is not shipped: ``package.module:NAME`` (:func:`import_path`) or an
    installed entry point of ``entry_points``, loaded. An unknown name is one line listing
    the ``shipped`` names and the entry points (``"unknown <what> 'x' (<listed>: ...; or
    'package.module:NAME' naming a <expected>)"``); a plug-in that fails to load, one line
    naming it. The one resolver of objectives and agents."""
    if ":" in name:
        return import_path(name, where)
    if name not in entry_points:
        known = [*shipped, *sorted(entry_points)]
        raise PriqnError(
            f"{where}: unknown {what} {name!r} ({listed}: {', '.join(known)}; "
            f"or 'package.module:NAME' naming a {expected})" + did_you_mean(name, known)
        )
    try:
        return entry_points[name].load()
    except Exception as exc:  # a broken plug-in: one line naming it
        raise PriqnError(f"{where}: entry point {name!r} failed to load ({exc})") from None
