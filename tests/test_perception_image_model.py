"""The image model: each effect on small synthetic images, seeded; the whole model's contract."""

from __future__ import annotations

import math

import numpy as np
import pytest

from endocam.perception.image_model import (
    ImageModelConfig,
    add_highlights,
    add_noise,
    degrade,
    motion_blur,
    scale_brightness,
)

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

GREY_DN = 128  # DN, a mid-grey test image
RTOL_STD = 0.05  # unitless, a noise std measured over 3 × 200² samples
ROUND_DN = 1  # DN, one rounding step of the 8-bit output


def grey(h: int = 60, w: int = 80, value: int = GREY_DN) -> np.ndarray:
    return np.full((h, w, 3), value, dtype=np.uint8)


def test_noise_has_the_configured_std() -> None:
    img = grey(200, 200)
    read, shot = 2.0, 4.0
    out = add_noise(img, read, shot, np.random.default_rng(0)).astype(float)
    expected = math.sqrt(read**2 + shot**2 * GREY_DN / 255.0)
    assert abs(out.std() / expected - 1.0) < RTOL_STD
    assert abs(out.mean() - GREY_DN) < 0.1


def test_motion_blur_smears_along_the_velocity_and_keeps_the_light() -> None:
    img = np.zeros((41, 41, 3), dtype=np.uint8)
    img[20, 20] = 255
    out = motion_blur(img, (10.0, 0.0))  # 10 px to the right
    lit = np.argwhere(out[..., 0] > 0)
    assert set(lit[:, 0]) <= {19, 20, 21}  # rows: the anti-aliased line's width only
    span = lit[:, 1].max() - lit[:, 1].min()
    assert 9 <= span <= 13
    assert abs(int(out[..., 0].sum()) - 255) <= ROUND_DN * len(lit)
    np.testing.assert_array_equal(motion_blur(img, (0.3, 0.2)), img)  # under a pixel


def test_brightness_gain_scales_and_saturates() -> None:
    out = scale_brightness(grey(value=100), 1.2)
    assert np.all(out == 120)
    assert np.all(scale_brightness(grey(value=250), 1.2) == 255)


def test_a_highlight_is_white_at_its_centre_and_fades() -> None:
    out = add_highlights(grey(), [(40.0, 30.0)], [2.0])
    assert np.all(out[30, 40] == 255)
    assert np.all(out[30, 40 + 8] == GREY_DN)  # 4 sigma away: untouched
    assert GREY_DN < out[30, 42, 0] < 255


def test_degrade_is_seeded_and_off_means_identity() -> None:
    img = np.random.default_rng(1).integers(0, 256, size=(30, 40, 3), dtype=np.uint8)
    cfg = ImageModelConfig()
    a = degrade(img, cfg, np.random.default_rng(7), (200.0, 50.0))
    b = degrade(img, cfg, np.random.default_rng(7), (200.0, 50.0))
    c = degrade(img, cfg, np.random.default_rng(8), (200.0, 50.0))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    off = ImageModelConfig(
        exposure=0.0,
        gain_range=(1.0, 1.0),
        highlight_rate=0.0,
        read_noise_dn=0.0,
        shot_noise_dn=0.0,
    )
    np.testing.assert_array_equal(degrade(img, off, np.random.default_rng(0), (500.0, 0.0)), img)


def test_highlights_land_on_the_given_sites() -> None:
    cfg = ImageModelConfig(
        exposure=0.0,
        gain_range=(1.0, 1.0),
        highlight_rate=5.0,
        read_noise_dn=0.0,
        shot_noise_dn=0.0,
    )
    out = degrade(grey(), cfg, np.random.default_rng(3), sites_px=[(10.0, 10.0)])
    assert np.all(out[10, 10] == 255)
    assert np.all(out[50, 70] == GREY_DN)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"exposure": -1.0},
        {"gain_range": (0.0, 1.0)},
        {"gain_range": (1.2, 1.0)},
        {"highlight_rate": math.nan},
        {"highlight_radius_px": (0.0, 1.0)},
        {"read_noise_dn": -0.1},
    ],
)
def test_bad_configs_are_refused(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        ImageModelConfig(**kwargs)


def test_a_non_image_is_refused() -> None:
    with pytest.raises(ValueError, match="image"):
        motion_blur(np.zeros((4, 4)), (2.0, 0.0))


def test_a_blur_longer_than_the_image_is_shortened_to_its_diagonal() -> None:
    img = np.zeros((24, 32, 3), dtype=np.uint8)
    img[12, 16] = 255
    huge = motion_blur(img, (1e7, 0.0))  # a square kernel this long would need 4e14 bytes
    diagonal = motion_blur(img, (40.0, 0.0))  # the 24x32 image's diagonal: 40 px
    assert np.array_equal(huge, diagonal)
