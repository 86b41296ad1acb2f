"""The ``cdpr`` command and its jobs (diagnosis, evaluation, benchmarks, ...).

The physics works on small matrices (6 x 8, 18 x 18): multi-threaded BLAS only adds
overhead there, and with worker processes (``--jobs``) its threads fight over the cores
(the diagnosis ran twice as long on two cores). One BLAS thread per process, unless the
user says otherwise; this runs before numpy is first imported by the ``cdpr`` command.
"""

import os as _os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")
