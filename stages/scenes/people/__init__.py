"""People in the scenes: pedestrians rigged and posed at the gait phase of their simulated walk.

* ``gait/``       — the Skeletal Motion Analyzer: gait-phase matching of walkers
* ``pedestrians`` — pedestrians posed by gait-phase matching
* ``skeletons``   — per-frame skeleton rows of the posed pedestrians
"""
