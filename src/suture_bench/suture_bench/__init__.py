# SPDX-License-Identifier: Apache-2.0
"""Offline evaluation and benchmarks: suture-eval, suture-fewshot, suture-order-bench, suture-recon-bench.

The only package allowed to import every stage.
"""
