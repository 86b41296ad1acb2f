"""``cdpr diagnose``: where simulation and recording differ, which physics the model left out.

Modules: :mod:`.samples` (dwell averaging, replicates), :mod:`.space` (effect
parameters), :mod:`.residuals` (residuals of a hypothesis), :mod:`.fit`
(least squares), :mod:`.select` (choosing effects), :mod:`.locate` (where the
mismatch is), :mod:`.report` (the ``cdpr-diagnosis/1`` object), :mod:`.plots`.
"""
