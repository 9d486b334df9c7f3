"""Benchmarks behind `skelasm bench`: each prints a table and writes a plot (PNG)."""
