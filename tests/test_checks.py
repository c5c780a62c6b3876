"""priqn.checks: the one density check and the one near-greedy tolerance check."""

from __future__ import annotations

import numpy as np
import pytest

from priqn.checks import check_acting_eps, check_density
from priqn.errors import PriqnError


@pytest.mark.parametrize("good", [1e-9, 0.5, 1, 1.0, np.float32(0.25), np.float64(1.0)])
def test_a_density_in_the_range_comes_back_as_a_float(good: object) -> None:
    value = check_density(good)
    assert type(value) is float and value == float(good)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("bad", "said"),
    [
        (0.0, "0 is out of range"),
        (-0.5, "-0.5 is out of range"),
        (1.01, "1.01 is out of range"),
        (float("nan"), "nan is out of range"),
        (float("inf"), "inf is out of range"),
        ("0.5", "'0.5' is not a number"),
        (None, "None is not a number"),
        (True, "True is not a number"),
    ],
)
def test_a_bad_density_is_one_line_naming_the_field(bad: object, said: str) -> None:
    expected = f"--densities: {said}; expected values in (0, 1] (traffic density = active "
    with pytest.raises(PriqnError) as exc:
        check_density(bad, "--densities")
    assert str(exc.value).startswith(expected) and "\n" not in str(exc.value)
    with pytest.raises(ValueError, match=r"^densities: .* expected values in \(0, 1\]"):
        check_density(bad, "densities", error=ValueError)


@pytest.mark.parametrize("good", [0, 0.0, 0.2, 3, np.float64(0.005)])
def test_a_tolerance_of_zero_or_more_comes_back_as_a_float(good: object) -> None:
    value = check_acting_eps(good)
    assert type(value) is float and value == float(good)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("bad", "said"),
    [
        (-0.1, "-0.1 is out of range"),
        (float("nan"), "nan is out of range"),
        (float("inf"), "inf is out of range"),
        ("0.2", "'0.2' is not a number"),
        (False, "False is not a number"),
    ],
)
def test_a_bad_tolerance_is_one_line_naming_the_flag(bad: object, said: str) -> None:
    with pytest.raises(PriqnError) as exc:
        check_acting_eps(bad, "--acting-eps")
    assert str(exc.value) == (
        f"--acting-eps: {said}; expected a tolerance >= 0 (per-state standard deviations), e.g. 0.2"
    )
    with pytest.raises(ValueError, match=r"^acting_eps: "):
        check_acting_eps(bad, "acting_eps", error=ValueError)


def test_every_reader_of_a_density_or_a_tolerance_uses_the_one_check() -> None:
    """EnvConfig, EvalConfig, --densities and the near-greedy policy all say it the same way."""
    import argparse

    from priqn.env.config import EnvConfig
    from priqn.evaluation.cli import config_from_args, configure_parser
    from priqn.evaluation.protocol import EvalConfig

    with pytest.raises(ValueError, match=r"^densities: 1.5 is out of range; expected values"):
        EnvConfig(densities=(0.5, 1.5))
    with pytest.raises(ValueError, match=r"^densities: 0 is out of range; expected values"):
        EvalConfig(densities=(0.0,))
    with pytest.raises(ValueError, match=r"^acting_eps: -1 is out of range; expected a tol"):
        EvalConfig(acting_eps=-1.0)
    parser = argparse.ArgumentParser()
    configure_parser(parser)
    with pytest.raises(PriqnError, match=r"^--densities: 2 is out of range; expected values"):
        config_from_args(parser.parse_args(["r", "--densities", "0.5,2"]))
