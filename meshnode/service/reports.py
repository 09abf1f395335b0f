"""What a node tells the host about itself during a render: PROGRESS, sent with each batch of
primary rays and as a heartbeat (what the live view shows and what the host watches to name a
lost node), and STATS, sent once at the end.

Kept apart from `session`, which decides when each goes: these only gather the figures, from
the session's statistics, scheduler, engine, links and clocks.
"""

import os
import time
from typing import TYPE_CHECKING

from protocols.messages import SETUP_STEPS, Kind, make

if TYPE_CHECKING:
    from meshnode.service.session import Session


def progress_message(session: "Session", rays: int) -> dict:
    """A PROGRESS: `rays` primary rays just traced, and what the host's live view shows of the
    node (its setup step too: before it traces, the page says what it is doing)."""
    s = session
    links = {m: o.link.stats for m, o in s.outboxes.items()}
    objects = s.core.engine.stats["objects"] if s.core is not None else 0
    return make(
        Kind.PROGRESS,
        node=s.node,
        rays=rays,
        work=s.stats.batches,
        ready=s.ready,
        state=int(s.sched.state),
        objects=objects,
        setup=SETUP_STEPS.index(s.setup),
        **s.stats.live(links),
    )


def stats_message(session: "Session") -> dict:
    """The node's STATS: its counters, engines, links, work shared, and setup and frame times."""
    s = session
    links = {m: o.link.stats | {"tls": o.link.tls} for m, o in s.outboxes.items()}
    report = s.stats.report(s.core.engine.stats, links)
    report["waves"] = s.sched.term.wave
    report["engine_reused"] = s.core.engine_reused
    report["eye_map"] = s.core.eye_reason  # whether its eye rays' walks start from the eye's map
    report["eye_claims"] = s.core.claims_reason  # whether it made the eye rays it traces
    report["sky"] = s.core.sky_reason  # whether eye rays that meet nothing are made
    report["copies"] = {str(m): e.stats for m, e in s.core.copies.items()}
    report["ray_sets_sent"] = s.stats.ray_sets  # RAYS_SET frames: RAYS sharing a link
    report["rays_relayed"] = s.stats.relayed  # rays received here for another node
    report["batches_inline"] = s.stats.inline  # of `batches`, traced on the loop's thread
    report["host_packets"] = s.packets.packets  # PIXELS to the host (`DepositPackets`)
    report["progress_sent"] = s.progress_sent  # PROGRESS, heartbeats included
    report["chunks_given"] = s.sched.chunks_given  # taken by neighbours (steal)
    report["chunks_taken"] = s.sched.chunks_taken
    report["chunks_given_by_state"] = dict(s.sched.given_in)
    report["setup_seconds"] = s.setup_seconds  # CONFIG to engine built, links up
    report["compile_seconds"] = s.compile_seconds  # ... of which compiling kernels
    report["engine_bytes_held"] = s.core.engine_bytes  # its own engine and copies
    # the whole process's CPU from the frame's start (kernels, routing, deposits,
    # framing, the event loop): what a node's speedup counts
    report["frame_cpu_seconds"] = time.process_time() - s.frame_cpu_start
    # ... of which in the operating system (sockets, TCP, page faults)
    report["frame_system_cpu_seconds"] = os.times().system - s.frame_sys_start
    # ... of which the event loop's thread outside the batches it traced (messages framed
    # and read, scheduling, eye rays made): the rest of `frame - batch` is the pool's
    loop = time.thread_time() - s.frame_loop_start
    report["loop_cpu_seconds"] = max(loop - s.stats.inline_cpu, 0.0)
    return make(Kind.STATS, node=s.node, stats=report)
