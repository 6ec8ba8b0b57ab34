"""The algorithms of the replication: SAC (paper version), DRL-EG, and the baselines.

Look an algorithm up by name with :func:`baselines.registry.get_algorithm`.
"""
