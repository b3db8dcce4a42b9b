"""Image files as hostile input (issue 34, item 2): headers read before decoding, lying chunks,
pixel bombs in every format btel decodes, and OpenCV's own pixel cap."""

from __future__ import annotations

import io
import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image

from btel.cli import main
from btel.descriptors.images import DECODED_FORMATS, decode_bytes, read_image
from btel.exceptions import DataNotFoundError, ResourceLimitError


def _chunk(kind: bytes, data: bytes, length: int | None = None) -> bytes:
    size = len(data) if length is None else length
    return struct.pack(">I", size) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _png(width: int, height: int, colour_type: int, idat: bytes, idat_length: int | None = None) -> bytes:
    header = struct.pack(">IIBBBBB", width, height, 8, colour_type, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header) + _chunk(b"IDAT", idat, idat_length)
            + _chunk(b"IEND", b""))


def _encoded(fmt: str, image: np.ndarray, **options) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format=fmt, **options)
    return buffer.getvalue()


def _tiff_with_size(width: int, height: int) -> bytes:
    """A small TIFF whose ImageWidth / ImageLength tags are rewritten to ``width × height``."""
    data = bytearray(_encoded("TIFF", np.zeros((4, 4), np.uint8)))
    assert data[:2] == b"II"
    ifd = struct.unpack_from("<I", data, 4)[0]
    for i in range(struct.unpack_from("<H", data, ifd)[0]):
        entry = ifd + 2 + 12 * i
        tag, kind = struct.unpack_from("<HH", data, entry)
        if tag in (256, 257):
            struct.pack_into("<H" if kind == 3 else "<I", data, entry + 8, width if tag == 256 else height)
    return bytes(data)


def _jpeg_with_size(width: int, height: int) -> bytes:
    data = bytearray(_encoded("JPEG", np.zeros((8, 8), np.uint8)))
    sof = data.index(b"\xff\xc0")
    struct.pack_into(">HH", data, sof + 5, height, width)
    return bytes(data)


def _bmp_with_size(width: int, height: int) -> bytes:
    data = bytearray(_encoded("BMP", np.zeros((4, 4, 3), np.uint8)))
    struct.pack_into("<ii", data, 18, width, height)
    return bytes(data)


def test_a_png_whose_idat_length_lies_is_refused_before_opencv_allocates_it(tmp_path: Path) -> None:
    """Issue 34: a 200-byte PNG whose IDAT length reads 0x7fffffff drove `btel extract` to 2.25 GB."""
    folder = tmp_path / "images"
    folder.mkdir()
    path = folder / "a.png"
    path.write_bytes(_png(8, 8, 0, zlib.compress(b"\0" * 72), idat_length=0x7FFFFFFF))
    assert path.stat().st_size < 200
    with pytest.raises(DataNotFoundError, match=r"a.png': its header or chunks are damaged.*Truncated"):
        read_image(path, grey=True)
    result = CliRunner().invoke(main, ["extract", str(folder), "-o", str(tmp_path / "x.npy"),
                                       "--no-progress"])
    assert result.exit_code == 2 and result.exception is not None
    assert result.output.count("\n") == 1 and "chunks are damaged" in result.output


def test_a_png_with_a_bad_chunk_checksum_is_refused(tmp_path: Path) -> None:
    data = bytearray(_encoded("PNG", np.full((8, 8), 7, np.uint8)))
    data[data.index(b"IDAT") + 6] ^= 0xFF
    (tmp_path / "crc.png").write_bytes(bytes(data))
    with pytest.raises(DataNotFoundError, match="chunks are damaged"):
        read_image(tmp_path / "crc.png")


@pytest.mark.parametrize("colour_type, grey", [(0, True), (2, False), (2, True)])
def test_huge_png_dimensions_are_refused_from_the_header(tmp_path: Path, colour_type: int,
                                                         grey: bool) -> None:
    """Issue 34: an 875 KB 30000×30000 grey PNG reached 1.9 GB, a 20000² colour one 2.5 GB. The same
    headers over a few bytes of data: the header alone is refused, nothing is inflated."""
    side = 30000 if colour_type == 0 else 20000
    path = tmp_path / "big.png"
    path.write_bytes(_png(side, side, colour_type, zlib.compress(b"\0" * 1000)))
    with pytest.raises(ResourceLimitError, match="big.png.*BTEL_MEMORY_LIMIT"):
        read_image(path, grey=grey)


@pytest.mark.parametrize("fmt, data", [
    ("JPEG", lambda: _jpeg_with_size(60000, 60000)),
    ("BMP", lambda: _bmp_with_size(30000, 30000)),
    ("BMP top-down", lambda: _bmp_with_size(30000, -30000)),
    ("TIFF", lambda: _tiff_with_size(60000, 60000)),
    ("PPM", lambda: b"P5\n30000 30000\n255\n" + b"\0" * 64),
])
def test_huge_dimensions_are_refused_in_every_format(tmp_path: Path, fmt: str, data) -> None:
    path = tmp_path / "big.img"
    path.write_bytes(data())
    with pytest.raises(ResourceLimitError, match="BTEL_MEMORY_LIMIT"):
        read_image(path, grey=True)


