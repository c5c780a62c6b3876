"""User-facing errors.

Anything the user can cause (bad file, bad flag, missing net, ...) raises
:class:`PriqnError` with ONE line that names the file/field and what is expected.
The CLI prints it as ``priqn: error: <message>`` and exits with status 2, never a
traceback. Internal bugs stay ordinary exceptions.
"""

from __future__ import annotations


class PriqnError(Exception):
    """A one-line, user-facing error: say what is wrong and what is expected."""

    def __init__(self, message: str) -> None:
        # Keep it one line even if a caller formats a multi-line cause into it.
        super().__init__(" ".join(str(message).split()))
