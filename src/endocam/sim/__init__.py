"""MuJoCo scene and renderer of the wire-chaser world (the only module that speaks MuJoCo)."""
