"""The study's image metrics on synthetic images with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.perception import metrics as P

WHITE, BLACK, RED, DARK, GREY = (255, 255, 255), (0, 0, 0), (0, 0, 255), (20, 20, 20), (128, 128, 128)


def gauge(pointer_rows=(20, 60), size=100, face=WHITE, background=GREY):
    """A white square face with a red band and a dark vertical pointer, on grey."""
    img = np.full((size, size, 3), background, np.uint8)
    img[10:90, 10:90] = face
    img[10:25, 10:90] = RED
    if pointer_rows is not None:
        img[pointer_rows[0]:pointer_rows[1] + 1, 48:52] = DARK
    img[0:100, 0:4] = DARK  # dark housing outside the face: never the pointer
    return img


def test_contrast_and_saturation_of_uniform_images():
    assert P.rms_contrast(np.full((8, 8), 255, np.uint8)) == 0.0
    assert P.rms_contrast(np.zeros((8, 8), np.uint8)) == 0.0
    assert P.high_intensity_ratio(np.full((8, 8), 255, np.uint8)) == 1.0
    assert P.high_intensity_ratio(np.zeros((8, 8), np.uint8)) == 0.0
    assert P.high_intensity_ratio(np.full((8, 8), 240, np.uint8)) == 0.0  # strictly above 240


def test_half_black_half_white_and_half_saturated_crop():
    img = np.zeros((10, 10), np.uint8)
    img[:, 5:] = 255
    assert P.rms_contrast(img) == pytest.approx(0.5)
    half = np.full((10, 10), 100, np.uint8)
    half[:5] = 250
    assert P.high_intensity_ratio(half) == 0.5


def test_gauge_mask_thresholds():
    px = np.array([[RED, (0, 0, 120), WHITE, (200, 200, 200), (150, 150, 150), (255, 0, 0), BLACK]], np.uint8)
    # red; dark red (V 120 >= 50, S 255); white; light grey (S 0, V 200); grey (V 150); blue; black
    assert P.gauge_mask(px).tolist() == [[True, True, True, True, False, False, False]]


def test_pointer_of_known_height_and_ratio():
    roi = (0, 0, 100, 100)
    assert P.pointer_height(gauge((20, 60)), roi) == 40
    assert P.pointer_height(gauge(None), roi) == 0  # only the housing is dark: not inside
    ratios = P.oil_height_ratio([gauge((20, 60)), gauge((40, 60)), gauge(None)], roi)
    assert ratios == [1.0, 0.5, 0.0]
    assert P.pointer_height(gauge((20, 60)), (40, 30, 20, 20)) == 19  # crop rows 30..49 only


def test_first_frame_without_pointer_and_bad_roi():
    with pytest.raises(ValueError, match="first frame"):
        P.oil_height_ratio([gauge(None)], (0, 0, 100, 100))
    with pytest.raises(ValueError, match="roi"):
        P.pointer_height(gauge(), (50, 50, 80, 80))
