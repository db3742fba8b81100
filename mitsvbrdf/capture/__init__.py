"""Capture at a real bench: so far HDR merging and camera response calibration (:mod:`.hdr`).
Devices, the serial controller, calibration of the LCD and the capture session follow."""

from .hdr import HDRResult, Response, calibrate_response, hat_weight, merge_hdr

__all__ = ["Response", "calibrate_response", "merge_hdr", "HDRResult", "hat_weight"]
