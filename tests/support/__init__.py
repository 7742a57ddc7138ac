"""Helpers shared by the tests, imported by package name (``from support.configs import ...``;
the pytest config puts ``tests/`` on the path).

- ``configs``: THE build-config builder (``config_doc`` / ``build_config`` / ``config_file``).
- ``builds``: a small finished dataset built from a generated mission.
- ``members``: tar members and manifest keys of a finished dataset, read independently.
- ``missions``: synthetic missions generated once per session, keyed by their parameters.
- ``los_reference``: exact line of sight from the definition (no code shared with the kernel).
- ``independent_truth``: camera and frame maths re-derived without ``mars_pairs``.
- ``real_samples``: where the real data beside the checkout lies.
- ``fetch_archive`` / ``fetch_server`` / ``replica_archive``: archives served for fetch tests.
- ``label_shapes``: pathological label shapes for the label-reading bounds.
"""
