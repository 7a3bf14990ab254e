"""Benchmarks: ``make bench`` prints medians and writes ``bench/results.json``."""
