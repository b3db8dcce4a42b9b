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

import importlib
from typing import TYPE_CHECKING

from .._lazy import lazy_names

if TYPE_CHECKING:  # pragma: no cover - imported on first use (btel._lazy): reading a .npy needs no OpenCV
    from ..core.frontend import delta_descriptors
    from .augment import augmented_views
    from .base import DESCRIPTORS, ImageDescriptor, get_descriptor, load_descriptor, register_descriptor
    from .densevlad import DenseVLADDescriptor, dense_rootsift, vlad_encode
    from .extract import extract_descriptors
    from .hog import HOGDescriptor
    from .images import IMAGE_EXTENSIONS, list_images, read_image, to_grey
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

__getattr__, __dir__ = lazy_names(__name__, {
    "delta_descriptors": "..core.frontend", "augmented_views": ".augment",
    **dict.fromkeys(("ImageDescriptor", "get_descriptor", "load_descriptor", "register_descriptor"), ".base"),
    **dict.fromkeys(("DenseVLADDescriptor", "dense_rootsift", "vlad_encode"), ".densevlad"),
    "extract_descriptors": ".extract", "HOGDescriptor": ".hog",
    **dict.fromkeys(("IMAGE_EXTENSIONS", "list_images", "read_image", "to_grey"), ".images"),
    "load_descriptor_matrix": ".npy",
    **dict.fromkeys(("PatchNormDescriptor", "patch_normalise"), ".patchnorm")},
    computed={"DESCRIPTORS": lambda: importlib.import_module(".base", __name__).registered()})
