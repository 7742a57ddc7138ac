"""The dataset build, in two packages and the configuration they share.

- ``pipeline.config`` (and ``config_schema``, ``config_section``, ``splitting``): the build
  configuration, read and checked against its schema before any work, and the split rule (a
  function of position and config).
- ``pipeline.sample``: one observation -> one sample (label, image, pose, view, chips,
  dense members, manifest row), the stages in order; no knowledge of the build.
- ``pipeline.builder``: a build of many samples (plan and label listing, engines and workers,
  outputs and resume, finish); it calls ``pipeline.sample`` and nothing calls it back.
"""
