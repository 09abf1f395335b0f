"""The cost pre-pass's CPU allowance: at most PREPASS_SHARE of one node's tracing of the render.

The pre-pass simulates the mesh on a coarse image to cut the cells, choose copies and grow
boxes. Each simulation costs about the same (tens of milliseconds a 3x3 on a coarse image),
whatever the render's size, so on a short render the pre-pass can cost more than the nodes
save. The first cut's simulations always run: they estimate the render's tracing (`learn`).
Every later simulation asks the allowance first (`affords`); a stage refused is skipped, or
stops with the best it has, and the plan's statistics say which and why (`report`).
Simulations are timed as they run (`spent`), not guessed.

A simulation of new cells builds every node's engine; one of the same cells with other
copies, forwarding or dealing takes them from the plan's cache (balls 3x3: 70 ms against
25 ms). So a stage is estimated from what it builds: the simulations' CPU on engines already
built (`per_pass`) and each engine built (`per_build`), both measured. Kernels a process
loads from the disk cache on its first simulation (0.09 s of a fresh host's first cut on
balls 3x3: half of it) are the process's, paid once, not the pre-pass's: they are left out
of what it spent and of its estimates, and reported apart; so are kernels a machine compiles
on its first render of a kind of cell (rings 2x2 on a fresh cache: 7.5 s, 2.5 times the
render's tracing).
"""

import math
import time
from dataclasses import dataclass, field

from meshnode.engine.loading import load_seconds

PREPASS_SHARE = 0.1  # of one node's estimated tracing CPU the pre-pass may take


