"""MuJoCo only: the wire-chaser scene, the camera arm's drawing, rendering and ray visibility.

The only package that imports MuJoCo; the episode loop (:mod:`endocam.runner.episode`) runs
without it.
"""
