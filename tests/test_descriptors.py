"""Image front ends: image reading, HOG, patch normalisation, DenseVLAD, .npy loading."""

from __future__ import annotations

from pathlib import Path

import cv2
import faiss
import numpy as np
import pytest
from skimage.feature import hog
from sklearn.base import clone

from btel.descriptors import (
    DESCRIPTORS,
    DenseVLADDescriptor,
    HOGDescriptor,
    ImageDescriptor,
    PatchNormDescriptor,
    dense_rootsift,
    extract_descriptors,
    get_descriptor,
    list_images,
    load_descriptor,
    load_descriptor_matrix,
    patch_normalise,
    read_image,
    to_grey,
    vlad_encode,
)
from btel.exceptions import (
    DataNotFoundError,
    InvalidDescriptorsError,
    InvalidParameterError,
    ModelFileError,
    NotEnoughPlacesError,
    NotFittedError,
)
from btel.core.modelfile import load_arrays, save_arrays


def _textured(seed: int, shape: tuple[int, int] = (96, 128)) -> np.ndarray:
    """A random smooth texture, uint8: enough gradient structure for SIFT and HOG."""
    rng = np.random.default_rng(seed)
    noise = rng.random(shape).astype(np.float32)
    smooth = cv2.GaussianBlur(noise, (0, 0), 2.0)
    smooth = (smooth - smooth.min()) / (smooth.max() - smooth.min())
    return (smooth * 255).astype(np.uint8)


def _write_images(folder: Path, names: list[str], shape: tuple[int, int] = (32, 64)) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, name in enumerate(names):
        path = folder / name
        ok = cv2.imwrite(str(path), _textured(i, shape))
        assert ok, f"test setup could not write {path}"
        paths.append(path)
    return paths


# -- image listing and reading ---------------------------------------------------------------


def test_list_images_natural_order_and_filtering(tmp_path: Path) -> None:
    _write_images(tmp_path, ["10.png", "2.png", "1.PNG", "img-3.jpg", "img-20.jpeg", "b.bmp"])
    (tmp_path / "notes.txt").write_text("not an image")
    (tmp_path / ".hidden.png").write_bytes(b"")
    (tmp_path / "sub").mkdir()
    names = [p.name for p in list_images(tmp_path)]
    assert names == ["1.PNG", "2.png", "10.png", "b.bmp", "img-3.jpg", "img-20.jpeg"]


def test_list_images_missing_empty_and_file(tmp_path: Path) -> None:
    with pytest.raises(DataNotFoundError, match="does not exist"):
        list_images(tmp_path / "nowhere")
    with pytest.raises(DataNotFoundError, match="no images.*it is empty"):
        list_images(tmp_path)
    (tmp_path / "readme.txt").write_text("x")
    with pytest.raises(DataNotFoundError, match="no images.*readme.txt"):
        list_images(tmp_path)
    with pytest.raises(DataNotFoundError, match="is a file, not a folder"):
        list_images(tmp_path / "readme.txt")


def test_read_image_colour_is_rgb_and_grey(tmp_path: Path) -> None:
    bgr = np.zeros((4, 6, 3), np.uint8)
    bgr[..., 0] = 200  # blue in OpenCV's BGR order
    path = tmp_path / "blue.png"
    cv2.imwrite(str(path), bgr)
    rgb = read_image(path)
    assert rgb.shape == (4, 6, 3) and rgb.dtype == np.uint8
    assert (rgb[..., 2] == 200).all() and (rgb[..., :2] == 0).all()
    grey = read_image(path, grey=True)
    assert grey.shape == (4, 6)
    # Decoding to grey and converting the RGB array agree (up to OpenCV's rounding).
    assert np.abs(grey.astype(int) - to_grey(rgb).astype(int)).max() <= 1


def test_corrupt_empty_and_missing_image_files(tmp_path: Path) -> None:
    bad = tmp_path / "broken.jpg"
    bad.write_bytes(b"\xff\xd8\xff\xe0 this is not really a jpeg")
    with pytest.raises(DataNotFoundError, match="cannot decode.*broken.jpg"):
        read_image(bad)
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(DataNotFoundError, match="empty.png.*empty"):
        read_image(tmp_path / "empty.png")
    with pytest.raises(DataNotFoundError, match="does not exist"):
        read_image(tmp_path / "missing.png")
    # The error names the bad file when it is met inside a folder being described.
    _write_images(tmp_path, ["0.png"])
    with pytest.raises(DataNotFoundError, match="broken.jpg"):
        HOGDescriptor().transform(tmp_path, progress=False)


