"""The synthetic iCub world: a simulator of the robot the paper used, apart from the library.

- ``sim.world``: objects, their labels (Tables I, II, IV), scenes (§V) and the
  world's recordings;
- ``sim.sensors``: the raw payloads a robot bridge sends (§II-C);
- ``sim.data``: the simulator's own world files (``generic_world.json``); the
  paper's world file stays in ``core/data`` because the service reads its
  vocabulary and the planner its applicability and contexts.

The service never imports this package: it runs on what a robot sends. The
experiments, the benchmarks, the tests and ``contextweb bridge simulate`` do.
"""
