"""User-facing errors.

Anything the user can cause (bad file, bad flag, missing net, ...) raises
:class:`PriqnError` with ONE line that names the file/field and what is expected.
The CLI prints it as ``priqn: error: <message>`` and exits with status 2, never a
traceback. Internal bugs stay ordinary exceptions.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable


class PriqnError(Exception):
    """A one-line, user-facing error: say what is wrong and what is expected."""

    def __init__(self, message: str) -> None:
        # Keep it one line even if a caller formats a multi-line cause into it.
        super().__init__(" ".join(str(message).split()))


def did_you_mean(name: object, valid: Iterable[str], prefix: str = "") -> str:
    """``"; did you mean 'x'?"`` naming the one of ``valid`` closest to a mistyped
    ``name`` (:func:`difflib.get_close_matches`), or ``""`` when none is close: the end
    of an unknown-name error that lists the valid ones
    (``unknown preset 'papr' (valid: default, paper, ...); did you mean 'paper'?``).
    ``prefix`` goes before the name suggested, not into the match (a dotted config key:
    ``learner.`` + ``lr``)."""
    close = difflib.get_close_matches(str(name), [str(v) for v in valid], n=1)
    return f"; did you mean {prefix + close[0]!r}?" if close else ""
