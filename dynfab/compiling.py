"""Saying "compiling kernels (first run only)" before a compile that will really happen.

dynfab's compiled code comes in two kinds, both compiled on first use and kept in an
on-disk cache that later processes load from in milliseconds:

- numba functions (`@numba.njit(cache=True)`: the static solvers, the assembly, the
  certificate), cached next to their modules (or in NUMBA_CACHE_DIR). numba's event API
  reports "numba:compile" only when a function is really compiled: a cache hit loads it
  without that event. A listener on it says the message at the first compile of one of
  dynfab's own functions (numba's internal helpers, uncached, compile in every process and
  are left out: they would make "first run only" untrue).
- Warp modules (the dynamic solvers' kernels), compiled on their first load unless Warp's
  kernel cache (`warp.config.kernel_cache_dir`, WARP_CACHE_PATH) holds their binary.
  `will_compile(module, device)` checks that cache before the load; while `announcing` is
  active, `warp.Module.load` is wrapped to check it (once per module and device) and say
  the message first. The wrapper is installed when Warp starts (`watch_warp`, called by
  `dynfab.kernels.runtime.initialize`), so a run that never uses Warp never imports it.

The message is said once per `announcing` block; the watches are removed when it ends
(Warp's at once after the message: the wrapper costs a set lookup per launch).

A run also times its compiles (`start_clock`, `compile_seconds`): a first run's steps spend
seconds compiling that later runs load in milliseconds, and its summary says the two apart
(`steps/compile_time`).
"""

from __future__ import annotations

import contextlib
import glob
import os
import time

MESSAGE = "compiling kernels (first run only)"
"""What is said before the first real compile."""

_active: "_Announcer | None" = None
"""The announcer of the running `announcing` block, or None."""


class _Announcer:
    """Says MESSAGE once, at the first real compile of `packages`' numba functions or of a
    Warp module, then removes its watches."""

    def __init__(self, say, packages: tuple[str, ...]):
        self.say, self.packages = say, packages
        self.said = False
        self.listener = None
        self.original_load = None
        self.wrapper = None
        self.checked: set = set()

    def announce(self) -> None:
        """Say MESSAGE, the first time; stop checking Warp's loads (numba's listener, called
        only at a real compile, stays until the block ends: it may be running now)."""
        if not self.said:
            self.said = True
            self.unwatch_warp()
            self.say(MESSAGE)

    def watch_numba(self) -> None:
        from numba.core import event

        announcer = self

        class Listener(event.Listener):
            def on_start(self, ev) -> None:
                dispatcher = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
                module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
                if module.split(".")[0] in announcer.packages:
                    announcer.announce()

            def on_end(self, ev) -> None:
                pass

        self.listener = Listener()
        event.register("numba:compile", self.listener)

    def watch_warp(self) -> None:
        import warp as wp

        if self.said or self.original_load is not None:
            return
        original = self.original_load = wp.Module.load
        announcer = self

        def load(module, device, block_dim=None, *args, **kwargs):
            if not announcer.said and _first_load_compiles(announcer.checked, module, device,
                                                           block_dim, args, kwargs):
                announcer.announce()
            return original(module, device, block_dim, *args, **kwargs)

        self.wrapper = wp.Module.load = load

    def remove(self) -> None:
        """Take both watches off (idempotent)."""
        if self.listener is not None:
            from numba.core import event

            event.unregister("numba:compile", self.listener)
            self.listener = None
        self.unwatch_warp()

    def unwatch_warp(self) -> None:
        """Give `warp.Module.load` back (idempotent); where another watch wrapped it since
        (the compile clock's), leave the chain as it is, this wrapper then passing through
        (`said` set)."""
        if self.original_load is not None:
            import warp as wp

            if wp.Module.load is self.wrapper:
                wp.Module.load = self.original_load
            self.said = True
            self.original_load = None


