"""The wire-chaser task: configuration, wire geometry, ring trajectories and touches."""
