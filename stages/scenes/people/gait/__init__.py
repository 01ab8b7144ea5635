"""Skeletal Motion Analyzer: gait-phase matching of pedestrians (paper, appendix "Skeletal Motion
Analyzer"). Pure compute on arrays; nothing here opens a file or imports ``catalog``. A motion
clip enters as a :class:`~carlaocc.schemas.motion.MotionClip` (:func:`kinematics.clip_positions`)
or as the same plain arrays passed to :func:`kinematics.forward_kinematics`.

Frames and units: BVH is Y-up; forward kinematics converts once to our right-handed Z-up frame
(``(x, y, z)_ours = (z, x, y)_bvh``). Everything downstream is metres, seconds, radians, Z up.
Phase convention: phase 0 = maximum forward offset of the left ankle (left heel strike); phases
run over one full cycle (two steps) in [0, 1), phase index d <-> phase d / D.

Modules:

- ``kinematics``  forward kinematics of a skeleton (Y-up -> Z-up), the seven gait joints
- ``descriptor``  per-frame gait features and the window descriptor delta = [dx, theta_rel]
- ``cycles``      walking segment, gait period and phases of a walk; the canonical cycle
- ``walker``      phase-labelled walks: the procedural articulated walker, resampling, joint noise
- ``matching``    the Gaussian phase model (:class:`matching.GaitModel`) and its accuracy

The applied half (pedestrians matched and posed in a town's traffic) is
:mod:`carlaocc.stages.scenes.people.pedestrians`.
"""
