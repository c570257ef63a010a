"""Starting Warp for a run: quietly on the CPU, loudly where a GPU was asked for."""

import contextlib
import os
import sys

import warp as wp


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
    """wp.init() without the banner; on the CPU also without Warp's native notice that no
    CUDA driver was found (printed unconditionally, and irrelevant to a CPU run: a user's
    stderr then holds dynfab's lines only). On a GPU device the notice stays visible."""
    wp.config.log_level = wp.LOG_WARNING
    if str(device).startswith("cpu"):
        with _native_stderr_silenced():
            wp.init()
    else:
        wp.init()
