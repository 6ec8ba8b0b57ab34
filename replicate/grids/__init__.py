"""Grids of runs: profiles and budgets, seed-batch planning and time estimates, the local and
Ray executors, the options every grid command shares. Imports the store, never the claims,
reports or figures."""
