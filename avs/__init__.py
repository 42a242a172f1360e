"""The ``avs`` command line: start the system, watch its streams, run episodes."""

import os

# numba's parallel kernels on OpenMP (libgomp, which Open3D needs too): left to choose, numba
# tries first the TBB that Open3D bundles, finds it too old and says so on every command's
# console
os.environ.setdefault("NUMBA_THREADING_LAYER", "omp")
# ... with idle threads sleeping, not spinning (services/__init__.py says why)
os.environ.setdefault("OMP_WAIT_POLICY", "passive")