def test_to_grey_accepts_forms_and_rejects_bad_arrays() -> None:
    grey = _textured(0, (8, 8))
    colour = np.repeat(grey[:, :, None], 3, axis=2)
    assert np.array_equal(to_grey(colour), grey)
    assert np.array_equal(to_grey(grey[:, :, None]), grey)
    assert np.array_equal(to_grey(np.dstack([colour, np.full((8, 8), 255, np.uint8)])), grey)
    assert np.allclose(to_grey(grey.astype(np.float64) / 255), grey / 255, atol=1e-6)
    assert np.array_equal(to_grey(grey.astype(np.int64)), grey)
    assert np.allclose(to_grey(grey.astype(np.uint16) * 257), grey / 255, atol=1e-6)
    with pytest.raises(InvalidParameterError, match=r"\[0, 1\].*Divide"):
        to_grey(grey.astype(np.float32))
    with pytest.raises(InvalidParameterError, match="NaN"):
        to_grey(np.full((4, 4), np.nan))
    with pytest.raises(InvalidParameterError, match="0..255"):
        to_grey(np.full((4, 4), 300))
    with pytest.raises(InvalidParameterError, match="shape"):
        to_grey(np.zeros((4, 4, 2), np.uint8))
    with pytest.raises(InvalidParameterError, match="numeric"):
        to_grey(np.array([["a"]]))


def test_image_collection_forms() -> None:
    images = [_textured(i, (32, 64)) for i in range(3)]
    hogd = HOGDescriptor()
    expected = hogd.transform(images, progress=False)
    assert np.array_equal(hogd.transform(np.stack(images), progress=False), expected)
    assert np.array_equal(hogd.transform(tuple(images), progress=False), expected)
    with pytest.raises(InvalidParameterError, match="list of images"):
        hogd.transform(images[0])
    with pytest.raises(InvalidParameterError, match="one colour image"):
        hogd.transform(np.zeros((32, 64, 3), np.uint8))
    with pytest.raises(InvalidParameterError, match="no images"):
        hogd.transform([])
    with pytest.raises(InvalidParameterError, match="folder, a list"):
        hogd.transform(42)


# -- HOG ----------------------------------------------------------------------------------------


def test_hog_matches_scikit_image_with_default_parameters() -> None:
    image = _textured(1, (32, 64))
    X = HOGDescriptor().fit().transform([image, image.astype(np.float32) / 255], progress=False)
    assert X.shape == (2, 3780) and X.dtype == np.float32
    expected = hog(image.astype(np.float32) / 255, orientations=9, pixels_per_cell=(4, 4),
                   cells_per_block=(2, 2), block_norm="L2-Hys")
    np.testing.assert_allclose(X[0], expected, atol=1e-6)
    np.testing.assert_allclose(X[1], X[0], atol=1e-6)  # uint8 and float [0, 1] inputs agree


def test_hog_resizes_with_inter_area_and_reports_dims() -> None:
    big = _textured(2, (128, 256))
    X = HOGDescriptor().transform([big], progress=False)
    small = cv2.resize(big, (64, 32), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
    np.testing.assert_allclose(X[0], hog(small, 9, (4, 4), (2, 2), "L2-Hys"), atol=1e-6)
    custom = HOGDescriptor(size=(32, 32), pixels_per_cell=(8, 8), orientations=6)
    assert custom.output_dim == 3 * 3 * 2 * 2 * 6
    assert custom.transform([big], progress=False).shape == (1, custom.output_dim)
    assert HOGDescriptor().fit().dim_ == 3780


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"size": (4, 4)}, "holds no"),
        ({"size": (64,)}, "pair"),
        ({"orientations": 0}, "orientations"),
        ({"block_norm": "L3"}, "block_norm"),
        ({"pixels_per_cell": (4, 0)}, r"pixels_per_cell\[1\]"),
    ],
)
def test_hog_bad_parameters(params: dict, message: str) -> None:
    with pytest.raises(InvalidParameterError, match=message):
        HOGDescriptor(**params).fit()


