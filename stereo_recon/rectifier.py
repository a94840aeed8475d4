"""CPU/GPU dispatch of stereo rectification for the streaming pass."""

from __future__ import annotations


class Rectifier:
    """Rectify a raw pair (left BGR, right grey): CPU cv2.remap with fixed-point maps, or the GPU path.

    rig: ``calib.rig.StereoRig``; use_gpu: rectify on a CUDA device through torch/kornia (``stereo_recon.gpu``)
    when the rig is not already rectified.
    """

    def __init__(self, rig, use_gpu: bool):
        self.gpu = None
        if use_gpu and not rig.rectified:
            from stereo_recon import gpu

            self.gpu = gpu.GpuRectifier(rig.rectification(alpha=0.0))  # float maps: exact positions
        # 16SC2 maps: OpenCV's fixed-point remap, ~1/32 px position steps, faster than float maps.
        self.rect = rig.rectification(alpha=0.0, map_type="16SC2")

    def __call__(self, left_bgr, right_gray):
        """(rectified left BGR, rectified right grey) of one raw pair, in the rectified left camera."""
        if self.gpu is not None:
            return self.gpu.rectify_pair(left_bgr, right_gray)
        from calib.rig import rectify_pair

        return rectify_pair(left_bgr, right_gray, self.rect)
