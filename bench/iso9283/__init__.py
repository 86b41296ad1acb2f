"""ISO 9283:1998 performance figures of recordings (``cdpr iso9283``) and the paper's plots.

- :mod:`.figures`: the figures as pure functions on arrays (AP, RP, AP_a..RP_c; AT, RT,
  the normal-plane matching of paths).
- :mod:`.segments`: visits (dwells) and passes (moves) of a recording.
- :mod:`.analysis`: figures of recordings, the ``--json`` object and the table.
- :mod:`.plots`: Fig. 6-like (pose bars) and Fig. 7-like (paths, AT along the path) plots.
"""