@pytest.mark.realdata
def test_hog_on_a_real_nordland_frame(nordland_dir: Path) -> None:
    frame = nordland_dir / "summer" / "images-00100.png"
    X = HOGDescriptor().transform([frame], progress=False)
    assert X.shape == (1, 3780) and X.dtype == np.float32
    assert np.isfinite(X).all() and X.max() > 0


@pytest.mark.realdata
def test_hog_nearest_neighbour_summer_to_winter_recall(nordland_hog) -> None:
    """Guards the HOG pipeline: SPEC §10 measured brute-force recall@10 = 0.38 on all frames."""
    summer, winter = nordland_hog
    assert summer.shape == winter.shape == (3576, 3780)
    index = faiss.IndexFlatL2(summer.shape[1])
    index.add(summer)
    pred = index.search(winter, 1)[1][:, 0]
    error = np.abs(pred - np.arange(len(winter)))
    recall0, recall10 = float(np.mean(error == 0)), float(np.mean(error <= 10))
    print(f"HOG nordland summer→winter: recall@0={recall0:.3f} recall@10={recall10:.3f}")
    assert recall10 >= 0.30


# -- patch normalisation ----------------------------------------------------------------------


def test_patch_normalise_zero_mean_unit_std_and_flat_patches() -> None:
    image = _textured(3, (32, 64)).astype(np.float64)
    image[:8, :8] = 17.0  # one flat patch
    out = patch_normalise(image, 8)
    assert out.shape == (32, 64) and out.dtype == np.float32
    patches = out.reshape(4, 8, 8, 8).transpose(0, 2, 1, 3).reshape(32, 64)
    assert np.all(patches[0] == 0)
    np.testing.assert_allclose(patches[1:].mean(axis=1), 0, atol=1e-5)
    np.testing.assert_allclose(patches[1:].std(axis=1), 1, atol=1e-5)


def test_patch_normalise_removes_per_patch_brightness_and_contrast() -> None:
    image = _textured(4, (16, 16)).astype(np.float64)
    gain = np.kron(np.array([[0.5, 2.0], [3.0, 1.0]]), np.ones((8, 8)))
    offset = np.kron(np.array([[10.0, -4.0], [0.0, 50.0]]), np.ones((8, 8)))
    np.testing.assert_allclose(patch_normalise(image * gain + offset), patch_normalise(image), atol=1e-4)


def test_patch_normalise_rejects_bad_input() -> None:
    with pytest.raises(InvalidParameterError, match="multiple of patch_size"):
        patch_normalise(np.zeros((30, 64)), 8)
    with pytest.raises(InvalidParameterError, match="2-D"):
        patch_normalise(np.zeros((32, 64, 3)), 8)
    with pytest.raises(InvalidParameterError, match="patch_size"):
        patch_normalise(np.zeros((32, 64)), 0)


def test_patchnorm_descriptor_shape_and_content() -> None:
    image = _textured(5, (64, 128))
    X = PatchNormDescriptor().transform([image], progress=False)
    assert X.shape == (1, 2048) and X.dtype == np.float32
    thumb = cv2.resize(image, (64, 32), interpolation=cv2.INTER_AREA).astype(np.float32) / 255
    np.testing.assert_allclose(X[0], patch_normalise(thumb).ravel(), atol=1e-6)
    with pytest.raises(InvalidParameterError, match="whole number"):
        PatchNormDescriptor(size=(60, 32)).fit()


# -- registry, estimator contract, save/load ---------------------------------------------------


def test_registry_and_params() -> None:
    assert set(DESCRIPTORS) == {"hog", "patchnorm", "densevlad"}
    assert isinstance(get_descriptor("HOG", orientations=12), HOGDescriptor)
    assert get_descriptor("hog", orientations=12).output_dim == 3780 // 9 * 12
    assert isinstance(get_descriptor("dense-vlad"), DenseVLADDescriptor)
    with pytest.raises(InvalidParameterError, match="unknown descriptor.*densevlad, hog, patchnorm"):
        get_descriptor("sift")
    with pytest.raises(InvalidParameterError, match="it takes: .*orientations"):
        get_descriptor("hog", orientation=12)
    dv = clone(DenseVLADDescriptor(n_clusters=7, sizes=(4,)))
    assert dv.get_params()["n_clusters"] == 7 and dv.sizes == (4,)


