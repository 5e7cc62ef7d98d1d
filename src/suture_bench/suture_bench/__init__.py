"""Offline evaluation and benchmarks (suture-eval, issue 7); the only package allowed to import every stage."""
