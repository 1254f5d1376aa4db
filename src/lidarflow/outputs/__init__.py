"""What lidarflow writes for other programs to read: the ``predict`` command's output bags
(grids, the input's messages copied beside them) and the ONNX model files of ``export``.

Apart from :mod:`lidarflow.predict`, the runtime a robot imports: outputs import the runtime,
never the other way round.
"""
