"""A first render's tracing kernel compiled by a second process while this one compiles the
rest of its setup.

A cold first render compiled its setup steps one after the other (showcase.nff: the structure
build 5.5 s, the tracing kernel 25 s, the primary rays 1.2 s): numba compiles one function at
a time in a process (its compiler lock, and the GIL). The tracing kernel needs no structure,
only its variant's types, so when the engine announces a cold variant, before it builds
anything, `meshnode warmup --variant NAME --kernels trace` starts compiling that kernel into
the shared disk cache on another core (over a stand-in structure of no objects: it compiles
no build kernel); this process builds its structure and compiles the primary rays meanwhile,
then waits for it and loads the kernel (`Engine.warmup` finds it marked warm). With one core,
or if the second process fails, this process compiles the kernel itself, as before.

The variant names the structure, which "auto" chooses only after building the hierarchy:
the engine announces the hierarchy's variant first (every SPD scene's choice) and, when it
chooses the grid, the grid's; the second process is then started again for that one.
"""

import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # the tree this process runs: the child runs it too


def _cores() -> int:
    """Cores this process may use."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


class CompileAside:
    """The second process of one render's setup, if one is started (`announce`); a context
    manager that stops it if the render ends first (an error, Ctrl-C)."""

    def __init__(self, say=None):
        self.say = say  # say(line) hears what the second process did; None: nothing is said
        self.proc: subprocess.Popen | None = None
        self.variant: str | None = None  # the variant it compiles
        self.started = 0.0
        self.seconds = 0.0  # the second process's wall, start to end
        self.waited = 0.0  # this process's wait for it

    def __enter__(self) -> "CompileAside":
        return self

    def __exit__(self, *exc) -> None:
        self._stop()

    def _stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def announce(self, then=None):
        """The engine's `announce` callback: a cold variant's tracing kernel starts compiling
        aside, then `then(variant)` is called (None: nothing more)."""

        def announce(variant: str) -> None:
            self.start(variant)
            if then is not None:
                then(variant)

        return announce

    def start(self, variant: str) -> None:
        """Compile `variant`'s tracing kernel in a second process (not on one core); one
        compiling another variant (the structure foreseen, not chosen) is stopped first."""
        if self.variant == variant or _cores() < 2:
            return
        self._stop()
        self.variant = variant
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
        command = ["warmup", "--variant", variant, "--kernels", "trace"]
        self.started = time.perf_counter()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "meshnode.service.cli", *command],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            env=env,
        )

    def then(self, warmup):
        """`warmup()` once the second process, if any, has ended: it then loads what that
        compiled (or compiles it, had that failed)."""
        if self.proc is not None:
            start = time.perf_counter()
            _, err = self.proc.communicate()
            self.waited = time.perf_counter() - start
            self.seconds = time.perf_counter() - self.started
            if self.say is not None and self.proc.returncode == 0:
                where = "the tracing kernel in a second process"
                self.say(f"compiled {where} in {self.seconds:.1f} s")
            elif self.say is not None:
                last = err.decode(errors="replace").strip().splitlines()[-1:] or ["no message"]
                self.say(f"the second compiling process failed ({last[0]}): compiling here")
        return warmup()

    def account(self, seconds: dict) -> dict:
        """The setup's seconds (`firstrun.Setup.seconds`) with the wait for the second
        process counted as compiling, not loading, and that process's own seconds."""
        if self.proc is None:
            return seconds
        return {
            **seconds,
            "compile_seconds": seconds["compile_seconds"] + self.waited,
            "load_seconds": max(0.0, seconds["load_seconds"] - self.waited),
            "compile_aside_seconds": self.seconds,
        }
