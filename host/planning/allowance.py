"""The cost pre-pass's CPU allowance: at most PREPASS_SHARE of one node's tracing of the render.

The pre-pass simulates the mesh on a coarse image to cut the cells, choose copies and grow
boxes. Each simulation costs about the same (tens of milliseconds a 3x3 on a coarse image),
whatever the render's size, so on a short render the pre-pass can cost more than the nodes
save. The first cut's simulations always run: they estimate the render's tracing (`learn`).
Every later simulation asks the allowance first (`affords`); a stage refused is skipped, or
stops with the best it has, and the plan's statistics say which and why (`report`).

Simulations are charged what they count, not what the clock says (`Work`, `charge`): the
nodes and batches they simulate, the work units they trace, the objects whose engines they
build and the new cells whose sightlines they make, each at a CPU cost measured on the SPD
scenes. Timed, the same request got other plans run to run (teapot 3x3: three or four sets
of copies tried, the shares' check afforded or not) as this shared machine's load moved
each simulation by a fifth. Charged, a plan is the same every time, and its one node's
tracing is itself estimated from counts (`prepass.tracing_seconds`). The CPU is still
measured and reported beside the charge; past VALVE times the allowance, measured, nothing
more runs (a machine far slower than the model: the pre-pass stays bounded all the same).

A simulation of new cells builds every node's engine; one of the same cells with other
copies, forwarding or dealing takes them from the plan's cache (balls 3x3: 70 ms against
25 ms). So a stage is estimated from what it builds: the simulations' charge on engines
already built (`per_pass`), each engine built (`per_build`) and each new cut's sightlines
(`per_cut`), from what the plan's simulations were charged so far. Kernels a process loads
from the disk cache on its first simulation (0.09 s of a fresh host's first cut on balls
3x3: half of it) are the process's, paid once, not the pre-pass's: they are left out of the
measured CPU and reported apart; so are kernels a machine compiles on its first render of a
kind of cell (rings 2x2 on a fresh cache: 7.5 s, 2.5 times the render's tracing).
"""

import math
import time
from dataclasses import dataclass, field

from meshnode.engine.loading import load_seconds

PREPASS_SHARE = 0.1  # of one node's estimated tracing CPU the pre-pass may take
# What a simulation is charged, by what it counts (`charge`): fitted on this machine to the
# 602 simulations of plans of balls, gears, rings, teapot, tetra, the mountain and tetra_s8
# on 2x2 to 4x4 with every stage run (charge over measured CPU: median 1.0, tenth to ninetieth
# percentile 0.7-1.1 for the simulations, 0.8-1.2 for the builds; docs/measurements.md,
# session 57).
NODE_SECONDS = 630e-6  # a node simulated: its scheduler's, driver's and deliveries' Python
BATCH_SECONDS = 61e-6  # a batch traced, around its kernel
UNIT_SECONDS = 11.5e-9  # a work unit traced (a coarse image's rays share less of each walk)
ENGINE_SECONDS = 735e-6  # an engine built, and each of its objects by kind:
OBJECT_SECONDS = {"spheres": 0.94e-6, "triangles": 0.8e-6, "polygons": 3.36e-6, "cones": 1.12e-6}
# (triangles at their ninetieth percentile, 0.56 at the median: the 65,536-triangle tetra's
# builds took 0.55-0.82 us a triangle, and its plans measured up to a third over their charge)
SIGHT_SECONDS = 3e-3  # what the eye sees of cells, an entry made (3 a new cut: 5-12 ms)
TABLE_SECONDS = 15e-3  # a map's table a plan reads (`mapbounds.per_map`: 3-4 a plan, made
# once a process in 12-67 ms in all on the SPD scenes, the lights' maps the most; charged
# to every plan, made or kept, so a plan is the same whatever the process planned before)
BETWEEN = 1.2  # the plan's own work between simulations: a fifth of theirs (2x2 to 4x4) ...
HELD_SECONDS = 0.15e-6  # ... and, each simulation, for every object a node holds in it (the
# holders' subsets and tables: the 65,536-triangle tetra's plans 17 ms a simulation beyond)
VALVE = 2.0  # measured CPU past this many allowances: nothing more runs, whatever is charged


@dataclass(frozen=True)
class Work:
    """What one simulation did, counted: what it is charged for (`charge`)."""

    nodes: int = 0
    batches: int = 0  # batches its nodes traced
    units: int = 0  # their work units (`meshnode.mesh.stats.work_units`)
    built: int = 0  # engines it built ...
    objects: dict = field(default_factory=dict)  # ... and their objects, by kind
    sights: int = 0  # sightlines' entries it made (`EngineCache.sightlines`)
    tables: int = 0  # the map's tables it read first in its plan (made, or kept from another)
    held: int = 0  # objects its nodes held, summed over them


def charge(work: Work) -> tuple[float, float, float, float]:
    """(simulating, building, sightlines, the map's tables) CPU charged for `work`, before
    BETWEEN."""
    simulating = (
        NODE_SECONDS * work.nodes
        + BATCH_SECONDS * work.batches
        + UNIT_SECONDS * work.units
        + HELD_SECONDS * work.held
    )
    building = ENGINE_SECONDS * work.built + sum(
        OBJECT_SECONDS.get(kind, max(OBJECT_SECONDS.values(), default=0.0)) * n
        for kind, n in work.objects.items()
    )
    return simulating, building, SIGHT_SECONDS * work.sights, TABLE_SECONDS * work.tables


