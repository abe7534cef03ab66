"""The pipeline stages: plain functions on data, each with a small `run` that does the file I/O."""

import os

# The MLN engine's small matrix products run fastest on one BLAS thread; several threads contend on a
# shared 2-core machine and made weight learning 30 times slower under load. Users may still override.
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")
