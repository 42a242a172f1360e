"""What the camera images of the gaze experiment (thesis 5.4.1) are judged by: dense optical
flow (Farnebäck) as angular image speed, perceptual blur (Crete et al. 2007), and whether the
two objects are localised in a frame: the single-coloured cup by HSV segmentation, the
textured box by feature matching (ORB in place of the thesis's SIFT: both rely on corners
that motion blur wipes out)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


def grey(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)


def flow_rmse_deg_s(
    prev: np.ndarray, cur: np.ndarray, deg_per_px: tuple[float, float], fps: float
) -> float:
    """RMS over the image of the dense optical flow (Farnebäck) between two frames, in deg/s:
    pixels per frame × degrees per pixel (u, v) × frames per second."""
    flow = cv2.calcOpticalFlowFarneback(grey(prev), grey(cur), None, 0.5, 4, 21, 3, 5, 1.1, 0)
    deg = flow * np.asarray(deg_per_px, np.float32) * fps
    return float(np.sqrt(np.mean(np.sum(deg**2, axis=-1))))


def blur(rgb: np.ndarray) -> float:
    """Crete et al. (2007) no-reference perceptual blur, 0 (sharp) … 1 (blurred): blur the
    image again along each axis (9-tap box) and see how much of its neighbour-to-neighbour
    variation that takes away; a sharp image loses much, a blurred one little."""
    f = grey(rgb).astype(np.float64)
    result = 0.0
    for axis in (0, 1):
        k = (9, 1) if axis == 0 else (1, 9)
        b = cv2.blur(f, (k[1], k[0]))
        d_f = np.abs(np.diff(f, axis=axis))
        d_b = np.abs(np.diff(b, axis=axis))
        v = np.maximum(0.0, d_f - d_b)
        s_f, s_v = d_f.sum(), v.sum()
        result = max(result, (s_f - s_v) / s_f if s_f > 0 else 1.0)
    return float(result)


@dataclass
class CupFinder:
    """The green cup by HSV segmentation: found when the largest green region's area is
    within ``tolerance`` of the still reference's and its centre within ``max_offset`` px of
    where the cup is."""

    reference_area: float
    tolerance: float = 0.35
    max_offset: float = 15.0
    hue: tuple[int, int] = (45, 85)  # OpenCV hue (0-180): green
    min_saturation: int = 100
    min_value: int = 60

    @staticmethod
    def mask(rgb: np.ndarray, hue=(45, 85), min_saturation=100, min_value=60) -> np.ndarray:
        hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
        lo = np.array([hue[0], min_saturation, min_value], np.uint8)
        hi = np.array([hue[1], 255, 255], np.uint8)
        return cv2.inRange(hsv, lo, hi)

    @classmethod
    def from_reference(cls, rgb: np.ndarray) -> CupFinder:
        area = cls.largest(cls.mask(rgb))[0]
        if area <= 0:
            raise ValueError("no green cup in the reference frame")
        return cls(area)

    @staticmethod
    def largest(mask: np.ndarray) -> tuple[float, np.ndarray]:
        n, _, stats, centroids = cv2.connectedComponentsWithStats(mask)
        if n <= 1:
            return 0.0, np.full(2, np.nan)
        k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        return float(stats[k, cv2.CC_STAT_AREA]), centroids[k]

    def found(self, rgb: np.ndarray, where: np.ndarray) -> bool:
        m = self.mask(rgb, self.hue, self.min_saturation, self.min_value)
        area, centre = self.largest(m)
        if area <= 0:
            return False
        ok_area = abs(area - self.reference_area) <= self.tolerance * self.reference_area
        return bool(ok_area and np.linalg.norm(centre - where) <= self.max_offset)


@dataclass
class TextureFinder:
    """The textured box by feature matching: ORB features of a still reference view of it
    matched (ratio test) into a frame, a homography by RANSAC; found with enough inliers and
    the box's centre mapped within ``max_offset`` px of where it is."""

    keypoints: tuple
    descriptors: np.ndarray
    centre: np.ndarray
    min_inliers: int = 15
    max_offset: float = 15.0

    @staticmethod
    def _orb():
        return cv2.ORB_create(nfeatures=1500, fastThreshold=12)

    @classmethod
    def from_reference(cls, rgb: np.ndarray, box: tuple[int, int, int, int]) -> TextureFinder:
        """``box``: (u0, v0, u1, v1) of the object in the reference frame."""
        u0, v0, u1, v1 = box
        mask = np.zeros(rgb.shape[:2], np.uint8)
        mask[v0:v1, u0:u1] = 255
        kp, desc = cls._orb().detectAndCompute(grey(rgb), mask)
        if desc is None or len(kp) < 30:
            raise ValueError("too few features on the textured box in the reference frame")
        return cls(kp, desc, np.array([(u0 + u1) / 2, (v0 + v1) / 2]))

    def found(self, rgb: np.ndarray, where: np.ndarray) -> bool:
        kp, desc = self._orb().detectAndCompute(grey(rgb), None)
        if desc is None or len(kp) < self.min_inliers:
            return False
        pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(self.descriptors, desc, k=2)
        good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < 0.75 * p[1].distance]
        if len(good) < self.min_inliers:
            return False
        src = np.float32([self.keypoints[m.queryIdx].pt for m in good])
        dst = np.float32([kp[m.trainIdx].pt for m in good])
        H, inliers = cv2.findHomography(src, dst, cv2.RANSAC, 4.0)
        if H is None or int(inliers.sum()) < self.min_inliers:
            return False
        c = H @ np.array([*self.centre, 1.0])
        return bool(np.linalg.norm(c[:2] / c[2] - where) <= self.max_offset)
