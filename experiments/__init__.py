"""rtfit.experiments: experiments, executors, sweeps, figures, reports and the ``rtfit`` CLI.

JAX runs rtfit's fits, which are small (tens of parameters, thousands of residuals): they run on the
CPU unless the user sets ``JAX_PLATFORMS`` himself. Left to its defaults on a GPU machine, JAX
would grab 75% of GPU memory in every process that imports it, beside Dr.Jit's renders and in every
worker of a GPU pool, and run out of memory.
"""

import os as _os

_os.environ.setdefault("JAX_PLATFORMS", "cpu")
_os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")


def _import_drjit_without_its_libllvm_lines() -> None:
    """A ``$DRJIT_LIBLLVM_PATH`` that names no file makes ``import drjit`` print two lines of its own
    (``jit_find_library(): Unable to load …``, ``jitc_llvm_init(): LLVM API initialization failed``) before
    rtfit can say anything: Dr.Jit is imported here first with its stderr (file descriptor 2) on the null
    device, and rtfit's one line (`rtfit.reference.variants.resolve_variant`: "… $DRJIT_LIBLLVM_PATH=… is
    not a file") is all a command that needs the LLVM backend prints (issue 32)."""
    path = _os.environ.get("DRJIT_LIBLLVM_PATH")
    if not path or _os.path.isfile(path):
        return
    saved, null = _os.dup(2), _os.open(_os.devnull, _os.O_WRONLY)
    _os.dup2(null, 2)
    try:
        import drjit  # noqa: F401  (drjit: imported here only to silence its start-up lines)
    except ImportError:  # reported where Dr.Jit is used
        pass
    finally:
        _os.dup2(saved, 2)
        _os.close(saved)
        _os.close(null)


_import_drjit_without_its_libllvm_lines()