def test_stateless_save_load_round_trip(tmp_path: Path) -> None:
    path = HOGDescriptor(orientations=6, size=(32, 32)).save(tmp_path / "hog.npz")
    loaded = ImageDescriptor.load(path)
    assert isinstance(loaded, HOGDescriptor)
    assert loaded.get_params() == HOGDescriptor(orientations=6, size=(32, 32)).get_params()
    image = _textured(6)
    np.testing.assert_array_equal(loaded.transform([image], progress=False),
                                  HOGDescriptor(orientations=6, size=(32, 32)).transform([image], progress=False))
    with pytest.raises(ModelFileError, match="not a 'densevlad'"):
        DenseVLADDescriptor.load(path)


def test_load_rejects_missing_and_foreign_files(tmp_path: Path) -> None:
    with pytest.raises(ModelFileError, match="does not exist"):
        load_descriptor(tmp_path / "none.npz")
    foreign = save_arrays(tmp_path / "model.npz", {"w": np.zeros(3)}, {"model": "BTECompressed"})
    with pytest.raises(ModelFileError, match="not an image descriptor.*BTECompressed"):
        load_descriptor(foreign)
    odd = save_arrays(tmp_path / "odd.npz", {}, {"kind": "image-descriptor", "descriptor": "surf"})
    with pytest.raises(ModelFileError, match="unknown descriptor 'surf'"):
        load_descriptor(odd)


# -- DenseVLAD on synthetic images ------------------------------------------------------------

_FAST = {"sizes": (4, 6), "step": 6, "max_descriptors": 5000, "kmeans_iter": 10}


def test_dense_rootsift_grid_and_normalisation() -> None:
    local = dense_rootsift(_textured(7, (96, 128)), sizes=(4,), step=8)
    # Centres every 8 px from 8 to W-8 (and H-8): 15 × 11 positions, none flat on this texture.
    assert local.shape == (15 * 11, 128) and local.dtype == np.float32
    assert (local >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(local, axis=1), 1, atol=1e-5)  # sqrt of L1-normalised
    assert dense_rootsift(np.zeros((96, 128), np.uint8), sizes=(4,)).shape == (0, 128)
    with pytest.raises(InvalidParameterError, match="too small"):
        dense_rootsift(np.zeros((12, 12), np.uint8), sizes=(4,))


def test_dense_rootsift_per_scale_count_on_a_gardens_point_sized_image() -> None:
    # The documented step choice: at most a few thousand descriptors per scale on 640×360.
    counts = [len(dense_rootsift(_textured(8, (360, 640)), sizes=(b,), step=8)) for b in (4, 6, 8, 10)]
    assert max(counts) == 79 * 44 and min(counts) > 2500


def test_vlad_encode_normalisation() -> None:
    rng = np.random.default_rng(0)
    centroids = rng.random((4, 3)).astype(np.float32)
    local = np.vstack([centroids[0] + 0.1, centroids[0] + 0.2, centroids[2] - 0.05]).astype(np.float32)
    vector = vlad_encode(local, centroids)
    blocks = vector.reshape(4, 3)
    assert vector.shape == (12,) and vector.dtype == np.float32
    assert np.isclose(np.linalg.norm(vector), 1)
    assert np.all(blocks[[1, 3]] == 0)  # no descriptor assigned
    # Intra-normalisation: every non-empty block has the same norm, whatever its residual size.
    np.testing.assert_allclose(np.linalg.norm(blocks[[0, 2]], axis=1), 1 / np.sqrt(2), atol=1e-6)
    np.testing.assert_allclose(blocks[0], np.full(3, 1 / np.sqrt(6)), atol=1e-6)
    assert np.array_equal(vlad_encode(np.empty((0, 3), np.float32), centroids), np.zeros(12, np.float32))


def test_densevlad_shows_an_elapsed_time_while_its_pca_runs(monkeypatch) -> None:
    """The PCA over the map's VLAD vectors ran a silent minute on Nordland (3,576 × 16,384) between two
    bars: it now runs under the elapsed-time line with progress on (on a terminal a line refreshed in
    place, in a log a line every 10 s: :func:`btel.core.progress.elapsed_ticker`)."""
    import contextlib
    import io

    from btel.descriptors import densevlad

    shown: list[tuple[str, bool]] = []

    @contextlib.contextmanager
    def ticker(desc: str, enabled: bool, file=None):  # noqa: ANN001, ANN202
        shown.append((desc, enabled))
        yield

    monkeypatch.setattr(densevlad, "elapsed_ticker", ticker)
    images = [_textured(10 + i) for i in range(6)]
    for progress in (True, False):
        DenseVLADDescriptor(n_clusters=8, n_components=4, **_FAST).fit(images, progress=progress)
    assert shown == [("densevlad: PCA-whitening 6 VLAD vectors (1024 → 4 dims)", True),
                     ("densevlad: PCA-whitening 6 VLAD vectors (1024 → 4 dims)", False)]


