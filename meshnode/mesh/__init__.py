"""The mesh algorithm, without sockets: one node's tracing core with its adaptive-sampling
books, the scheduler with its feeds and steps, termination, the stats, and the simulated mesh
that drives the same scheduler."""
