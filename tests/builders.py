"""Builders of test inputs shared by several test modules (``from builders import ...``; tests/ is on the path).

Each section is headed by the package whose tests use it; add yours under its own heading.
"""
from __future__ import annotations

import numpy as np

from rjfit.data.observations import Observations
from rjfit.model.blinn import radiance
from rjfit.sampler.priors import ParamPrior, Prior

# ============================================================================ sampler
# (tests/sampler/: the exactness tests by enumeration and by simulation-based calibration)

#: (shape, scale) of the inverse-gamma prior of sigma^2 in :func:`tiny_problem`'s prior.
TINY_SIGMA2_PRIOR = (3.0, 0.6)


def tiny_problem(seed=5):
    """A 2 x 2 image under 3 lights (12 observations) of two regions split down the middle, and a proper prior.

    The regions' truth is ``(I0, kd, gamma, sigma^2) = (10, 0.75, 4, 0.3)`` left and
    ``(10, 0.3, 15, 0.3)`` right; the prior is lognormal around the truth's I0 and gamma,
    uniform kd and inverse-gamma :data:`TINY_SIGMA2_PRIOR` sigma^2 (so sigma^2 integrates
    out analytically in the enumeration tests). Returns ``(observations, prior)``.
    """
    rng = np.random.default_rng(seed)
    H, W, L = 2, 2, 3
    pixel = np.repeat(np.arange(H * W), L)
    light = np.tile(np.arange(L), H * W).astype(np.int32)
    cos_ln = rng.uniform(0.3, 1.0, pixel.size)
    cos_hn = rng.uniform(0.6, 1.0, pixel.size)
    irradiance = rng.uniform(0.5, 1.5, pixel.size)
    col = pixel % W
    truth = np.array([[10.0, 0.75, 4.0, 0.3], [10.0, 0.3, 15.0, 0.3]])[col]
    mu = radiance(truth[:, 0], truth[:, 1], truth[:, 2], cos_ln, cos_hn, irradiance)
    y = mu + rng.normal(0, np.sqrt(0.3), pixel.size)
    obs = Observations(image_shape=(H, W), n_lights=L, pixel=pixel.astype(np.int64), light=light, y=y,
                       cos_ln=cos_ln, cos_hn=cos_hn, irradiance=irradiance, object_mask=np.ones((H, W), bool))
    prior = Prior(params=(ParamPrior("lognormal", np.log(10.0), 0.3), ParamPrior("uniform", 0.0, 1.0),
                          ParamPrior("lognormal", np.log(8.0), 0.6), ParamPrior("invgamma", *TINY_SIGMA2_PRIOR)))
    return obs, prior
