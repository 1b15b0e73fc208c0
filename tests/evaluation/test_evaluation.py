"""Accuracy evaluation against a reference: incomparable maps refused."""

import numpy as np
import pytest

from skintopo.errors import SkinTopoError
from skintopo.evaluation import evaluate_height
from skintopo.heightmap import HeightMap


def test_evaluation_refuses_incomparable_maps():
    a = HeightMap(np.random.default_rng(0).normal(size=(64, 64)), 10.0)
    with pytest.raises(SkinTopoError, match="different pixel sizes"):
        evaluate_height(a, HeightMap(a.z, 20.0))
    with pytest.raises(SkinTopoError, match="do not overlap"):
        evaluate_height(a, HeightMap(np.random.default_rng(1).normal(size=(64, 64)), 10.0))
