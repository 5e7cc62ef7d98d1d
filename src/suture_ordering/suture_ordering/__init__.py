"""Ordering stage (not built yet, issue 4).

Mask cleaning, centreline, cut tip, sequence search, ordering_node.
"""
