"""Image front ends: from images to the global descriptors every btel method fits on.

Each descriptor has the same interface (:class:`ImageDescriptor`): ``fit(images)``,
``transform(images) -> (n, dim) float32``, ``fit_transform``, ``output_dim``/``dim_``,
``save(path)`` / ``ImageDescriptor.load(path)``. Pick one by short name::

    from btel.descriptors import get_descriptor, extract_descriptors
    X = get_descriptor("hog").transform("data/nordland64/summer")
    X_map = extract_descriptors("map/", "densevlad", fit_on="map/")

- ``"hog"`` — :class:`HOGDescriptor`: HOG of the 64×32 grey thumbnail (3780-D);
- ``"patchnorm"`` — :class:`PatchNormDescriptor`: SeqSLAM's 8×8 patch-normalised 64×32
  thumbnail (2048-D);
- ``"densevlad"`` — :class:`DenseVLADDescriptor`: dense RootSIFT → VLAD (K = 128) →
  PCA-whitening (Torii et al. 2015).

Descriptors computed elsewhere (NetVLAD, ...) are read with :func:`load_descriptor_matrix`.
:func:`delta_descriptors` turns any traverse of descriptors into sequence (delta) descriptors.
"""

from __future__ import annotations

# images first: it sets OpenCV's pixel cap from btel's memory limit before anything loads OpenCV.
from .images import IMAGE_EXTENSIONS, list_images, read_image, to_grey  # isort: skip
from ..frontend import delta_descriptors
from .augment import augmented_views
from .base import DESCRIPTORS, ImageDescriptor, get_descriptor, load_descriptor, register_descriptor
from .densevlad import DenseVLADDescriptor, dense_rootsift, vlad_encode
from .extract import extract_descriptors
from .hog import HOGDescriptor
from .npy import load_descriptor_matrix
from .patchnorm import PatchNormDescriptor, patch_normalise

__all__ = [
    "augmented_views",
    "delta_descriptors",
    "DESCRIPTORS",
    "IMAGE_EXTENSIONS",
    "DenseVLADDescriptor",
    "HOGDescriptor",
    "ImageDescriptor",
    "PatchNormDescriptor",
    "dense_rootsift",
    "extract_descriptors",
    "get_descriptor",
    "list_images",
    "load_descriptor",
    "load_descriptor_matrix",
    "patch_normalise",
    "read_image",
    "register_descriptor",
    "to_grey",
    "vlad_encode",
]