def test_the_limit_follows_btel_memory_limit(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    image = np.zeros((300, 400, 3), np.uint8)
    path = tmp_path / "a.png"
    path.write_bytes(_encoded("PNG", image))
    assert decode_bytes(400, 300, 3, grey=False) == 400 * 300 * (2 * 3 + 2 * 3)
    monkeypatch.setenv("BTEL_MEMORY_LIMIT", str(decode_bytes(400, 300, 3, grey=True)))
    assert read_image(path, grey=True).shape == (300, 400)  # grey costs less than colour
    with pytest.raises(ResourceLimitError, match=r"400×300, 3 channels, decoded"):
        read_image(path)


@pytest.mark.parametrize("fmt", ["PNG", "JPEG", "BMP", "TIFF", "PPM", "WEBP"])
def test_every_decoded_format_still_reads(tmp_path: Path, fmt: str) -> None:
    assert fmt in DECODED_FORMATS
    image = (np.add.outer(np.arange(24), np.arange(32)) * 5 % 256).astype(np.uint8)
    path = tmp_path / f"a.{fmt.lower()}"
    path.write_bytes(_encoded(fmt, np.stack([image, image[::-1], 255 - image], -1)))
    assert read_image(path).shape == (24, 32, 3) and read_image(path, grey=True).shape == (24, 32)


def test_other_formats_and_animations_are_refused_by_name(tmp_path: Path) -> None:
    frames = [Image.fromarray(np.full((8, 8), v, np.uint8)) for v in (0, 255)]
    frames[0].save(tmp_path / "a.gif")
    frames[0].save(tmp_path / "anim.png", save_all=True, append_images=frames[1:])
    with pytest.raises(DataNotFoundError, match=r"not a PNG, JPEG, BMP, TIFF, PPM or WEBP image"):
        read_image(tmp_path / "a.gif")
    with pytest.raises(DataNotFoundError, match="animated PNG"):
        read_image(tmp_path / "anim.png")


def test_opencv_pixel_cap_is_set_from_the_limit_when_btel_loads_opencv(tmp_path: Path) -> None:
    """OpenCV reads OPENCV_IO_MAX_IMAGE_PIXELS once, when it loads: btel sets it (a backstop behind
    the header check) unless OpenCV is loaded already or the user set it."""
    ok, png = cv2.imencode(".png", np.zeros((100, 100), np.uint8))
    (tmp_path / "a.png").write_bytes(png.tobytes())
    code = ("import os; from btel.descriptors import hog; import cv2, numpy as np; "
            "print(os.environ['OPENCV_IO_MAX_IMAGE_PIXELS']); "
            "data = np.fromfile(os.environ['PNG'], np.uint8)\n"
            "try:\n    print(cv2.imdecode(data, 0).size)\nexcept cv2.error:\n    print('refused')")
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_IO_MAX_IMAGE_PIXELS"}
    env.update(BTEL_MEMORY_LIMIT="32K", PNG=str(tmp_path / "a.png"))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.stdout.split() == ["16384", "10000"], out.stderr
    env["BTEL_MEMORY_LIMIT"] = "8K"  # 4096 pixels: OpenCV itself refuses the 10,000-pixel image
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.stdout.split() == ["4096", "refused"], out.stderr


@pytest.mark.parametrize("value", ["abc", "-1", "1e6", ""])
def test_a_pixel_cap_opencv_cannot_parse_is_refused_before_opencv_aborts(value: str, tmp_path: Path) -> None:
    """OPENCV_IO_MAX_IMAGE_PIXELS=abc made `btel extract` die with SIGABRT (std::stoull in OpenCV)."""
    ok, png = cv2.imencode(".png", np.zeros((16, 16), np.uint8))
    (tmp_path / "images").mkdir()
    (tmp_path / "images" / "a.png").write_bytes(png.tobytes())
    env = {**os.environ, "OPENCV_IO_MAX_IMAGE_PIXELS": value}
    out = subprocess.run([sys.executable, "-m", "btel.cli", "extract", str(tmp_path / "images"), "-o",
                          str(tmp_path / "x.npy"), "--descriptor", "hog"], env=env, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 2, out.stderr
    assert f"OPENCV_IO_MAX_IMAGE_PIXELS={value!r} is not a whole number of pixels" in out.stderr


@pytest.mark.realdata
def test_real_frames_read_as_before(nordland_dir: Path, gardenspoint_sample_dir: Path) -> None:
    """The header check changes no pixel: the real frames decode exactly as OpenCV alone decodes them."""
    files = (sorted((nordland_dir / "summer").glob("*.png"))[:20]
             + sorted((gardenspoint_sample_dir / "ref").glob("*.jpg")))
    for path in files:
        direct = cv2.imdecode(np.fromfile(path, np.uint8), cv2.IMREAD_GRAYSCALE)
        np.testing.assert_array_equal(read_image(path, grey=True), direct)
        colour = cv2.cvtColor(cv2.imdecode(np.fromfile(path, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        np.testing.assert_array_equal(read_image(path), colour)


def test_webp_and_pgm_files_in_a_folder_are_read(tmp_path) -> None:
    """read_image decodes WEBP and PGM, but list_images skipped them ('not images btel reads')."""
    import cv2

    from btel.descriptors import list_images, read_image

    rng = np.random.default_rng(0)
    cv2.imwrite(str(tmp_path / "0.webp"), (rng.random((32, 48, 3)) * 255).astype(np.uint8))
    cv2.imwrite(str(tmp_path / "1.pgm"), (rng.random((32, 48)) * 255).astype(np.uint8))
    found = list_images(tmp_path)
    assert [p.name for p in found] == ["0.webp", "1.pgm"]
    assert all(read_image(p).shape[:2] == (32, 48) for p in found)
