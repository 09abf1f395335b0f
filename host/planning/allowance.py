"""The cost pre-pass's CPU allowance: at most PREPASS_SHARE of one node's tracing of the render.

The pre-pass simulates the mesh on a coarse image to cut the cells, choose copies and grow
boxes. Each simulation costs about the same (tens of milliseconds a 3x3 on a coarse image),
whatever the render's size, so on a short render the pre-pass can cost more than the nodes
save. The first cut's simulations always run: they estimate the render's tracing (`learn`).
Every later simulation asks the allowance first (`affords`); a stage refused is skipped, or
stops with the best it has, and the plan's statistics say which and why (`report`).
Simulations are timed as they run (`spent`), not guessed.
"""

import math
import time
from dataclasses import dataclass, field

PREPASS_SHARE = 0.1  # of one node's estimated tracing CPU the pre-pass may take


@dataclass
class Allowance:
    began: float = field(default_factory=time.process_time)
    seconds: float = math.inf  # CPU the pre-pass may take (inf until the estimate is learnt)
    trace: float | None = None  # one node's tracing of the render, estimated (seconds)
    passes: int = 0  # simulations run
    pass_seconds: float = 0.0  # their CPU in all
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

    def ran(self, seconds: float) -> None:
        """A simulation ran, taking `seconds` of CPU."""
        self.passes += 1
        self.pass_seconds += seconds

    @property
    def spent(self) -> float:
        """The pre-pass's CPU so far (simulations and the work between them)."""
        return time.process_time() - self.began

    @property
    def per_pass(self) -> float:
        """A simulation's CPU, as measured so far."""
        return self.pass_seconds / self.passes if self.passes else 0.0

    def affords(self, stage: str, passes: int = 1, reserve: int = 0) -> bool:
        """Whether `passes` more simulations fit, `reserve` more kept for later stages; a
        refusal is recorded for `stage` with the figures."""
        if self.refused:
            self.skipped.append({"stage": stage, "why": self.refused})
            return False
        need = (passes + reserve) * self.per_pass
        if self.spent + need <= self.seconds:
            return True
        self.skipped.append(
            {
                "stage": stage,
                "why": f"{passes} more simulation(s) of about {self.per_pass:.3f} s CPU"
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
            "simulation_cpu_seconds": self.pass_seconds,
            "skipped": list(self.skipped),
        }
