"""Starting Warp for a run, quietly, on a device that exists (a user's mistake otherwise)."""

import contextlib
import os
import sys

import warp as wp

from dynfab.errors import UserError


@contextlib.contextmanager
def _native_stderr_silenced():
    """Send what native code writes to file descriptor 2 to /dev/null for a moment."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def initialize(device: str) -> None:
    """wp.init() without the banner and without Warp's native notices (that no CUDA driver
    was found, printed unconditionally), then check that `device` exists: an unknown name
    or a CUDA device on a machine without one is a UserError (one line, exit status 2)
    naming the devices this machine has, not a traceback from the first array; then the
    first compile of a kernel is announced if a `dynfab.compiling.announcing` block runs."""
    wp.config.log_level = wp.LOG_WARNING
    with _native_stderr_silenced():
        wp.init()
        try:
            wp.get_device(device)
        except (RuntimeError, ValueError) as error:
            available = ", ".join(str(d) for d in wp.get_devices())
            raise UserError(f"--device {device!r}: not available on this machine ({error}); "
                             f"available: {available}") from None
    from dynfab.compiling import watch_warp

    watch_warp()  # a compile of the kernels is announced (dynfab.compiling), if asked for
