"""The episode loop (no MuJoCo), experiment batches and the output files a run writes.

:mod:`endocam.runner.episode` is headless: it imports no simulator. Rendering
(:mod:`endocam.runner.outputs`, :mod:`endocam.runner.experiments`) reaches MuJoCo through
:mod:`endocam.sim` inside the functions that render.
"""
