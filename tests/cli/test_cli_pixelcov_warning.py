"""calibrate --walls's warning on loose pixel covariances says which case it met."""

from types import SimpleNamespace

import numpy as np
import pytest

from bayescal.cli.pixelcov import _warn_loose_along


def _data(sd_big, n_big, n=100):
    """n rows, 0.1 px across the ring; n_big of them sd_big px in one direction, the rest 1."""
    cov = np.tile(np.diag([0.01, 1.0]), (n, 1, 1))
    cov[:n_big, 1, 1] = sd_big**2
    return SimpleNamespace(pixel_cov=cov, pixel_table=SimpleNamespace(path="laser.csv"))


def test_most_rows_loose_is_the_along_ring_default():
    with pytest.warns(UserWarning, match=r"up to 5 px \(along the ring\).*--along-sd 1"):
        _warn_loose_along(_data(5.0, 100))


def test_a_few_loose_rows_are_uncertain_points_not_the_along_sd():
    # after `extract --along-sd 1` a few points keep an sd of tens of px (measured: up to 66 px
    # in 0-13 of ~340 unflagged rows on the third renderer's images); the advice to pass
    # --along-sd 1 would be wrong there
    with pytest.warns(UserWarning, match=r"up to 66 px in 3 of 100 rows") as rec:
        _warn_loose_along(_data(66.0, 3))
    assert "--along-sd" not in str(rec[0].message)


def test_no_warning_when_every_sd_is_within_2_px(recwarn):
    _warn_loose_along(_data(1.5, 100))
    assert not [w for w in recwarn if "pixel sds" in str(w.message)]