@dataclass
class Allowance:
    began: float = field(default_factory=time.process_time)
    seconds: float = math.inf  # CPU the pre-pass may take (inf until the estimate is learnt)
    trace: float | None = None  # one node's tracing of the render, estimated (seconds)
    passes: int = 0  # simulations run
    reused: int = 0  # simulations asked again, their outcomes kept (`prepass.partition_pass`)
    pass_seconds: float = 0.0  # their CPU in all (kernel loads left out)
    built: int = 0  # engines they built
    build_seconds: float = 0.0  # ... and those builds' CPU
    once_seconds: float = 0.0  # ... and the map's tables they made, once a plan
    sight_seconds: float = 0.0  # ... and what the eye sees of their cells, once a cut
    cuts: int = 0  # simulations that made it (of new cells)
    most_built: int = 0  # the most one simulation built: a new cut's, every node's engine
    loads: float = field(default_factory=lambda: load_seconds())  # kernel loads before it
    skipped: list = field(default_factory=list)
    bounded: bool = True  # False: simulations outside a plan (a bench's, a test's) all run
    refused: str = ""  # why no simulation at all is afforded (`refuse_all`)

    def learn(self, trace: float) -> None:
        """One node's tracing of the render, estimated from the first cut's simulation:
        from now on the pre-pass keeps within PREPASS_SHARE of it."""
        self.trace = float(trace)
        if self.bounded:
            self.seconds = PREPASS_SHARE * self.trace if self.trace > 0 else 0.0

    def refuse_all(self, stage: str, why: str) -> None:
        """No simulation fits, known before any runs (`stage` skipped for `why`): every
        later stage is refused with the same reason."""
        self.seconds, self.refused = 0.0, why
        self.skipped.append({"stage": stage, "why": why})

    def too_small(self, samples: int, coarse: int) -> str:
        """Why a render of `samples` samples affords no simulation of `coarse` ("" where it
        may): a simulation traces the same scene at the same depth, so under 1 /
        PREPASS_SHARE of them it takes more than the allowance of the render's tracing."""
        least = coarse / PREPASS_SHARE
        if samples >= least:
            return ""
        return (
            f"the render traces {samples} samples, fewer than {least:.0f} ({1 / PREPASS_SHARE:.0f}"
            f" coarse passes of {coarse}): no simulation fits in {PREPASS_SHARE:.0%} of its "
            "tracing"
        )

    def ran(
        self,
        seconds: float,
        built: int = 0,
        build_seconds: float = 0.0,
        once: float = 0.0,
        sights: float = 0.0,
    ) -> None:
        """A simulation ran, taking `seconds` of CPU (kernel loads left out), `build_seconds`
        of them building `built` engines, `once` making the map's tables no later one
        makes again (`mapbounds.per_map`: balls 3x3, 28 ms of the first simulation's 88) and
        `sights` what the eye sees of new cells (`EngineCache.sightlines`: rings 4x4, 11 ms
        of the first cut's 73, where a simulation of the same cells took 35)."""
        self.passes += 1
        self.pass_seconds += seconds
        self.built += built
        self.build_seconds += build_seconds
        self.once_seconds += once
        self.sight_seconds += sights
        self.cuts += sights > 0
        self.most_built = max(self.most_built, built)

    @property
    def loaded(self) -> float:
        """CPU this process spent loading kernels from the disk cache (or compiling those it
        lacked) since the plan began."""
        return load_seconds() - self.loads

    @property
    def spent(self) -> float:
        """The pre-pass's CPU so far (simulations and the work between them), kernel loads
        left out."""
        return time.process_time() - self.began - self.loaded

    @property
    def per_pass(self) -> float:
        """A simulation's CPU on engines already built, as measured so far."""
        made = self.pass_seconds - self.build_seconds - self.once_seconds - self.sight_seconds
        return made / self.passes if self.passes else 0.0

    @property
    def per_cut(self) -> float:
        """What the eye sees of a simulation's new cells, as measured so far."""
        return self.sight_seconds / self.cuts if self.cuts else 0.0

    @property
    def per_build(self) -> float:
        """An engine's build in a simulation, as measured so far."""
        return self.build_seconds / self.built if self.built else 0.0

    def cost(self, passes: int, builds: int | None = None) -> float:
        """CPU of `passes` simulations that build `builds` engines (None: each a new cut's,
        as many as the most one simulation built; any: of new cells, whose sightlines are
        made too)."""
        builds = passes * self.most_built if builds is None else builds
        cuts = passes * self.per_cut if builds else 0.0
        return passes * self.per_pass + builds * self.per_build + cuts

    def affords(
        self, stage: str, passes: int = 1, reserve: int = 0, builds: int | None = None
    ) -> bool:
        """Whether `passes` more simulations building `builds` engines fit (`cost`; None:
        new cells each), `reserve` more kept for later stages (the copies', on the cells'
        engines); a refusal is recorded for `stage` with the figures."""
        if self.refused:
            self.skipped.append({"stage": stage, "why": self.refused})
            return False
        these = self.cost(passes, builds)
        each, need = these / max(passes, 1), these + self.cost(reserve, 0)
        if self.spent + need <= self.seconds:
            return True
        self.skipped.append(
            {
                "stage": stage,
                "why": f"{passes} more simulation(s) of about {each:.3f} s CPU"
                + (f" ({reserve} kept for later stages)" if reserve else "")
                + f" would pass the pre-pass's {self.seconds:.2f} s ({PREPASS_SHARE:.0%} of "
                f"one node's tracing, about {self.trace:.2f} s); {self.spent:.2f} s spent",
            }
        )
        return False

    @property
    def why(self) -> str:
        """The last refusal's reason (`affords`), for the stage's own report."""
        return self.skipped[-1]["why"] if self.skipped else ""

    def report(self) -> dict:
        """What the statistics say of the pre-pass's CPU."""
        return {
            "allowed_cpu_seconds": self.seconds if math.isfinite(self.seconds) else None,
            "cpu_seconds": self.spent,
            "one_node_tracing_seconds": self.trace,
            "simulations": self.passes,
            "simulations_reused": self.reused,
            "simulation_cpu_seconds": self.pass_seconds,
            "engines_built": self.built,
            "engine_build_cpu_seconds": self.build_seconds,
            "map_tables_cpu_seconds": self.once_seconds,
            "kernel_load_cpu_seconds": self.loaded,
            "skipped": list(self.skipped),
        }