def test_densevlad_without_pca_and_with_capped_pca() -> None:
    images = [_textured(10 + i) for i in range(6)]
    raw = DenseVLADDescriptor(n_clusters=8, n_components=None, **_FAST).fit(images, progress=False)
    X = raw.transform(images, progress=False)
    assert raw.dim_ == raw.output_dim == 8 * 128 and X.shape == (6, 1024) and X.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(X, axis=1), 1, atol=1e-5)
    assert raw.centroids_.shape == (8, 128)
    np.testing.assert_allclose(np.linalg.norm(raw.centroids_, axis=1), 1, atol=1e-5)

    pca = DenseVLADDescriptor(n_clusters=8, n_components=100, **_FAST)
    Y = pca.fit_transform(images, progress=False)
    assert pca.n_components_ == 5  # capped at n_train_images - 1
    assert Y.shape == (6, 5) and np.isfinite(Y).all()
    np.testing.assert_allclose(np.linalg.norm(Y, axis=1), 1, atol=1e-5)
    np.testing.assert_allclose(Y, pca.transform(images, progress=False), atol=1e-5)  # fit_transform = fit+transform
    assert DenseVLADDescriptor(n_clusters=8, n_components=3, **_FAST).fit(images, progress=False).dim_ == 3


def test_densevlad_fit_without_descriptor_cache_gives_the_same_result(monkeypatch: pytest.MonkeyPatch) -> None:
    images = [_textured(40 + i) for i in range(4)]
    cached = DenseVLADDescriptor(n_clusters=8, **_FAST).fit_transform(images, progress=False)
    monkeypatch.setattr("btel.descriptors.densevlad._FIT_CACHE_BYTES", 0)  # forces the second read
    recomputed = DenseVLADDescriptor(n_clusters=8, **_FAST).fit_transform(images, progress=False)
    np.testing.assert_array_equal(cached, recomputed)


def test_densevlad_is_reproducible_with_a_seed() -> None:
    images = [_textured(20 + i) for i in range(4)]
    a = DenseVLADDescriptor(n_clusters=8, n_components=None, random_state=3, **_FAST).fit(images, progress=False)
    b = DenseVLADDescriptor(n_clusters=8, n_components=None, random_state=3, **_FAST).fit(images, progress=False)
    assert np.array_equal(a.centroids_, b.centroids_)


def test_densevlad_load_rejects_edited_arrays(tmp_path: Path) -> None:
    images = [_textured(50 + i) for i in range(3)]
    path = DenseVLADDescriptor(n_clusters=4, **_FAST).fit(images, progress=False).save(tmp_path / "dv.npz")
    arrays, header = load_arrays(path)
    arrays["centroids"] = arrays["centroids"][:3]
    save_arrays(tmp_path / "edited.npz", arrays, {k: v for k, v in header.items() if not k.startswith("format")})
    with pytest.raises(ModelFileError, match="inconsistent.*centroids"):
        DenseVLADDescriptor.load(tmp_path / "edited.npz")


def test_progress_bar_stays_silent_off_a_terminal(capsys: pytest.CaptureFixture[str]) -> None:
    HOGDescriptor().transform([_textured(i, (32, 64)) for i in range(3)], progress=True)
    assert capsys.readouterr().err == ""


