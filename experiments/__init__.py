"""rtfit.experiments: experiments, executors, sweeps, figures, reports and the ``rtfit`` CLI.

JAX runs rtfit's fits, which are small (tens of parameters, thousands of residuals): they run on the
CPU unless the user sets ``JAX_PLATFORMS`` himself. Left to its defaults on a GPU machine, JAX
would grab 75% of GPU memory in every process that imports it, beside Dr.Jit's renders and in every
worker of a GPU pool, and run out of memory.
"""

import os as _os

_os.environ.setdefault("JAX_PLATFORMS", "cpu")
_os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
