"""Closed form of the paper's reflectance model (Lenoch et al. 2016, eq. 1-3).

    mu = I0 * E * ( kd/pi + (1 - kd) * N(g) * <h.n>^g ) * <l.n>

``E`` is the relative irradiance factor of an observation: the light's relative
intensity divided by r^2 for a point light, the relative intensity alone for a
directional light. ``N(g)`` is the energy normalisation of the Blinn-Phong lobe
given by Giesen (2009), "Derivation of Phong and Blinn-Phong BRDF normalization
factors".
"""
from __future__ import annotations

import numpy as np

__all__ = ["blinn_normalisation", "brdf", "radiance", "radiance_of_rows", "log_cos_power"]


def blinn_normalisation(gamma):
    """Giesen's normalisation factor ``(g+2)(g+4) / (8 pi (2^(-g/2) + g))``.

    With it, the lobe ``N(g) <h.n>^g <l.n>`` integrates to (nearly exactly) one over the
    hemisphere of light directions for normal incidence of the viewer.

    Parameters
    ----------
    gamma : float or array_like
        Blinn exponent ``g`` (> 0 in the model; any float is evaluated, without checks).

    Returns
    -------
    numpy.ndarray
        ``N(g)`` with the shape of ``gamma`` (a 0-d array for a scalar).
    """
    gamma = np.asarray(gamma, dtype=float)
    return (gamma + 2.0) * (gamma + 4.0) / (8.0 * np.pi * (np.exp2(-gamma / 2.0) + gamma))


def log_cos_power(cos_hn, gamma):
    """``<h.n>^g`` computed as ``exp(g log <h.n>)``, zero where ``<h.n> <= 0``.

    ``<h.n>`` of a valid observation is positive (both <l.n> and <v.n> are), so the clip
    only guards invalid inputs against NaN.
    """
    cos_hn = np.asarray(cos_hn, dtype=float)
    positive = cos_hn > 0.0
    log_cos = np.log(np.where(positive, cos_hn, 1.0))
    return np.where(positive, np.exp(gamma * log_cos), 0.0)


def brdf(kd, gamma, cos_hn):
    """The BRDF value ``kd/pi + (1 - kd) N(g) <h.n>^g`` (per steradian).

    Parameters
    ----------
    kd : float or array_like
        Diffuse fraction (``ks = 1 - kd``).
    gamma : float or array_like
        Blinn exponent ``g``; ``N(g)`` is :func:`blinn_normalisation`.
    cos_hn : float or array_like
        ``<h.n>`` per observation; the specular lobe is zero where ``<h.n> <= 0``
        (see :func:`log_cos_power`).

    Returns
    -------
    numpy.ndarray
        The BRDF with the broadcast shape of the inputs. No input is checked.
    """
    return kd / np.pi + (1.0 - kd) * blinn_normalisation(gamma) * log_cos_power(cos_hn, gamma)


def radiance(I0, kd, gamma, cos_ln, cos_hn, irradiance):
    """Closed-form radiance ``mu`` of eq. 2 for arrays of observations.

    Parameters
    ----------
    I0, kd, gamma : float or array_like
        Intensity scale, diffuse fraction (``ks = 1 - kd``) and Blinn exponent;
        broadcast against the observation arrays (e.g. per-observation region values).
    cos_ln, cos_hn : array_like
        ``<l.n>`` and ``<h.n>`` per observation; ``<l.n> <= 0`` gives zero radiance.
    irradiance : array_like
        Relative light intensity times ``1/r^2`` (1/r^2 = 1 for directional lights).

    Returns
    -------
    numpy.ndarray
        ``mu`` with the broadcast shape of the inputs.
    """
    cos_ln = np.asarray(cos_ln, dtype=float)
    return I0 * np.asarray(irradiance, dtype=float) * brdf(kd, gamma, cos_hn) * np.maximum(cos_ln, 0.0)


def radiance_of_rows(theta, rows, C, log_cos_hn):
    """Eq. 2 for observations each under its row of ``theta``: ``C (I0 kd / pi + I0 (1 - kd) N(g) <h.n>^g)``.

    The factors are taken per row and gathered per observation, so an observation costs one
    exponential: the form for the many draws a fit's summaries evaluate (:func:`radiance` is the
    term-by-term form, the tests' oracle).

    Parameters
    ----------
    theta : array_like, shape (R, >= 3)
        ``I0, kd, gamma`` (then anything) per row.
    rows : array_like of int, shape (N,)
        Each observation's row.
    C : ndarray, shape (N,)
        ``E <l.n>`` per observation (clipped at 0 by the caller where it may be negative).
    log_cos_hn : ndarray, shape (N,)
        ``log <h.n>`` per observation.

    Returns
    -------
    numpy.ndarray
        ``mu`` (N,). No input is checked.
    """
    theta = np.asarray(theta, dtype=float)
    I0, kd, gamma = theta[:, 0], theta[:, 1], theta[:, 2]
    diffuse, lobe = I0 * kd / np.pi, I0 * (1.0 - kd) * blinn_normalisation(gamma)
    return C * (diffuse[rows] + lobe[rows] * np.exp(gamma[rows] * log_cos_hn))
