"""Pictures of a cloud (:mod:`.render`) and the per-point fields they colour by
(:mod:`.fields`); the ``pictures`` extra (matplotlib) draws them."""
