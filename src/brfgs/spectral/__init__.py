"""Spectral compression B -> d -> B: the 1-D convolutional autoencoder (paper eq. 9) or a linear basis."""

from brfgs.spectral.autoencoder import (
    AutoencoderConfig,
    SpectralAutoencoder,
    evaluate_autoencoder,
    sample_pixels,
    spectral_angle_torch,
    train_autoencoder,
)
from brfgs.spectral.linear_basis import LinearBasis, fit_linear_basis

__all__ = [
    "AutoencoderConfig",
    "LinearBasis",
    "SpectralAutoencoder",
    "evaluate_autoencoder",
    "fit_linear_basis",
    "sample_pixels",
    "spectral_angle_torch",
    "train_autoencoder",
]
