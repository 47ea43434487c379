"""Whole jobs, each a settings dataclass and one function running it: what the CLI, examples and
benches call."""
