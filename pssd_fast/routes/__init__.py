"""What a run does around its pipeline's step, and the plan that picks it.

:mod:`.plan` decides once per run which route it takes and at which sizes; the routes are
:mod:`.coarse` (iterate on cell means, then fit every point to them), :mod:`.scales` (a scale
per point, the walks) and :mod:`.edges` (the points near features on their own). The
per-iteration steps themselves are in :mod:`pssd_fast.pipelines`.
"""
