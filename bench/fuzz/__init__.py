"""The node fuzzer behind `python -m bench.fuzz_node`, by part: hostile inputs (`inputs`),
the node under test (`node`), a raw connection (`conn`), the cases on a fresh connection
(`connection_cases`) and inside a session (`session_cases`), the fuzzer running them in lanes
(`fuzzer`) and the printed `report`."""
