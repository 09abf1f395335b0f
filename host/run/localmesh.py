"""The embedded default: `meshnode serve` processes on loopback, started and always stopped.

Each node prints `listening HOST:PORT` once bound; the host reads that line, so ports are
chosen by the OS. Processes are killed on any exit path (errors, Ctrl-C) by the context
manager, so no orphan is left behind. Nodes start with SIGINT ignored: a Ctrl-C at the
terminal (sent to the whole process group) reaches the host alone, which stops them all at
once (SIGTERM: they die without a word) before it winds down, instead of every node printing
its own traceback or reporting its neighbours gone; they stay in the terminal's group, so a
hang-up or Ctrl-Z still reaches them.
"""

import os
import select
import signal
import subprocess
import sys
import threading
from contextlib import contextmanager

from host.run.errors import MeshError

# How a node process runs best, unless its environment says otherwise (the Dockerfile sets the
# same; bench processes too, so the one node they measure against runs as the nodes do):
# - OPENBLAS_NUM_THREADS=1: a node multiplies no matrix large enough to share, and numpy's
#   OpenBLAS threads spin after it loads (0.1 s of CPU a node start, taken from neighbours);
# - NUMPY_MADVISE_HUGEPAGE=0: numpy asks for huge pages for arrays from 4 MB, and a node's
#   ray batches come and go: each fresh one faulted in 2 MB pages the system zeroed whole.
#   Real nodes in turns, 3x3 under a quarter share, the nine frames' CPU summed: balls 2-8%
#   less in five pairs of six (their system CPU 0.44-0.56 s against 0.53-0.83), mount 2-3%
#   less, teapot 4% less to 1% more; the mountain's kernels no slower (0.754-0.758 s against
#   0.786-0.789).
NODE_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "NUMPY_MADVISE_HUGEPAGE": "0"}


class LocalMesh:
    """`with LocalMesh(n) as addresses:` n node processes on 127.0.0.1, each tracing on
    `threads` threads (one: the default mesh has a node per core). `listen` (one
    HOST:PORT per node) and `wrap` (a command prefix per node, such as `ip netns exec NS`)
    place nodes elsewhere on this machine, for tests over real network devices; `module`
    (a `meshnode.service.cli` look-alike), `options` (more `serve` options) and `env` start them
    differently, for tests that inject faults; `secret`: the cluster secret the nodes get
    (in their environment, never on a command line other users can read); `once`: nodes
    serve one render (False: until stopped, for several renders on one mesh)."""

    def __init__(
        self,
        n: int,
        cluster: str = "meshtrace",
        start_timeout: float = 60.0,
        listen: list[str] | None = None,
        wrap=None,
        threads: int = 1,
        module: str = "meshnode.service.cli",
        options=(),
        env=None,
        secret: bytes | None = None,
        once: bool = True,
    ):
        self.n, self.cluster, self.timeout, self.threads = n, cluster, start_timeout, threads
        self.secret = secret
        self.once = once
        self.module, self.options, self.env = module, list(options), env
        self.listen = listen or ["127.0.0.1:0"] * n
        self.wrap = wrap or (lambda i: [])
        self.procs: list[subprocess.Popen] = []
        self._sigint = None  # the SIGINT handler to restore on exit

    def __enter__(self) -> list[str]:
        if (
            threading.current_thread() is threading.main_thread()
            and signal.getsignal(signal.SIGINT) is signal.default_int_handler
        ):
            self._sigint = signal.signal(signal.SIGINT, self._interrupted)
        try:
            with _sigint_ignored():
                for i in range(self.n):
                    self.procs.append(
                        subprocess.Popen(
                            [
                                *self.wrap(i),
                                sys.executable,
                                "-m",
                                self.module,
                                "serve",
                                "--listen",
                                self.listen[i],
                                "--cluster",
                                self.cluster,
                                *(["--once"] * self.once),
                                "--threads",
                                str(self.threads),
                                *self.options,
                            ],
                            stdout=subprocess.PIPE,
                            text=True,
                            env=self._environment(),
                        )
                    )
            return [self._address(i, p) for i, p in enumerate(self.procs)]
        except BaseException:
            self.__exit__(None, None, None)
            raise

    def _environment(self) -> dict:
        env = {**NODE_ENVIRONMENT, **os.environ, **(self.env or {})}
        env.pop("MESHTRACE_SECRET", None)
        if self.secret is not None:
            env["MESHTRACE_SECRET"] = self.secret.decode()
        return env

    def _address(self, n: int, proc: subprocess.Popen) -> str:
        """The address node `n` prints once bound, waiting at most `timeout` seconds for it;
        MeshError in one line when it exits (killed, a bad option) or stays silent."""
        ready, _, _ = select.select([proc.stdout], [], [], self.timeout)
        line = proc.stdout.readline() if ready else ""
        if line.startswith("listening "):
            return line.split()[1]
        try:
            code = proc.wait(timeout=1.0)
        except subprocess.TimeoutExpired:
            code = None
        if code is None:
            why = f"did not say it was listening within {self.timeout:g} s"
        elif code < 0:
            why = f"was killed by signal {-code} before it was listening"
        else:
            why = f"exited with code {code} before it was listening"
        said = f" (it said {line.strip()[:80]!r})" if line.strip() else ""
        raise MeshError(f"local node {n} (pid {proc.pid}) {why}{said}")

    def _stop(self) -> None:
        """SIGTERM to every node still running."""
        for p in self.procs:
            if p.poll() is None:
                p.terminate()

    def _interrupted(self, signum, frame):
        """Ctrl-C: stop every node first, so none sees its neighbours vanish (and logs it)
        while the host winds down, then interrupt the host as Python does."""
        self._stop()
        raise KeyboardInterrupt

    def __exit__(self, *exc) -> None:
        if self._sigint is not None:
            signal.signal(signal.SIGINT, self._sigint)
            self._sigint = None
        self._stop()
        for p in self.procs:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
            if p.stdout:
                p.stdout.close()


@contextmanager
def _sigint_ignored():
    """SIGINT ignored while children start, so they inherit it ignored (Python and asyncio
    then leave it so); only the main thread may change signal handlers."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
