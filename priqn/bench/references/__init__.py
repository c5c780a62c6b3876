"""The references: slow, literal implementations kept as the specification of fast ones.

They are the baselines ``priqn bench`` times the product code against and the oracles the
tests check it with, byte for byte; nothing in the product imports them.

* :mod:`priqn.bench.references.sensors`: :class:`ReferenceSensors`, the sensors'
  first implementation (:mod:`priqn.env.sensors`; ``priqn bench env``,
  ``tests/test_sensors.py``);
* :mod:`priqn.bench.references.subsets`: :func:`reference_optimal_subsets`, Algorithm 1
  the slow way (:mod:`priqn.agents.subsets`; ``priqn bench preorder``,
  ``tests/test_preorder.py``).
"""
