"""The replay of recordings through :class:`bridge.Client` (``contextweb bridge replay``): folders of
PLY/PCD/WAV/CSV/NPY files (:mod:`bridge.tools.replay`), ROS bags (:mod:`bridge.tools.bags`) and
yarpdatadumper sessions (:mod:`bridge.tools.yarp`), cut into scenes by a mapping file
(:mod:`bridge.tools.mapping`, :mod:`bridge.tools.segments`) and encoded by :mod:`bridge.tools.payloads`.

Part of the robot's distribution (bridge/pyproject.toml) behind its ``bags`` extra: numpy, rosbags and
the file readers, never ``core``, ``app`` or ``storage``. The simulated robot (``contextweb bridge
simulate``) needs the world and the feature extraction, so it lives in the server's ``sim.robot``.
"""
