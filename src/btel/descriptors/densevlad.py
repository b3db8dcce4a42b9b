"""DenseVLAD: dense RootSIFT aggregated into a VLAD vector, then PCA-whitened.

After Torii, Arandjelović, Sivic, Okutomi and Pajdla, "24/7 place recognition by view synthesis"
(CVPR 2015) — the descriptor the BTEL paper uses on Nordland (d = 4096). Per image:

1. grey, downscaled (never enlarged) so the longer side is at most ``max_side`` (default 640: the
   paper works on VGA-sized images);
2. upright SIFT (OpenCV) on a regular grid at several scales: ``sizes`` are SIFT *bin* widths in
   pixels — 4, 6, 8, 10 as in ``vl_phow``, i.e. regions of 16, 24, 32 and 40 pixels — with
   centres every ``step`` pixels wherever the whole region lies inside the image;
3. RootSIFT: L1-normalise and take the square root (each descriptor then has unit L2 norm);
4. VLAD over ``n_clusters`` (K = 128) k-means centroids learned in ``fit`` from at most
   ``max_descriptors`` descriptors sampled evenly over the map images (faiss k-means; centroids
   then L2-normalised as in the authors' code): per centroid, the sum of residuals of the
   descriptors assigned to it; intra-normalisation (L2 per centroid block); global L2;
5. PCA-whitening to ``n_components`` learned on the map images' VLAD vectors, then L2.

Choices and deviations from the paper, each deliberate:

- **step = 8 pixels** (paper: 2, ``vl_phow``'s default). On a 640×360 Gardens Point frame a step
  of 8 gives at most 79 × 44 = 3,476 descriptors per scale and about 13,000 per image (~0.1 s of
  SIFT on one core); a step of 2 gives 16 times as many. Set ``step=2`` for the paper's density.
- OpenCV describes every scale on one image smoothed with σ = 1.6 (its SIFT base level), where
  ``vl_phow`` smooths each scale with σ = bin/6. OpenCV's SIFT bin is 3·(size/2) pixels wide, so
  a bin width B becomes ``KeyPoint(size=B / 1.5, angle=0)``.
- ``vl_phow`` sets low-contrast descriptors to zero and keeps them; OpenCV has no contrast
  threshold. Descriptors that are exactly zero (no gradient under the region: sky, black frames)
  carry no information and are dropped; an image without any descriptor gets a zero VLAD.
- **PCA cap**: n centred training vectors have at most n − 1 directions of variance, and
  whitening divides by each one's standard deviation, so ``n_components_`` is ``min(n_components,
  n_train_images − 1, K·128, #components with variance > max(1e-6 × the largest, 1e-10))``:
  the paper's 4096 needs 4097 distinct map images; ``n_components=None`` skips PCA (K·128 = 16,384).
"""

from __future__ import annotations

import warnings
from functools import lru_cache
from typing import Any, ClassVar

from .images import iter_grey, to_grey  # isort: skip - first: it sets OpenCV's pixel cap before cv2 loads
import cv2  # noqa: E402
import faiss
import numpy as np
from scipy import sparse
from sklearn.decomposition import PCA
from sklearn.utils import check_random_state

from ..core.validation import check_is_fitted, check_positive_int
from ..exceptions import InvalidParameterError, NotEnoughPlacesError
from ..core.limits import check_count
from ..core.progress import elapsed_ticker
from .base import DescriptorWarning, ImageDescriptor, register_descriptor, single_blas_thread

__all__ = ["DenseVLADDescriptor", "dense_rootsift", "vlad_encode", "SIFT_DIM"]

#: Length of one SIFT descriptor.
SIFT_DIM = 128
# A PCA component whose variance is below 1e-6 × the largest, or below 1e-10 in absolute terms
# (training VLADs have unit norm, so their variances sum to at most 1), is numerically zero:
# float32 rounding, not data. Whitening would blow it up.
_PCA_RTOL = 1e-6
_PCA_ATOL = 1e-10
# Local descriptors of the training images kept in memory between the two passes of fit.
_FIT_CACHE_BYTES = 512 * 2**20


@lru_cache(maxsize=16)
def _grid(height: int, width: int, sizes: tuple[int, ...], step: int) -> tuple[cv2.KeyPoint, ...]:
    # Centres every `step` pixels where the 4-bin-wide region (4·B pixels) fits inside the image.
    # Cached: building ~13k KeyPoint objects in Python costs more than a dict lookup per image.
    points = []
    for bin_px in sizes:
        margin = 2 * bin_px
        for y in range(margin, height - margin + 1, step):
            for x in range(margin, width - margin + 1, step):
                points.append(cv2.KeyPoint(float(x), float(y), bin_px / 1.5, 0.0))
    return tuple(points)


