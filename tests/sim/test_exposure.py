"""The camera's exposure (thesis 5.4.1, Fig. 5.9b): the auto-exposure loop follows a step in
the scene's light a frame late and as a first-order system with its time constant, frames
saturate at 255, and a fixed exposure keeps its gain."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.sim.exposure import Exposure, mean_luma

FPS = 30.0
DT = 1 / FPS
TAU = 0.4


def scene(mean: float, seed: int = 0) -> np.ndarray:
    """A textured frame's light (float32, as the renderer's mean over an exposure)."""
    rng = np.random.default_rng(seed)
    return (mean * rng.uniform(0.5, 1.5, (120, 160, 3))).astype(np.float32)


def run(ae: Exposure, light: np.ndarray, frames: int) -> list[float]:
    return [mean_luma(ae.frame(light, DT)) for _ in range(frames)]


@pytest.mark.parametrize("step", [2.0, 0.5])
def test_after_a_step_in_the_light_the_frames_are_off_then_reach_the_target_in_3_tau(step):
    """Settled on a scene at the target, the light steps by ×2 (a brighter view) or ×0.5: the
    first frame is off by the whole step (the loop meters the frame it delivered and sets the
    next), after τ the log error is e⁻¹ of the step's, after 3τ the mean is within 5 % of the
    target; the gain ends at 1/step (a no-op loop fails every one of these)."""
    before = scene(60.0)
    ae = Exposure(target=mean_luma(before), tau=TAU)
    settled = run(ae, before, 10)
    assert ae.gain == pytest.approx(1.0, abs=0.01) and settled[-1] == pytest.approx(ae.target, 0.01)

    after = before * np.float32(step)
    means = run(ae, after, round(5 * TAU * FPS) + 1)
    log_error = [math.log(m / ae.target) for m in means]
    assert log_error[0] == pytest.approx(math.log(step), rel=0.02)  # the step's first frame
    one_tau = round(TAU * FPS)  # frames after the first that took a gain from the loop
    assert log_error[one_tau] / log_error[0] == pytest.approx(math.exp(-1), abs=0.03)
    assert abs(means[one_tau] / ae.target - 1) > 0.2  # still visibly off after τ
    assert abs(means[3 * one_tau] / ae.target - 1) < 0.05
    assert abs(means[-1] / ae.target - 1) < 0.02
    assert ae.gain == pytest.approx(1 / step, rel=0.03)


def test_pixels_saturate_at_255_and_the_loop_comes_down_from_saturation_more_slowly():
    """Too much light clips at 255 (never wraps around the 8 bits); a saturated frame meters
    darker than its light, so the first correction is smaller than an unclipped one's and the
    frames stay white for about τ (3× the light needed); the loop still settles on the
    target."""
    light = np.full((60, 80, 3), 200.0, np.float32)
    ae = Exposure(target=100.0, tau=TAU, gain=3.0)
    frame = ae.expose(light)
    assert frame.dtype == np.uint8 and (frame == 255).all()  # 600 → 255, not 600 mod 256
    ae.frame(light, DT)
    alpha = 1 - math.exp(-DT / TAU)
    assert ae.gain == pytest.approx(3.0 * (100 / 255) ** alpha, rel=1e-6)  # metered 255
    assert ae.gain > 3.0 * (100 / 600) ** alpha  # what the light itself would have given
    means = run(ae, light, round(8 * TAU * FPS))
    assert means[:10] == pytest.approx([255] * 10)  # saturated for about τ
    assert abs(means[round(4 * TAU * FPS)] / 100 - 1) < 0.1
    assert abs(means[-1] / 100 - 1) < 0.02 and ae.gain == pytest.approx(0.5, rel=0.02)


def test_a_black_scene_drives_the_gain_to_its_limit_and_no_further():
    ae = Exposure(target=100.0, tau=TAU, max_gain=16.0)
    means = run(ae, np.zeros((10, 10, 3), np.float32), 200)
    assert ae.gain == 16.0 and means[-1] == 0.0


def test_a_fixed_exposure_keeps_its_gain_and_gives_the_light_as_it_is():
    """The thesis's fixed settings: the step stays in the frames; at gain 1 a frame is the
    light truncated to 8 bits, bit for bit (the gaze experiment's frames before the model)."""
    before = scene(60.0)
    ae = Exposure(target=mean_luma(before), auto=False)
    run(ae, before, 5)
    means = run(ae, before * np.float32(2.0), 40)
    assert ae.gain == 1.0
    assert means[-1] == pytest.approx(2 * ae.target, rel=0.02)
    assert np.array_equal(ae.expose(before), before.astype(np.uint8))


def test_mean_luma_weights_green_most():
    one = np.zeros((2, 2, 3), np.uint8)
    r, g, b = (one.copy() for _ in range(3))
    r[..., 0], g[..., 1], b[..., 2] = 255, 255, 255
    assert [round(mean_luma(x), 2) for x in (r, g, b)] == [76.24, 149.69, 29.07]
