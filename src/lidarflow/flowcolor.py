"""The standard optical-flow colour wheel (Baker et al., as in Middlebury and RAFT's
``flow_to_image``): a flow as an RGB picture, in NumPy alone."""

from __future__ import annotations

import numpy as np

__all__ = ["flow_to_rgb"]


def _colour_wheel() -> np.ndarray:
    # The Middlebury wheel's segments, red-yellow-green-cyan-blue-magenta: length, start
    # colour, and the channel that ramps up (+1) or down (-1) along it.
    segments = (
        (15, (255, 0, 0), 1, 1),
        (6, (255, 255, 0), 0, -1),
        (4, (0, 255, 0), 2, 1),
        (11, (0, 255, 255), 1, -1),
        (13, (0, 0, 255), 0, 1),
        (6, (255, 0, 255), 2, -1),
    )
    parts = []
    for length, start, channel, direction in segments:
        ramp = np.floor(255 * np.arange(length) / length)
        part = np.tile(np.array(start, float), (length, 1))
        part[:, channel] = ramp if direction == 1 else 255 - ramp
        parts.append(part)
    return np.concatenate(parts)


_WHEEL = _colour_wheel()


def flow_to_rgb(flow: np.ndarray, max_magnitude: float | None = None) -> np.ndarray:
    """Colour-code flow ``(2, H, W)`` (channel 0 column, 1 row displacement): hue is the
    direction, saturation the magnitude (normalised by ``max_magnitude``, default the largest).

    >>> flow_to_rgb(np.zeros((2, 1, 1)))[0, 0].tolist()
    [255, 255, 255]
    """
    u = np.nan_to_num(np.asarray(flow[0], np.float64))
    v = np.nan_to_num(np.asarray(flow[1], np.float64))
    magnitude = np.hypot(u, v)
    scale = max_magnitude or float(magnitude.max())
    if scale > 0:
        u, v, magnitude = u / scale, v / scale, magnitude / scale
    n = len(_WHEEL)
    angle = np.arctan2(-v, -u) / np.pi
    position = (angle + 1) / 2 * (n - 1)
    k0 = np.floor(position).astype(int)
    k1 = (k0 + 1) % n
    frac = (position - k0)[..., None]
    colour = ((1 - frac) * _WHEEL[k0] + frac * _WHEEL[k1]) / 255
    radius = np.clip(magnitude, 0, 1)[..., None]
    colour = 1 - radius * (1 - colour)
    return np.floor(255 * colour).astype(np.uint8)
