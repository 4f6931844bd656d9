"""Development tools that feed a running service through :class:`bridge.Client`: the simulated iCub
(``contextweb bridge simulate``) and the replay of recordings, bags and yarp sessions
(``contextweb bridge replay``).

They read recordings with numpy, soundfile, plyfile, rosbags and ``core`` (the payloads and the
feature extraction), so they ship with the server's distribution (the root pyproject.toml), not
with the robot's ``pip install ./bridge`` (bridge/pyproject.toml), which holds the client alone.
"""
