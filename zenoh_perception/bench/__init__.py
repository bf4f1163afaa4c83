"""Benchmark and stress scripts (not tests): they print figures side by side with a baseline.

Run them through ``zenoh-perception bench`` or ``python -m zenoh_perception.bench.<name>``.
"""
