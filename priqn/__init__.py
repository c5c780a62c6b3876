"""priqn: preordered distributional RL (Pr-IQN) for autonomous driving in SUMO.

Importing the package registers the gymnasium environment ``priqn/Intersection-v0``;
the environment module itself (and SUMO) is only imported when an env is made.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

import gymnasium

from priqn.objectives import OBJECTIVES

try:  # the one place the version is typed is pyproject.toml
    __version__ = version("priqn")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"
__all__ = ["OBJECTIVES", "__version__"]

if "priqn/Intersection-v0" not in gymnasium.registry:
    gymnasium.register(
        id="priqn/Intersection-v0",
        # IntersectionEnv, fitting make_vec's "sync" / "async" modes to the 5-vector reward.
        entry_point="priqn.env.vector:make_env",
        # gymnasium.make_vec(...) builds worker processes (libsumo: one SUMO per process).
        vector_entry_point="priqn.env.vector:make_vec",
        # The reward is a 5-vector by design; gymnasium's passive checker would warn
        # that it is not a float on every make(). tests/test_env.py runs check_env.
        disable_env_checker=True,
    )
