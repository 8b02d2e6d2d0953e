"""Benchmarks, separate from the tests: each run records machine, versions, inputs and figures."""
