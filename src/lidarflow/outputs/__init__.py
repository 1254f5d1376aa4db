"""What lidarflow writes for other programs to read: the ``predict`` command's output bags and
the ONNX files of ``export``. Outputs import the runtime (:mod:`lidarflow.predict`), never the
other way round.
"""
