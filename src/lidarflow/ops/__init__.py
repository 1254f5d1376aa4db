"""Pure torch maths of the pipeline: the differentiable warp and the Gaussian filter of the loss."""

from lidarflow.ops.gaussian import gaussian_blur, gaussian_kernel1d, opencv_sigma
from lidarflow.ops.warp import warp

__all__ = ["gaussian_blur", "gaussian_kernel1d", "opencv_sigma", "warp"]
