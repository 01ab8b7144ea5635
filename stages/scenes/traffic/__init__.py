"""Traffic sequences on any town of the contract (:mod:`carlaocc.stages.scenes.network`), procedural
or OpenDRIVE.

* ``simulation`` — traffic sequences: levels, spawning, integration, records (:func:`simulation.simulate_town`)
* ``vehicles``   — vehicles: IDM, leaders along the lanes, lane changes
* ``walkers``    — walkers on the walk graph, gait phase
* ``junctions``  — junction reservations shared by vehicles and walkers
"""
