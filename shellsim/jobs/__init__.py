"""Whole jobs, each run by one function from one settings object (for the CLI, the examples, the benches)."""
