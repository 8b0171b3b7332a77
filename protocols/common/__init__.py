"""Robot-side helpers more than one protocol uses.

* :mod:`~kilonet.protocols.common.neighbours` — what a robot knows about its neighbours, as heard.
* :mod:`~kilonet.protocols.common.refinement` — distributed refinement of positions from neighbours'
  ranges (gcs's phase 7 and ``localize``).
"""