@contextlib.contextmanager
def announcing(say, packages: tuple[str, ...] = ("dynfab",)):
    """While the block runs, call say(MESSAGE) once, before the first compile that really
    happens: of a numba function defined in `packages` (top-level package names), or of a
    Warp module (module docstring). Nothing is said when the caches hold everything."""
    global _active
    announcer = _Announcer(say, tuple(packages))
    previous, _active = _active, announcer
    announcer.watch_numba()
    try:
        watch_warp()
        yield
    finally:
        announcer.remove()
        _active = previous


def watch_warp() -> None:
    """Watch Warp's module loads for the running `announcing` block, if any, and for the
    compile clock, if started (Warp has been imported; called when it starts)."""
    import sys

    if "warp" not in sys.modules:
        return
    if _active is not None:
        _active.watch_warp()
    if _clock.started:
        _clock.watch_warp()


class _CompileClock:
    """Seconds spent compiling in this process since `start_clock` (module docstring):
    numba's compiles, each outermost one timed whole (a function's compile compiles its
    callees inside it), and Warp's module loads that compile. The watches stay for the
    process: numba's listener is called only at a real compile, Warp's load wrapper checks a
    set before it times anything."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self.started = False
        self.depth = 0
        self.began = 0.0
        self.checked: set = set()
        self.warp_watched = False

    def start(self) -> None:
        if self.started:
            return
        self.started = True
        from numba.core import event

        clock = self

        class Listener(event.Listener):
            def on_start(self, ev) -> None:
                if clock.depth == 0:
                    clock.began = time.perf_counter()
                clock.depth += 1

            def on_end(self, ev) -> None:
                clock.depth -= 1
                if clock.depth == 0:
                    clock.seconds += time.perf_counter() - clock.began

        event.register("numba:compile", Listener())
        watch_warp()

    def watch_warp(self) -> None:
        import warp as wp

        if self.warp_watched:
            return
        self.warp_watched = True
        original = wp.Module.load
        clock = self

        def load(module, device, block_dim=None, *args, **kwargs):
            compiles = _first_load_compiles(clock.checked, module, device, block_dim, args,
                                            kwargs)
            began = time.perf_counter()
            try:
                return original(module, device, block_dim, *args, **kwargs)
            finally:
                if compiles:
                    clock.seconds += time.perf_counter() - began

        wp.Module.load = load


_clock = _CompileClock()


def start_clock() -> None:
    """Start timing this process's compiles (idempotent; `compile_seconds` reads it)."""
    _clock.start()


def compile_seconds() -> float:
    """Seconds spent compiling since `start_clock` [s]."""
    return _clock.seconds


def _first_load_compiles(checked: set, module, device, block_dim, args, kwargs) -> bool:
    """Whether this call of `warp.Module.load` compiles: the first for its (module, device,
    block_dim) that `checked` has seen (added to it), with no binary given (nothing to
    compile then), that `will_compile`. The watches' one check before a load."""
    key = (id(module), str(device), block_dim)
    if key in checked or args or kwargs.get("binary_path"):
        return False
    checked.add(key)
    return will_compile(module, device, block_dim)


def will_compile(module, device, block_dim: int | None = None) -> bool:
    """Whether loading the Warp `module` on `device` compiles it: its binary and metadata
    are not in Warp's kernel cache (or the cache is off). Mirrors `warp.Module.load`'s
    lookup: the folder named by the module's identifier (its content hash) under
    `warp.config.kernel_cache_dir`, holding "<identifier>.meta" and the device's binary
    (the CPU's object file, a CUDA architecture's PTX or CUBIN)."""
    import warp as wp

    if not wp.config.cache_kernels:
        return True
    device = wp.get_device(device)
    if block_dim is None:
        block_dim = module.options["block_dim"]
    name = module.get_module_identifier(block_dim)
    folder = os.path.join(wp.config.kernel_cache_dir, name)
    if not os.path.exists(os.path.join(folder, f"{name}.meta")):
        return True
    try:  # the exact file name, where this Warp version names it so
        binary = module._get_compile_output_name(device, block_dim=block_dim)
        return not os.path.exists(os.path.join(folder, binary))
    except (AttributeError, TypeError):
        pattern = f"{name}*.o" if device.is_cpu else f"{name}.sm*"
        return not glob.glob(os.path.join(glob.escape(folder), pattern))
