"""Speed benchmarks against the libraries a user would otherwise use (not timed tests)."""