def test_densevlad_errors() -> None:
    images = [_textured(30 + i, (40, 40)) for i in range(2)]
    with pytest.raises(NotFittedError, match="not fitted"):
        DenseVLADDescriptor().transform(images)
    with pytest.raises(NotFittedError):
        DenseVLADDescriptor().save("never-written.npz")
    with pytest.raises(InvalidParameterError, match="needs at least 128 local descriptors.*gave only"):
        DenseVLADDescriptor(sizes=(4,), step=8).fit(images, progress=False)
    with pytest.raises(NotEnoughPlacesError, match="at least 2 training images"):
        DenseVLADDescriptor(n_clusters=2, sizes=(4,)).fit(images[:1], progress=False)
    with pytest.raises(InvalidParameterError, match="too small"):
        DenseVLADDescriptor(n_clusters=2).fit([np.zeros((10, 10), np.uint8)] * 2, progress=False)
    with pytest.raises(InvalidParameterError, match="same VLAD vector"):
        DenseVLADDescriptor(n_clusters=2, sizes=(4,)).fit([images[0]] * 3, progress=False)
    with pytest.raises(InvalidParameterError, match="max_descriptors"):
        DenseVLADDescriptor(max_descriptors=10).fit(images, progress=False)
    with pytest.raises(InvalidParameterError, match="sizes"):
        DenseVLADDescriptor(sizes=()).fit(images, progress=False)


def test_extract_descriptors_api(tmp_path: Path) -> None:
    folder = tmp_path / "map"
    paths = _write_images(folder, [f"{i}.png" for i in range(4)], shape=(64, 96))
    X = extract_descriptors(folder, "patchnorm", progress=False)
    np.testing.assert_array_equal(X, PatchNormDescriptor().transform(paths, progress=False))
    with pytest.raises(NotFittedError, match="fit_on"):
        extract_descriptors(folder, "densevlad")
    dv = DenseVLADDescriptor(n_clusters=4, n_components=None, **_FAST)
    X_map = extract_descriptors(folder, dv, fit_on=folder, progress=False)
    vocab = dv.save(tmp_path / "vocab.npz")
    X_again = extract_descriptors(paths, vocab, progress=False)  # a saved descriptor file
    np.testing.assert_array_equal(X_map, X_again)
    with pytest.raises(InvalidParameterError, match="descriptor must be a name"):
        extract_descriptors(folder, "no-such-thing")


# -- DenseVLAD on camera-sized real images ----------------------------------------------------


@pytest.fixture(scope="module")
def gardens_vlad16(gardenspoint_sample_dir: Path) -> tuple[DenseVLADDescriptor, np.ndarray, np.ndarray]:
    dv = DenseVLADDescriptor(n_clusters=16, max_descriptors=20_000)
    X_ref = dv.fit_transform(gardenspoint_sample_dir / "ref", progress=False)
    X_query = dv.transform(gardenspoint_sample_dir / "query", progress=False)
    return dv, X_ref, X_query


@pytest.mark.realdata
def test_densevlad_on_gardens_point(gardens_vlad16: tuple) -> None:
    dv, X_ref, X_query = gardens_vlad16
    assert dv.n_components_ == 9  # 10 training images → at most 9 PCA components
    assert X_ref.shape == X_query.shape == (10, 9) and X_ref.dtype == np.float32
    for X in (X_ref, X_query):
        assert np.isfinite(X).all()
        np.testing.assert_allclose(np.linalg.norm(X, axis=1), 1, atol=1e-5)
    assert dv.n_local_descriptors_ > 10 * 10_000  # about 13k dense descriptors per 640×360 frame
    assert dv.n_sampled_descriptors_ == 20_000


@pytest.mark.realdata
def test_densevlad_matches_shifted_darkened_map_images(gardens_vlad16: tuple, gardenspoint_sample_dir: Path) -> None:
    # A working pipeline maps a slightly moved, darker copy of a map image next to the original.
    # (Day→night on 10 images is no test: with a 10-image vocabulary and PCA it is near chance.)
    dv, X_ref, _ = gardens_vlad16
    copies = [(np.roll(read_image(p), 5, axis=1) * 0.6).astype(np.uint8)
              for p in list_images(gardenspoint_sample_dir / "ref")]
    X_copy = dv.transform(copies, progress=False)
    distances = ((X_copy[:, None, :] - X_ref[None, :, :]) ** 2).sum(axis=2)
    assert np.array_equal(distances.argmin(axis=1), np.arange(10))
    nearest, second = np.sort(distances, axis=1)[:, :2].T
    assert np.all(nearest < 0.5 * second)


@pytest.mark.realdata
def test_densevlad_save_load_round_trip(gardens_vlad16: tuple, gardenspoint_sample_dir: Path, tmp_path: Path) -> None:
    dv, _, X_query = gardens_vlad16
    path = dv.save(tmp_path / "densevlad.npz")
    loaded = DenseVLADDescriptor.load(path)
    assert loaded.get_params() == dv.get_params()
    assert np.array_equal(loaded.centroids_, dv.centroids_)
    assert np.array_equal(loaded.transform(gardenspoint_sample_dir / "query", progress=False), X_query)
    # The file holds the fitted arrays and little else (no pickles, a small JSON header).
    stored = sum(a.nbytes for a in (dv.centroids_, dv.pca_mean_, dv.pca_components_, dv.pca_explained_variance_))
    assert stored < path.stat().st_size < stored + 4096


