"""priqn: preordered distributional RL (Pr-IQN) for autonomous driving in SUMO.

Importing the package registers the gymnasium environment ``priqn/Intersection-v0``;
the environment module itself (and SUMO) is only imported when an env is made.
"""

from __future__ import annotations

import gymnasium

from priqn.objectives import OBJECTIVES

__version__ = "0.1.0"
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