def _prepare(grey: np.ndarray, max_side: int | None) -> np.ndarray:
    # OpenCV's SIFT needs 8-bit input.
    if grey.dtype != np.uint8:
        grey = np.round(grey * 255.0).astype(np.uint8)
    height, width = grey.shape
    if max_side is not None and max(height, width) > max_side:
        scale = max_side / max(height, width)
        new_size = (max(1, round(width * scale)), max(1, round(height * scale)))
        grey = cv2.resize(grey, new_size, interpolation=cv2.INTER_AREA)
    return grey


def _check_grid(height: int, width: int, sizes: tuple[int, ...], step: int) -> None:
    """Refuse a grid whose keypoints and SIFT descriptors exceed the memory limit, before building it."""
    count = sum(max(0, (height - 4 * b) // step + 1) * max(0, (width - 4 * b) // step + 1) for b in sizes)
    # A KeyPoint object (~100 B) and a 128-float descriptor computed in float32 (512 B) each.
    check_count(count, 100 + 4 * SIFT_DIM,
                f"dense SIFT with {len(sizes)} bin sizes and step {step} on {width}×{height} pixels ({count} keypoints)")


def _rootsift_grey(grey: np.ndarray, sizes: tuple[int, ...], step: int) -> np.ndarray:
    height, width = grey.shape
    _check_grid(height, width, sizes, step)
    keypoints = _grid(height, width, sizes, step)
    if not keypoints:
        raise InvalidParameterError(
            f"an image of {width}×{height} pixels is too small for dense SIFT with bin sizes {list(sizes)}: "
            f"the smallest region is {4 * min(sizes)} pixels wide. Use smaller sizes or larger images."
        )
    _, desc = cv2.SIFT_create().compute(grey, list(keypoints))
    if desc is None:
        return np.empty((0, SIFT_DIM), dtype=np.float32)
    totals = desc.sum(axis=1)
    desc = desc[totals > 0]
    return np.sqrt(desc / totals[totals > 0, None]).astype(np.float32)


def dense_rootsift(
    image: Any, *, sizes: tuple[int, ...] = (4, 6, 8, 10), step: int = 8, max_side: int | None = 640
) -> np.ndarray:
    """Dense upright RootSIFT descriptors of one image (steps 1–3 of the module docstring).

    Parameters
    ----------
    image : array-like of shape (H, W) or (H, W, 3)
        Any image :func:`btel.descriptors.images.to_grey` accepts.
    sizes : tuple of int
        SIFT bin widths in pixels (region = 4 bins wide).
    step : int
        Grid spacing in pixels.
    max_side : int or None
        Downscale so the longer side is at most this; None keeps the size.

    Returns
    -------
    ndarray of shape (m, 128), dtype float32
        Non-negative rows of unit L2 norm; all-zero SIFT descriptors are left out.
    """
    return _rootsift_grey(_prepare(to_grey(image), max_side), tuple(sizes), step)


def vlad_encode(local: np.ndarray, centroids: np.ndarray) -> np.ndarray:
    """VLAD of one image's local descriptors, intra-normalised then L2-normalised.

    Parameters
    ----------
    local : ndarray of shape (m, d), float32
        Local descriptors (m may be 0).
    centroids : ndarray of shape (K, d), float32
        The vocabulary.

    Returns
    -------
    ndarray of shape (K * d,), dtype float32
        Block k (entries k·d … k·d + d − 1) is the L2-normalised sum of residuals of the
        descriptors nearest to centroid k (zeros when none are); the whole vector then has unit
        L2 norm, or is all zeros when ``m == 0``.
    """
    n_clusters, dim = centroids.shape
    if len(local) == 0:
        return np.zeros(n_clusters * dim, dtype=np.float32)
    # Nearest centroid by squared L2 distance; ‖x‖² is the same for every centroid, so drop it.
    distances = (centroids * centroids).sum(axis=1) - 2.0 * (local @ centroids.T)
    labels = np.argmin(distances, axis=1)
    # Sum of descriptors per centroid as a sparse (K, m) assignment matrix times the descriptors:
    # ~30× faster than np.add.at for ~13k descriptors.
    assignment = sparse.csr_matrix(
        (np.ones(len(labels), dtype=np.float32), (labels, np.arange(len(labels)))), shape=(n_clusters, len(labels))
    )
    residuals = np.asarray(assignment @ local, dtype=np.float32)
    residuals -= np.bincount(labels, minlength=n_clusters)[:, None].astype(np.float32) * centroids
    norms = np.linalg.norm(residuals, axis=1, keepdims=True)
    residuals = np.divide(residuals, norms, out=np.zeros_like(residuals), where=norms > 0)
    vector = residuals.ravel()
    total = np.linalg.norm(vector)
    return vector / total if total > 0 else vector


def _l2_rows(X: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(X, axis=1, keepdims=True)
    return np.divide(X, norms, out=np.zeros_like(X), where=norms > 0)


@register_descriptor
class DenseVLADDescriptor(ImageDescriptor):
    """DenseVLAD global descriptor (Torii et al. 2015) with a vocabulary and PCA learned in fit.

    Parameters
    ----------
    n_clusters : int
        K, the number of visual words (paper: 128). VLAD length before PCA is K·128.
    n_components : int or None
        PCA-whitened output length (paper: 4096), capped as the module docstring explains;
        None skips PCA.
    sizes : tuple of int
        SIFT bin widths in pixels, one scale each (regions 4× as wide).
    step : int
        Grid spacing in pixels (8 by default; the paper's 2 is 16× slower).
    max_side : int or None
        Images are downscaled so their longer side is at most this (None: never).
    max_descriptors : int
        Cap on the local descriptors sampled (evenly per image) for k-means.
    kmeans_iter : int
        k-means iterations.
    random_state : int, RandomState or None
        Seeds the descriptor sampling, k-means and PCA. Default 0: reproducible vocabularies.

    Attributes
    ----------
    centroids_ : ndarray of shape (n_clusters, 128), float32
        The vocabulary (L2-normalised k-means centroids).
    pca_mean_ : ndarray of shape (n_clusters * 128,), float32, or None
    pca_components_ : ndarray of shape (n_components_, n_clusters * 128), float32, or None
    pca_explained_variance_ : ndarray of shape (n_components_,), float32, or None
        PCA-whitening: ``y = (v − mean) @ components.T / sqrt(explained_variance)``.
    n_components_ : int or None
        Components actually kept (None without PCA).
    n_local_descriptors_ : int
        Local descriptors found in the training images; ``n_sampled_descriptors_`` of them
        trained k-means.
    dim_ : int
        Output length: ``n_components_``, or ``n_clusters * 128`` without PCA.

    Raises
    ------
    InvalidParameterError
        From fit: fewer sampled local descriptors than ``n_clusters``, images too small for the
        smallest SIFT region, identical training images, or a bad parameter.
    NotEnoughPlacesError
        From fit: PCA requested with fewer than 2 training images.
    NotFittedError
        From transform/save/output_dim before fit (or load).

    Examples
    --------
    >>> dv = DenseVLADDescriptor(n_clusters=16).fit("map/")            # doctest: +SKIP
    >>> X_map, X_query = dv.transform("map/"), dv.transform("query/")  # doctest: +SKIP
    >>> dv.save("densevlad.npz")                                        # doctest: +SKIP
    """

    name: ClassVar[str] = "densevlad"
    requires_fit: ClassVar[bool] = True

    def __init__(
        self,
        *,
        n_clusters: int = 128,
        n_components: int | None = 4096,
        sizes: tuple[int, ...] = (4, 6, 8, 10),
        step: int = 8,
        max_side: int | None = 640,
        max_descriptors: int = 100_000,
        kmeans_iter: int = 20,
        random_state: Any = 0,
    ) -> None:
        self.n_clusters = n_clusters
        self.n_components = n_components
        self.sizes = sizes
        self.step = step
        self.max_side = max_side
        self.max_descriptors = max_descriptors
        self.kmeans_iter = kmeans_iter
        self.random_state = random_state

    # -- parameters ---------------------------------------------------------------------------
    def _validate_params(self) -> None:
        n_clusters = check_positive_int(self.n_clusters, "n_clusters")
        if self.n_components is not None:
            check_positive_int(self.n_components, "n_components")
        if not isinstance(self.sizes, (tuple, list)) or not self.sizes:
            raise InvalidParameterError(f"sizes must be a non-empty tuple of SIFT bin widths in pixels; got {self.sizes!r}.")
        for size in self.sizes:
            check_positive_int(size, "each of sizes")
        check_positive_int(self.step, "step")
        if self.max_side is not None:
            check_positive_int(self.max_side, "max_side")
            # Worst case: a square max_side image (a saved file may declare any sizes and step).
            _check_grid(self.max_side, self.max_side, tuple(self.sizes), int(self.step))
        if check_positive_int(self.max_descriptors, "max_descriptors") < n_clusters:
            raise InvalidParameterError(
                f"max_descriptors ({self.max_descriptors}) must be at least n_clusters ({n_clusters}): "
                "k-means needs one descriptor per centroid."
            )
        check_positive_int(self.kmeans_iter, "kmeans_iter")

    @property
    def output_dim(self) -> int:
        """Descriptor length (known after fit): ``n_components_`` or ``n_clusters * 128``."""
        check_is_fitted(self, "dim_")
        return int(self.dim_)

    # -- pipeline -----------------------------------------------------------------------------
    def _local(self, grey: np.ndarray) -> np.ndarray:
        return _rootsift_grey(_prepare(grey, self.max_side), tuple(self.sizes), int(self.step))

    def _raw_dim(self) -> int:
        return int(self.centroids_.shape[0] * SIFT_DIM)

    def _encode(self, grey: np.ndarray) -> np.ndarray:
        return vlad_encode(self._local(grey), self.centroids_)

    def _project(self, raw: np.ndarray) -> np.ndarray:
        if self.pca_components_ is None:
            return raw
        whitened = (raw - self.pca_mean_) @ self.pca_components_.T
        whitened /= np.sqrt(self.pca_explained_variance_)
        return _l2_rows(whitened.astype(np.float32, copy=False))

    def _fit(self, items: list, progress: bool) -> np.ndarray | None:
        if hasattr(self, "dim_"):
            del self.dim_  # a refit that fails half-way must not leave a usable-looking mix of states
        rng = check_random_state(self.random_state)
        n_images, n_clusters = len(items), int(self.n_clusters)
        if self.n_components is not None and n_images < 2:
            raise NotEnoughPlacesError(
                f"PCA-whitening needs at least 2 training images; got {n_images}. "
                "Fit on more map images, or pass n_components=None to skip PCA."
            )
        # Sample evenly over images so a few highly textured frames cannot dominate the vocabulary.
        quota = -(-int(self.max_descriptors) // n_images)
        samples, n_local = [], 0
        # Keep each image's descriptors for the PCA pass while they fit in _FIT_CACHE_BYTES, so a
        # small map is read and described once instead of twice.
        cache: list[np.ndarray] | None = [] if self.n_components is not None else None
        cached_bytes = 0
        for grey in iter_grey(items, progress=progress, desc="densevlad: vocabulary"):
            local = self._local(grey)
            n_local += len(local)
            if cache is not None:
                cached_bytes += local.nbytes
                if cached_bytes <= _FIT_CACHE_BYTES:
                    cache.append(local)
                else:
                    cache = None
            if len(local) > quota:
                local = local[np.sort(rng.choice(len(local), size=quota, replace=False))]
            samples.append(local)
        sample = np.ascontiguousarray(np.concatenate(samples), dtype=np.float32)
        if len(sample) < n_clusters:
            raise InvalidParameterError(
                f"k-means with n_clusters={n_clusters} needs at least {n_clusters} local descriptors, but the "
                f"{n_images} training image(s) gave only {len(sample)}. Use a smaller n_clusters, more or "
                "larger images, or a smaller step."
            )
        kmeans = faiss.Kmeans(
            SIFT_DIM,
            n_clusters,
            niter=int(self.kmeans_iter),
            seed=int(rng.randint(0, 2**31 - 1)),
            # Our sample is already capped; stop faiss from subsampling it again.
            max_points_per_centroid=len(sample) // n_clusters + 1,
            verbose=False,
        )
        kmeans.train(sample)
        self.centroids_ = _l2_rows(np.asarray(kmeans.centroids, dtype=np.float32).copy())
        self.n_local_descriptors_ = int(n_local)
        self.n_sampled_descriptors_ = int(len(sample))
        self.pca_mean_ = self.pca_components_ = self.pca_explained_variance_ = None
        self.n_components_ = None
        if self.n_components is None:
            self.dim_ = n_clusters * SIFT_DIM
            return None

        raw = np.empty((n_images, n_clusters * SIFT_DIM), dtype=np.float32)
        with single_blas_thread():
            if cache is not None:
                for i, local in enumerate(cache):
                    raw[i] = vlad_encode(local, self.centroids_)
            else:
                for i, grey in enumerate(iter_grey(items, progress=progress, desc="densevlad: PCA")):
                    raw[i] = self._encode(grey)
        cap = min(int(self.n_components), n_images - 1, n_clusters * SIFT_DIM)
        with elapsed_ticker(f"densevlad: PCA-whitening {n_images} VLAD vectors ({raw.shape[1]} → {cap} dims)",
                            enabled=bool(progress)):
            pca = PCA(n_components=cap, whiten=True, random_state=rng).fit(raw)
        variance = pca.explained_variance_
        kept = int(np.count_nonzero(variance > max(variance[0] * _PCA_RTOL, _PCA_ATOL))) if variance.size else 0
        if kept == 0:
            raise InvalidParameterError(
                f"the {n_images} training images all give the same VLAD vector (e.g. blank frames); "
                "PCA has nothing to learn. Fit on varied map images or pass n_components=None."
            )
        self.pca_mean_ = pca.mean_.astype(np.float32)
        self.pca_components_ = np.ascontiguousarray(pca.components_[:kept], dtype=np.float32)
        self.pca_explained_variance_ = variance[:kept].astype(np.float32)
        self.n_components_ = kept
        self.dim_ = kept
        if kept < int(self.n_components):
            why = (f"PCA has at most n_train − 1 = {n_images - 1} directions of variance on {n_images} map images"
                   if cap == n_images - 1 and kept == cap else
                   f"only {kept} of {cap} components have non-zero variance (duplicate or blank map frames)")
            warnings.warn(
                f"densevlad: n_components={self.n_components} requested, {kept}-D descriptors produced: {why}. "
                f"The paper's {self.n_components}-D needs at least {int(self.n_components) + 1} distinct map images; "
                "pass n_components=None (btel extract --param n_components=null) to keep the raw VLAD vector instead.", DescriptorWarning, stacklevel=3)
        return np.concatenate([self._project(raw[i : i + self._batch_size]) for i in range(0, n_images, self._batch_size)])

    # -- persistence --------------------------------------------------------------------------
    def _stored_arrays(self) -> dict[str, np.ndarray]:
        arrays = {"centroids": self.centroids_}
        if self.pca_components_ is not None:
            arrays.update(pca_mean=self.pca_mean_, pca_components=self.pca_components_,
                          pca_explained_variance=self.pca_explained_variance_)
        return arrays

    def _fitted_state(self) -> dict[str, Any]:
        return {"dim": int(self.dim_), "n_components": self.n_components_,
                "n_local_descriptors": self.n_local_descriptors_, "n_sampled_descriptors": self.n_sampled_descriptors_}

    def _restore(self, arrays: dict[str, np.ndarray], state: dict[str, Any]) -> None:
        self._validate_params()
        centroids = np.ascontiguousarray(arrays["centroids"], dtype=np.float32)
        if centroids.shape != (self.n_clusters, SIFT_DIM):
            raise ValueError(f"centroids have shape {centroids.shape}, expected ({self.n_clusters}, {SIFT_DIM})")
        if not np.isfinite(centroids).all():
            raise ValueError("centroids contain NaN or infinite values")
        self.centroids_ = centroids
        self.n_local_descriptors_ = int(state["n_local_descriptors"])
        self.n_sampled_descriptors_ = int(state["n_sampled_descriptors"])
        raw_dim = self.n_clusters * SIFT_DIM
        if state["n_components"] is None:
            self.pca_mean_ = self.pca_components_ = self.pca_explained_variance_ = None
            self.n_components_ = None
            self.dim_ = raw_dim
        else:
            kept = int(state["n_components"])
            mean = np.asarray(arrays["pca_mean"], dtype=np.float32)
            components = np.ascontiguousarray(arrays["pca_components"], dtype=np.float32)
            variance = np.asarray(arrays["pca_explained_variance"], dtype=np.float32)
            if mean.shape != (raw_dim,) or components.shape != (kept, raw_dim) or variance.shape != (kept,):
                raise ValueError("PCA arrays do not match n_clusters and n_components")
            if not np.all(variance > 0):
                raise ValueError("PCA explained variances must be positive")
            # Whitening divides by √variance after a product with the components: values near
            # float32's limits (3e38 in a saved file) overflow to NaN descriptors. Unit-norm VLADs
            # have variances ≤ 1 and components of unit norm, so anything beyond 1e6 is not a PCA.
            for label, values in (("mean", mean), ("components", components), ("explained variances", variance)):
                if not np.isfinite(values).all() or np.abs(values).max(initial=0.0) > 1e6:
                    raise ValueError(f"PCA {label} are not finite values of a PCA of unit-norm VLAD vectors")
            if variance.min() < 1e-30:
                raise ValueError("PCA explained variances are too small to whiten by")
            self.pca_mean_, self.pca_components_, self.pca_explained_variance_ = mean, components, variance
            self.n_components_ = kept
            self.dim_ = kept
        if int(state["dim"]) != self.dim_:
            raise ValueError(f"header says dim {state['dim']} but the arrays give {self.dim_}")
