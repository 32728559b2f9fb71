"""The wire-chaser task: configuration, wire geometry, layout, ring trajectories and touches."""
