"""Offline evaluation and benchmarks: suture-eval, suture-order-bench, suture-recon-bench.

The only package allowed to import every stage.
"""
