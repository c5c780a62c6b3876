"""Range checks of numbers several modules take from users, each written once.

A traffic density (``EnvConfig.densities``, ``EvalConfig.densities``, reset options,
``--densities``, ``--density``) is a number in (0, 1]; a near-greedy tolerance
(``EvalConfig.acting_eps``, ``--acting-eps``, ``Policy.near_greedy``) is a number >= 0.
Each check returns the value as a float or raises one line that starts with ``where``
(the field or flag). ``error`` picks the exception: a config's ``__post_init__`` raises
``ValueError`` (``priqn.config.from_dict`` prefixes the file), a flag or an option
:class:`~priqn.errors.PriqnError`.
"""

from __future__ import annotations

import math
from numbers import Real

from priqn.errors import PriqnError

DENSITY_RANGE = "expected values in (0, 1] (traffic density = active actors / maximum actors)"
"""What a density must be, as every density error says it."""
TOLERANCE_RANGE = "expected a tolerance >= 0 (per-state standard deviations), e.g. 0.2"
"""What a near-greedy tolerance must be, as every such error says it."""


def _number(value: object) -> float | None:
    """``value`` as a float if it is a real number (not a bool), else None."""
    if isinstance(value, bool) or not isinstance(value, Real):
        return None
    return float(value)


def check_density(
    value: object, where: str = "density", error: type[Exception] = PriqnError
) -> float:
    """``value`` as a float if it is a traffic density in (0, 1]; else ``error`` in one line
    naming ``where`` (``"densities"``, ``"--density"``, ``"reset options 'density'"``)."""
    d = _number(value)
    if d is None:
        raise error(f"{where}: {value!r} is not a number; {DENSITY_RANGE}")
    if not (0.0 < d <= 1.0 and math.isfinite(d)):
        raise error(f"{where}: {d:g} is out of range; {DENSITY_RANGE}")
    return d


def check_acting_eps(
    value: object, where: str = "acting_eps", error: type[Exception] = PriqnError
) -> float:
    """``value`` as a float if it is a near-greedy tolerance >= 0 (in per-state standard
    deviations of the scalar value's quantiles); else ``error`` in one line naming ``where``
    (``"acting_eps"``, ``"--acting-eps"``, ``"near-greedy ε"``)."""
    eps = _number(value)
    if eps is None:
        raise error(f"{where}: {value!r} is not a number; {TOLERANCE_RANGE}")
    if not (eps >= 0 and math.isfinite(eps)):
        raise error(f"{where}: {eps:g} is out of range; {TOLERANCE_RANGE}")
    return eps
