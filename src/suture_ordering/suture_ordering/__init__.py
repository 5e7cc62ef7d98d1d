"""Ordering stage (not built yet, issue 4): mask cleaning, centreline, cut tip, sequence search, ordering_node."""
