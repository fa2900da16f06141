"""PEGASUS generator: Gaussian-splat assets to physically placed, exactly labelled BOP datasets."""

__version__ = "0.1.0"
