"""Offline evaluation and benchmarks (suture-eval, not built yet: issue 7).

The only package allowed to import every stage.
"""