@dataclass
class Allowance:
    began: float = field(default_factory=lambda: time.process_time())
    seconds: float = math.inf  # CPU the pre-pass may take (inf until the estimate is learnt)
    trace: float | None = None  # one node's tracing of the render, estimated (seconds)
    passes: int = 0  # simulations run
    reused: int = 0  # simulations asked again, their outcomes kept (`prepass.partition_pass`)
    pass_charge: float = 0.0  # their simulating charged (`charge`), BETWEEN apart
    build_charge: float = 0.0  # ... their engines' builds
    cut_charge: float = 0.0  # ... what the eye sees of their new cells
    table_charge: float = 0.0  # ... the map's tables the plan read, made or kept
    built: int = 0  # engines they built
    cuts: int = 0  # simulations that made sightlines (of new cells)
    most_built: int = 0  # the most one simulation built: a new cut's, every node's engine
    pass_seconds: float = 0.0  # measured: their CPU in all (kernel loads left out)
    build_seconds: float = 0.0  # ... of it building engines
    once_seconds: float = 0.0  # ... making the map's tables, once a plan
    sight_seconds: float = 0.0  # ... making what the eye sees of new cells
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
        work: Work,
        seconds: float = 0.0,
        build_seconds: float = 0.0,
        once: float = 0.0,
        sights: float = 0.0,
    ) -> None:
        """A simulation did `work`, charged for it (`charge`); measured, it took `seconds`
        of CPU (kernel loads left out), `build_seconds` of them building its engines, `once`
        making the map's tables no later one makes again (`mapbounds.per_map`: balls 3x3,
        28 ms of the first simulation's 88) and `sights` what the eye sees of new cells
        (`EngineCache.sightlines`: rings 4x4, 11 ms of the first cut's 73)."""
        simulating, building, cut, tables = charge(work)
        self.passes += 1
        self.pass_charge += simulating
        self.table_charge += tables
        self.build_charge += building
        self.cut_charge += cut
        self.built += work.built
        self.cuts += work.sights > 0
        self.most_built = max(self.most_built, work.built)
        self.pass_seconds += seconds
        self.build_seconds += build_seconds
        self.once_seconds += once
        self.sight_seconds += sights

    @property
    def loaded(self) -> float:
        """CPU this process spent loading kernels from the disk cache (or compiling those it
        lacked) since the plan began."""
        return load_seconds() - self.loads

    @property
    def cpu(self) -> float:
        """The pre-pass's CPU so far as measured (simulations and the work between them),
        kernel loads left out."""
        return time.process_time() - self.began - self.loaded

    @property
    def spent(self) -> float:
        """The pre-pass's CPU so far as charged: its simulations' and the work between them
        (BETWEEN)."""
        charged = self.pass_charge + self.build_charge + self.cut_charge + self.table_charge
        return BETWEEN * charged

    @property
    def per_pass(self) -> float:
        """A simulation's charge on engines already built, as charged so far."""
        return self.pass_charge / self.passes if self.passes else 0.0

    @property
    def per_cut(self) -> float:
        """What the eye sees of a simulation's new cells, as charged so far."""
        return self.cut_charge / self.cuts if self.cuts else 0.0

    @property
    def per_build(self) -> float:
        """An engine's build in a simulation, as charged so far."""
        return self.build_charge / self.built if self.built else 0.0

    def cost(self, passes: int, builds: int | None = None) -> float:
        """CPU of `passes` simulations that build `builds` engines (None: each a new cut's,
        as many as the most one simulation built; any: of new cells, whose sightlines are
        made too), the work between them counted (BETWEEN)."""
        builds = passes * self.most_built if builds is None else builds
        cuts = passes * self.per_cut if builds else 0.0
        return BETWEEN * (passes * self.per_pass + builds * self.per_build + cuts)

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
        if self.spent + need <= self.seconds and self.cpu <= VALVE * self.seconds:
            return True
        why = (
            f"{passes} more simulation(s) of about {each:.3f} s CPU"
            + (f" ({reserve} kept for later stages)" if reserve else "")
            + f" would pass the pre-pass's {self.seconds:.2f} s ({PREPASS_SHARE:.0%} of "
            f"one node's tracing, about {self.trace:.2f} s); {self.spent:.2f} s spent"
        )
        if self.spent + need <= self.seconds:  # the valve: the charges fell far short
            why = (
                f"the pre-pass measured {self.cpu:.2f} s of CPU, over {VALVE:g} times its "
                f"{self.seconds:.2f} s ({self.spent:.2f} s charged)"
            )
        self.skipped.append({"stage": stage, "why": why})
        return False

    @property
    def why(self) -> str:
        """The last refusal's reason (`affords`), for the stage's own report."""
        return self.skipped[-1]["why"] if self.skipped else ""

    def report(self) -> dict:
        """What the statistics say of the pre-pass's CPU: charged, and measured."""
        return {
            "allowed_cpu_seconds": self.seconds if math.isfinite(self.seconds) else None,
            "charged_cpu_seconds": self.spent,
            "cpu_seconds": self.cpu,
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
