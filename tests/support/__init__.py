"""Helpers shared by the tests, imported by package name (``from support.configs import ...``;
the pytest config puts ``tests/`` on the path).

- ``configs``: THE build-config builder (``config_doc`` / ``build_config`` / ``config_file``).
- ``builds``: datasets built from a generated mission (``build``, ``build_small``, the CLI's).
- ``members``: tar members and manifest keys of a finished dataset, read independently.
- ``missions``: synthetic missions generated once per session, keyed by their parameters.
- ``los_reference``: exact line of sight from the definition (no formula shared with the kernel).
- ``terrain``: fractal DEMs and grids of the kernel tests.
- ``independent_truth``: camera and frame maths re-derived without ``mars_pairs``.
- ``real_samples`` / ``real_gale``: the real data beside the checkout, labels at a real pose.
- ``fetch_archive`` / ``fetch_server`` / ``replica_archive``: archives served for fetch tests.
- ``label_shapes`` / ``label_seeds`` / ``observations``: label fuzzing and comparison.
"""
