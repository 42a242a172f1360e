"""A camera's exposure: fixed, or an auto-exposure (AE) loop that adapts to the scene's light
with a delay (thesis 5.4.1, Fig. 5.9b).

The thesis repeats the object-localisation-while-moving experiment with the foveal cameras'
settings fixed and with the cameras' automatic mode, noting that "such adaption takes time if
the illumination changes": while the robot moves, what the camera sees gets brighter or darker,
and an AE loop that follows it leaves the frames over- or under-exposed for a while.

The model is a gain on the light a frame integrated (the renderer's colours, taken as linear):

    frame_k = min(255, g_k · light_k)         (8 bit: saturation, then truncation)
    m_k     = mean luma of frame_k            (Rec. 601: 0.299 R + 0.587 G + 0.114 B)
    ln g_{k+1} = ln g_k + α · (ln target − ln m_k),   α = 1 − exp(−Δt/τ)

A real AE meters the frame it just delivered and sets the next one's exposure, so the loop is
one frame late and meters the saturated, quantised frame (a clipped frame reads darker than its
light is, and the loop comes down more slowly from over-exposure). Without saturation the frame
mean approaches the target as a first-order system with time constant τ in the log domain: after
a step in the scene's light by a factor r, ln(m/target) = ln r · exp(−t/τ) (within 5 % of ln r
after 3τ). Typical cameras settle in 0.5-1.5 s, i.e. τ ≈ 0.3-0.5 s. The gain is bounded by
what the sensor can do (integration time and analogue gain together); the integration time that
makes motion blur is a separate setting and not what this loop changes here.

With ``auto`` off the gain stays where it was configured, as in the thesis's fixed-settings
runs ("configured once and then kept fixed during the experiment").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Rec. 601 luma weights (the same as OpenCV's RGB → grey)
LUMA = np.array([0.299, 0.587, 0.114])


def mean_luma(rgb: np.ndarray) -> float:
    """The mean brightness an AE meters: the mean of the frame's luma, 0-255."""
    return float(np.mean(rgb.reshape(-1, 3), axis=0) @ LUMA)


@dataclass
class Exposure:
    """One camera's exposure: ``frame(light, dt)`` gives the 8-bit frame of a frame's light
    and, with ``auto``, meters it to set the gain of the next frame."""

    #: the mean luma the AE holds, 0-255
    target: float
    #: adapt (the camera's automatic mode), or keep ``gain`` (fixed settings)
    auto: bool = True
    #: the AE loop's time constant, s
    tau: float = 0.4
    #: the gain on the light of the next frame (1: the light as rendered)
    gain: float = 1.0
    #: the range the sensor's exposure time and analogue gain allow together
    min_gain: float = 1 / 16
    max_gain: float = 16.0

    def expose(self, light: np.ndarray) -> np.ndarray:
        """The frame of ``light`` (H×W×3, 0-255 as rendered) at the current gain: pixels that
        get more light than 255 saturate."""
        return np.clip(light * np.float32(self.gain), 0, 255).astype(np.uint8)

    def update(self, frame: np.ndarray, dt: float) -> float:
        """Meter ``frame`` (the one just delivered) and set the next frame's gain, ``dt``
        seconds later; returns the gain. A fixed exposure keeps its gain."""
        if not self.auto:
            return self.gain
        alpha = 1.0 - math.exp(-dt / self.tau)
        error = math.log(self.target / max(mean_luma(frame), 0.5))
        self.gain = min(self.max_gain, max(self.min_gain, self.gain * math.exp(alpha * error)))
        return self.gain

    def frame(self, light: np.ndarray, dt: float) -> np.ndarray:
        """Expose a frame, then meter it for the next one ``dt`` later."""
        img = self.expose(light)
        self.update(img, dt)
        return img
