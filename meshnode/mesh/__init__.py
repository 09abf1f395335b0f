"""The mesh algorithm, without sockets: one node's tracing core with the engines it keeps and
its adaptive-sampling books, the scheduler with its feeds and steps and the driver that acts on
them, the host's tile dealer, termination, the stats, and the simulated mesh that drives the
same scheduler."""
