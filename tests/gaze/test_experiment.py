"""The gaze experiment's measures on images with known answers, and the experiment itself
(thesis 5.4.1): stabilised flow error at most half the unstabilised, and both objects
localised more often with the stabiliser on, with fixed exposure and with the camera's
auto-exposure (Fig. 5.9b)."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from itertools import pairwise

import cv2
import numpy as np
import pytest

from experiments.gaze import GazeExperimentConfig, run_object
from experiments.image_quality import CupFinder, blur, flow_rmse_deg_s
from tests.conftest import ROOT


def texture(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 255, (60, 80, 3), dtype=np.uint8)
    return cv2.resize(small, (320, 240), interpolation=cv2.INTER_CUBIC)


def test_flow_of_a_known_shift_in_degrees_per_second():
    img = texture()
    shifted = np.roll(img, 4, axis=1)  # 4 px to the right
    deg = (0.025, 0.0167)
    measured = flow_rmse_deg_s(img[:, 20:-20], shifted[:, 20:-20], deg, 30.0)
    assert measured == pytest.approx(4 * 0.025 * 30, rel=0.1)
    assert flow_rmse_deg_s(img, img, deg, 30.0) < 0.01


def test_blur_grows_with_the_blur_of_the_image():
    img = texture()
    values = [blur(img)] + [blur(cv2.GaussianBlur(img, (0, 0), s)) for s in (1, 2, 4)]
    assert all(b > a for a, b in pairwise(values)), values
    assert values[0] < 0.4 and values[-1] > 0.6


def test_the_cup_finder_wants_the_cup_where_it_is():
    img = np.full((240, 320, 3), 200, np.uint8)
    cv2.circle(img, (160, 120), 25, (30, 170, 40), -1)
    finder = CupFinder.from_reference(img)
    assert finder.found(img, np.array([160.0, 120.0]))
    assert not finder.found(img, np.array([220.0, 120.0]))  # not where the cup should be
    smeared = cv2.blur(img, (101, 1))  # motion blur: the green washes out
    assert not finder.found(smeared, np.array([160.0, 120.0]))


@pytest.mark.timeout(600)
def test_stabilised_flow_error_is_at_most_half_and_localisation_succeeds_more(tmp_path):
    """Half a period of the hip swing (2 s at 0.25 Hz: out to one side and back through the
    start), both modes, both objects, with the robot's sensor models: the flow error falls to
    11 % (0.29 of 2.79 deg/s measured; a whole period, 4 s, gave 7 % and took twice as long)."""
    out = subprocess.run(
        [sys.executable, "-m", "avs.cli", "gaze-experiment", "--compare", "--duration", "2",
         "--out", str(tmp_path)],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    m = json.loads((tmp_path / "metrics.json").read_text())
    off, on = m["off"], m["on"]
    assert on["flow_rmse_deg_s"]["mean"] <= 0.5 * off["flow_rmse_deg_s"]["mean"], m
    assert on["blur"]["mean"] < off["blur"]["mean"]
    for obj in ("cup", "textured"):
        assert on["localization_success"][obj] > off["localization_success"][obj], m
    # with the sensor models (the default): 0.024° RMS stabilised, 8.7° not (2 s measured)
    assert on["gaze_error_deg"]["cup"] < 0.1 and off["gaze_error_deg"]["cup"] > 5.0
    assert "decrease" in out.stdout and "localised: textured" in out.stdout
    for d in (tmp_path, tmp_path / "on", tmp_path / "off"):
        for name in ("flow.png", "blur.png", "brightness.png"):
            assert (d / name).stat().st_size > 1000
    run = json.loads((tmp_path / "on" / "metrics.json").read_text())
    assert set(run) >= {"flow_rmse_deg_s", "blur", "localization_success"}
    assert set(run["flow_rmse_deg_s"]) == {"mean", "std", "max"}


@pytest.mark.timeout(300)
def test_with_auto_exposure_the_stabilised_cup_is_localised_more_often():
    """Fig. 5.9b with the camera's auto-exposure: 2 s of the swing (out to one side and back
    through the cup), the cup only. Unstabilised the view passes the table's edge and the
    floor, brighter than the still view, and the loop turns the gain down (to 0.91) and
    is still off when the cup comes back; stabilised the view, and so the gain, stays (within
    1 %). Localised: 40 % unstabilised, 100 % stabilised measured."""
    config = GazeExperimentConfig(duration=2.0, exposure_mode="auto")
    off = run_object(replace(config, stabilize=False), "cup")
    on = run_object(config, "cup")
    assert np.mean(on.found) > np.mean(off.found), (np.mean(on.found), np.mean(off.found))
    assert np.mean(on.found) == 1.0
    assert min(off.gain) < 0.95, off.gain  # the loop worked
    assert max(abs(g - 1) for g in on.gain) < 0.01, on.gain


@pytest.mark.timeout(300)
def test_the_stabiliser_fixates_where_the_odometry_puts_the_target():
    """The controller takes the platform's pose from the odometry, as a robot must: with the
    odometry believing the platform 3 cm to the left of where it stands, the stabilised camera
    looks 3 cm beside the cup, 1.5 m ahead (1.1° measured; atan(0.03 / 1.5) = 1.15°), where
    with a true belief it is on it (0.01°). 0.3 s of the swing."""
    config = GazeExperimentConfig(duration=0.3)
    right = run_object(config, "cup")
    off = run_object(replace(config, odometry_error=(0.0, 0.03, 0.0)), "cup")
    assert right.error_deg[-1] < 0.05, right.error_deg
    assert off.error_deg[-1] == pytest.approx(np.degrees(np.arctan2(0.03, 1.5)), rel=0.1)
