"""Capture at a real bench. So far: HDR merging and camera response calibration (:mod:`.hdr`),
and colour calibration from a ColorChecker (:mod:`.color`). Devices, the serial controller, the
LCD's geometric and decay calibration and the capture session follow."""

from .hdr import HDRResult, Response, calibrate_response, hat_weight, merge_hdr

__all__ = ["Response", "calibrate_response", "merge_hdr", "HDRResult", "hat_weight"]
