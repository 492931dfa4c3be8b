"""The stages run in order: one photo (:mod:`.pipeline`), a folder of them (:mod:`.batch`), a
cluster (:mod:`.ray_engine`)."""
