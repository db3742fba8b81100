"""Capture at a real bench. So far: HDR merging and camera response calibration (:mod:`.hdr`),
colour calibration from a ColorChecker (:mod:`.color`), and the LCD's drive curve and emission
decay written back into a scene file (:mod:`.display`), and the LCD's pose from its reflections
in a mirror sample (:mod:`.geometry`). Devices, the serial controller and the capture session
follow."""

from .hdr import HDRResult, Response, calibrate_response, hat_weight, merge_hdr

__all__ = ["Response", "calibrate_response", "merge_hdr", "HDRResult", "hat_weight"]
