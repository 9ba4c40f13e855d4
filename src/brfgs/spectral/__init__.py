"""Spectral compression: the 1-D convolutional autoencoder B -> d -> B (paper eq. 9)."""

from brfgs.spectral.autoencoder import (
    AutoencoderConfig,
    SpectralAutoencoder,
    evaluate_autoencoder,
    sample_pixels,
    spectral_angle_torch,
    train_autoencoder,
)

__all__ = [
    "AutoencoderConfig",
    "SpectralAutoencoder",
    "evaluate_autoencoder",
    "sample_pixels",
    "spectral_angle_torch",
    "train_autoencoder",
]