@pytest.mark.realdata
def test_densevlad_default_k128_on_gardens_point(gardenspoint_sample_dir: Path) -> None:
    # The paper's K = 128 and PCA; 40k sampled descriptors (default 100k) keep k-means short.
    dv = DenseVLADDescriptor(max_descriptors=40_000)
    X = dv.fit_transform(gardenspoint_sample_dir / "ref", progress=False)
    assert dv.centroids_.shape == (128, 128)
    assert X.shape == (10, 9) and np.isfinite(X).all()
    np.testing.assert_allclose(np.linalg.norm(X, axis=1), 1, atol=1e-5)


# -- .npy descriptor matrices -----------------------------------------------------------------


def test_load_descriptor_matrix_good_and_mmap(tmp_path: Path) -> None:
    X = np.random.default_rng(0).random((5, 3))
    np.save(tmp_path / "x.npy", X)
    loaded = load_descriptor_matrix(tmp_path / "x.npy")
    assert loaded.dtype == np.float32 and loaded.shape == (5, 3)
    np.testing.assert_allclose(loaded, X, rtol=1e-6)
    np.save(tmp_path / "f32.npy", X.astype(np.float32))
    mapped = load_descriptor_matrix(tmp_path / "f32.npy", mmap_mode="r")
    assert isinstance(mapped.base, np.memmap) or isinstance(mapped, np.memmap)
    np.testing.assert_array_equal(mapped, X.astype(np.float32))
    with pytest.raises(InvalidParameterError, match="mmap_mode"):
        load_descriptor_matrix(tmp_path / "f32.npy", mmap_mode="r+")


@pytest.mark.parametrize(
    ("array", "error", "message"),
    [
        (np.array([[1.0, np.nan], [0.0, 1.0]]), InvalidDescriptorsError, "NaN"),
        (np.arange(5.0), InvalidDescriptorsError, "2-D.*reshape"),
        (np.array([["a", "b"]]), InvalidDescriptorsError, "numbers"),
        (np.zeros((0, 4)), InvalidDescriptorsError, "at least 1 row"),
    ],
)
def test_load_descriptor_matrix_bad_content(tmp_path: Path, array: np.ndarray, error: type, message: str) -> None:
    np.save(tmp_path / "bad.npy", array)
    with pytest.raises(error, match=message):
        load_descriptor_matrix(tmp_path / "bad.npy")


def test_load_descriptor_matrix_bad_files(tmp_path: Path) -> None:
    with pytest.raises(DataNotFoundError, match="does not exist"):
        load_descriptor_matrix(tmp_path / "missing.npy")
    np.save(tmp_path / "objects.npy", np.array([[{"a": 1}]], dtype=object), allow_pickle=True)
    with pytest.raises(InvalidDescriptorsError, match="never unpickles"):
        load_descriptor_matrix(tmp_path / "objects.npy")
    (tmp_path / "junk.npy").write_bytes(b"not numpy at all")
    with pytest.raises(InvalidDescriptorsError, match="junk.npy"):
        load_descriptor_matrix(tmp_path / "junk.npy")
    np.savez(tmp_path / "two.npz", a=np.ones((2, 2)), b=np.ones((3, 2)))
    with pytest.raises(InvalidParameterError, match="2 arrays.*key="):
        load_descriptor_matrix(tmp_path / "two.npz")
    assert load_descriptor_matrix(tmp_path / "two.npz", key="b").shape == (3, 2)
    with pytest.raises(DataNotFoundError, match="no array 'c'"):
        load_descriptor_matrix(tmp_path / "two.npz", key="c")


@pytest.mark.realdata
def test_load_descriptor_matrix_real_netvlad(shared_data: Path) -> None:
    path = shared_data / "gardenspoint_netvlad" / "hiddenRepr-GardensPoint.npz"
    X = load_descriptor_matrix(path, key="hlrTrain")
    assert X.shape == (200, 500) and X.dtype == np.float32 and np.isfinite(X).all()
