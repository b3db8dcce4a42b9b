"""The structure-aware families of the readers' fuzz harness (issue 34): each builds one case from a
seeded ``random.Random``, so ``fuzz_readers.py`` reproduces every case from its id.

- **link graphs** (``hdf5``): hloc files whose groups are linked into cycles, to the root, under two
  names, through soft and external links, or nested past any sensible depth;
- **chunk shapes** (``hdf5``): chunked datasets with chunks from 1 value to 2³⁰, every filter
  combination (gzip, shuffle, fletcher32 and the refused LZF / scale-offset), and chunks whose
  stored gzip stream inflates far past what they declare;
- **image headers** (``image``): PNG, JPEG, BMP, TIFF, PNM and WebP files whose dimensions, chunk
  lengths, segment lengths, strip counts and offsets are set to extremes (checksums repaired or
  not, so the decoders behind the checks are reached);
- **ring geometries** (``gt_utm``): UTM positions on rings, disks, lines, grids and single points,
  queries at the centre, on the ring or anywhere, thresholds at the radius ± 10⁻ᵏ, counts that
  match the descriptors or not;
- **names** (``names``): hloc files and ``btel extract`` sidecars whose image names hold controls,
  separators, spaces, quotes, TeX, ``..`` and long runs; the reader checks that a pairs file
  keeps one pair per line and the predictions CSV one row per line.
"""

from __future__ import annotations

import io
import json
import random
import struct
import zlib
from typing import Any

import numpy as np

# ------------------------------------------------------------------------------------ link graphs
def _h5_bytes(fill: Any) -> bytes:
    import h5py

    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as fh:
        fill(fh)
    return buffer.getvalue()


def link_graph(rng: random.Random) -> tuple[bytes, str]:
    """An hloc-like tree of groups plus random extra links (hard, self, to the root, soft, external)."""
    import h5py

    kinds: list[str] = []

    def fill(fh: Any) -> None:
        groups = [fh]
        for i in range(rng.randint(1, 8)):
            group = rng.choice(groups).create_group(f"g{i}")
            groups.append(group)
            if rng.random() < 0.6:
                group.create_dataset("global_descriptor", data=np.full(rng.choice([4, 8]), i, np.float32))
        if rng.random() < 0.1:  # a deep chain
            deep = fh.create_group("/".join(["d"] * rng.randint(50, 80)))
            deep.create_dataset("global_descriptor", data=np.ones(4, np.float32))
            groups.append(deep)
        for j in range(rng.randint(0, 4)):
            kind = rng.choice(["hard", "hard", "self", "root", "soft", "external", "dataset"])
            source = rng.choice(groups[1:])
            name = f"l{j}"
            if name in source:
                continue
            target = rng.choice(groups)
            if kind == "hard":
                source[name] = target
            elif kind == "self":
                source[name] = source
            elif kind == "root":
                source[name] = fh
            elif kind == "soft":
                source[name] = h5py.SoftLink(target.name)
            elif kind == "external":
                source[name] = h5py.ExternalLink("other.h5", "/")
            else:
                datasets = [g["global_descriptor"] for g in groups[1:] if "global_descriptor" in g]
                if not datasets:
                    continue
                source[name] = rng.choice(datasets)
            kinds.append(kind)

    return _h5_bytes(fill), "link graph " + (",".join(kinds) or "tree")


# ------------------------------------------------------------------------------------ chunk shapes
def compressed_zeros(n_bytes: int) -> bytes:
    """A zlib stream of ``n_bytes`` zero bytes, built in milliseconds for any size: one raw deflate
    piece of 4 MiB (flushed, so it refers to nothing before it) repeated, the rest, and the adler32
    of zeros, ``(n mod 65521) << 16 | 1``."""
    block = 1 << 22
    head = zlib.compressobj(1, zlib.DEFLATED, -15)
    piece = head.compress(b"\0" * block) + head.flush(zlib.Z_FULL_FLUSH)
    tail = zlib.compressobj(1, zlib.DEFLATED, -15)
    rest = tail.compress(b"\0" * (n_bytes % block)) + tail.flush(zlib.Z_FINISH)
    return b"\x78\x01" + piece * (n_bytes // block) + rest + struct.pack(">I", ((n_bytes % 65521) << 16) | 1)


def chunk_shape(rng: random.Random) -> tuple[bytes, str]:
    """One global descriptor in a chunked dataset with a random chunk, filters and (maybe) a lying chunk."""
    import h5py

    d = rng.choice([1, 8, 64, 1000])
    dtype = rng.choice(["f4", "f8", "i2", "u1"])
    chunk = max(1, int(2 ** rng.uniform(0, 30)))
    filters: dict[str, Any] = {}
    if rng.random() < 0.6:
        filters["compression"] = "gzip"
        filters["compression_opts"] = rng.randint(0, 9)
    elif rng.random() < 0.2:
        filters["compression"] = "lzf"
    if rng.random() < 0.3:
        filters["shuffle"] = True
    if rng.random() < 0.2:
        filters["fletcher32"] = True
    if rng.random() < 0.05:
        filters["scaleoffset"] = 4 if dtype in ("i2", "u1") else 2
    shape = (d,) if rng.random() < 0.7 else (1, d)
    chunks = (chunk,) if len(shape) == 1 else (1, chunk)
    lie = rng.random() < 0.15 and filters.get("compression") == "gzip" and not filters.get("shuffle") \
        and not filters.get("fletcher32") and "scaleoffset" not in filters and chunk <= 4096
    inflate = int(2 ** rng.uniform(16, 28)) if lie else 0

    def fill(fh: Any) -> None:
        group = fh.create_group("db/a.jpg")
        ds = group.create_dataset("global_descriptor", shape=shape, dtype=dtype, chunks=chunks,
                                  maxshape=(None,) * len(shape), **filters)
        if lie:  # a stored stream far longer than the chunk it declares
            ds.id.write_direct_chunk((0,) * len(shape), compressed_zeros(inflate), 0)
        elif chunk <= 1 << 22:
            ds[...] = np.arange(d).reshape(shape) % 100
        fh.create_group("db/b.jpg").create_dataset("global_descriptor", data=np.ones(shape, dtype))

    try:
        data = _h5_bytes(fill)
    except (ValueError, TypeError, OSError) as exc:  # h5py refused the combination: an hloc file instead
        plain = _h5_bytes(lambda fh: fh.create_group("db/a.jpg").create_dataset(
            "global_descriptor", data=np.ones(8, np.float32)))
        return plain, f"chunk shape refused by h5py ({type(exc).__name__})"
    described = ",".join(f"{k}={v}" for k, v in filters.items())
    stored = f" storing {inflate} B of zeros" if lie else ""
    return data, f"chunk {chunks} of {shape} {dtype} {described}{stored}"


# ---------------------------------------------------------------------------------- image headers
def _encode(fmt: str, image: np.ndarray, **options: Any) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format=fmt, **options)
    return buffer.getvalue()


def _png_chunk(kind: bytes, data: bytes, length: int | None = None) -> bytes:
    size = len(data) if length is None else length
    return struct.pack(">I", size) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def image_seeds() -> list[bytes]:
    """Small valid images in every decoded format and mode, and the issue's crafted PNGs."""
    from PIL import Image

    grey = (np.add.outer(np.arange(24), np.arange(32)) * 7 % 256).astype(np.uint8)
    rgb = np.stack([grey, grey[::-1], 255 - grey], -1)
    out = [_encode("PNG", grey), _encode("PNG", rgb), _encode("PNG", np.dstack([rgb, grey])),
           _encode("PNG", (grey.astype(np.uint16) * 257)), _encode("PNG", rgb, optimize=True),
           _encode("JPEG", rgb), _encode("JPEG", rgb, progressive=True), _encode("JPEG", grey),
           _encode("BMP", rgb), _encode("TIFF", rgb), _encode("TIFF", grey, compression="tiff_deflate"),
           _encode("TIFF", rgb, compression="tiff_lzw"), _encode("PPM", rgb), _encode("PPM", grey),
           _encode("WEBP", rgb), _encode("WEBP", rgb, lossless=True)]
    buffer = io.BytesIO()
    Image.fromarray(grey).convert("P").save(buffer, format="PNG")
    out.append(buffer.getvalue())
    buffer = io.BytesIO()
    Image.fromarray(grey).save(buffer, format="PNG", save_all=True,
                               append_images=[Image.fromarray(255 - grey)])
    out.append(buffer.getvalue())  # an animated PNG
    ihdr = struct.pack(">IIBBBBB", 8, 8, 8, 0, 0, 0, 0)
    idat = zlib.compress(b"\0" * 72)
    out.append(b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr) + _png_chunk(b"IDAT", idat, 0x7FFFFFFF)
               + _png_chunk(b"IEND", b""))  # the IDAT length
    big = struct.pack(">IIBBBBB", 30000, 30000, 8, 0, 0, 0, 0)
    rows = compressed_zeros(1 << 20)  # 30000² grey, its first MiB of rows
    out.append(b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", big) + _png_chunk(b"IDAT", rows)
               + _png_chunk(b"IEND", b""))
    return out


_EXTREMES = [0, 1, 2, 255, 256, 4095, 30000, 65535, 65536, 2**24, 2**31 - 1, 2**31, 2**32 - 1]


def jpeg_of_empty_scans(scans: int, size: int = 256) -> bytes:
    """A progressive ``size``×``size`` grey JPEG whose first start-of-scan header repeats ``scans`` times
    with no data: libjpeg passes over every block at every scan (hostile round 3's scan bomb)."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.new("L", (size, size), 128).save(buffer, "JPEG", progressive=True)
    data, i, head = buffer.getvalue(), 2, []
    while data[i + 1] != 0xDA:
        length = struct.unpack(">H", data[i + 2 : i + 4])[0]
        head.append(data[i : i + 2 + length])
        i += 2 + length
    sos = data[i : i + 2 + struct.unpack(">H", data[i + 2 : i + 4])[0]]
    return data[:2] + b"".join(head) + sos * scans + b"\xff\xd9"


def _png_edit(buf: bytearray, rng: random.Random) -> str:
    chunks, pos = [], 8
    while pos + 8 <= len(buf):
        length = struct.unpack_from(">I", buf, pos)[0]
        chunks.append((pos, length))
        pos += 12 + length
        if length > len(buf):
            break
    if not chunks:
        return "png: no chunk"
    at, length = rng.choice(chunks)
    field = rng.choice(["length", "ihdr", "ihdr", "type"])
    if field == "length":
        struct.pack_into(">I", buf, at, rng.choice(_EXTREMES + [length + 1, max(0, length - 1)]) % 2**32)
        return "png chunk length"
    if field == "type":
        kinds = [b"IDAT", b"IEND", b"acTL", b"fcTL", b"fdAT", b"iCCP", b"zTXt", b"PLTE"]
        buf[at + 4:at + 8] = rng.choice(kinds)
        what = "png chunk type"
    else:
        at, length = chunks[0]
        if length < 13:
            return "png: short IHDR"
        offset = rng.choice([8, 12, 16, 17, 18, 20])
        if offset in (8, 12):
            struct.pack_into(">I", buf, at + offset, rng.choice(_EXTREMES) % 2**32)
        else:
            buf[at + offset] = rng.choice([0, 1, 2, 3, 4, 6, 8, 16, 255])
        what = f"png IHDR byte {offset - 8}"
    if rng.random() < 0.7 and at + 8 + length + 4 <= len(buf):  # repair the CRC: the decoders see it
        struct.pack_into(">I", buf, at + 8 + length, zlib.crc32(bytes(buf[at + 4:at + 8 + length])))
        what += " (crc fixed)"
    return what


def _jpeg_edit(buf: bytearray, rng: random.Random) -> str:
    sof = [i for i in range(len(buf) - 9) if buf[i] == 0xFF and buf[i + 1] in (0xC0, 0xC1, 0xC2)]
    segments = [i for i in range(len(buf) - 4)
                if buf[i] == 0xFF and 0xC0 <= buf[i + 1] <= 0xFE and buf[i + 1] != 0xD8]
    if sof and rng.random() < 0.6:
        at = rng.choice(sof)
        field = rng.choice([5, 7, 9])
        if field == 9:
            buf[at + 9] = rng.choice([0, 1, 3, 4, 255])
        else:
            struct.pack_into(">H", buf, at + field, rng.choice(_EXTREMES) % 2**16)
        return f"jpeg SOF byte {field}"
    if segments:
        at = rng.choice(segments)
        struct.pack_into(">H", buf, at + 2, rng.choice([0, 1, 2, 3, 65535, 32768]))
        return "jpeg segment length"
    return "jpeg: no marker"


def _bmp_edit(buf: bytearray, rng: random.Random) -> str:
    offset, fmt = rng.choice([(2, "<I"), (10, "<I"), (14, "<I"), (18, "<i"), (22, "<i"), (28, "<H"),
                              (30, "<I"), (34, "<I"), (46, "<I")])
    if offset + struct.calcsize(fmt) > len(buf):
        return "bmp: short"
    value = rng.choice(_EXTREMES + [-1, -30000, -(2**31)])
    bits = 8 * struct.calcsize(fmt)
    value = max(-(2 ** (bits - 1)), min(2 ** (bits - 1) - 1, value)) if fmt[1].islower() else value % 2**bits
    struct.pack_into(fmt, buf, offset, value)
    return f"bmp field {offset}"


def _tiff_edit(buf: bytearray, rng: random.Random) -> str:
    if buf[:2] != b"II" or len(buf) < 8:
        return "tiff: not little-endian"
    ifd = struct.unpack_from("<I", buf, 4)[0]
    if ifd + 2 > len(buf):
        return "tiff: ifd past end"
    count = struct.unpack_from("<H", buf, ifd)[0]
    entries = [ifd + 2 + 12 * i for i in range(count) if ifd + 14 + 12 * i <= len(buf)]
    if not entries:
        return "tiff: no entry"
    at = rng.choice(entries)
    tag, kind = struct.unpack_from("<HH", buf, at)
    field = rng.choice(["value", "value", "count", "type"])
    if field == "count":
        struct.pack_into("<I", buf, at + 4, rng.choice(_EXTREMES) % 2**32)
    elif field == "type":
        struct.pack_into("<H", buf, at + 2, rng.choice([0, 1, 3, 4, 5, 16, 255]))
    elif kind == 3:
        struct.pack_into("<H", buf, at + 8, rng.choice(_EXTREMES) % 2**16)
    else:
        struct.pack_into("<I", buf, at + 8, rng.choice(_EXTREMES) % 2**32)
    return f"tiff tag {tag} {field}"


def _pnm_edit(buf: bytearray, rng: random.Random) -> str:
    head = bytes(buf[:64]).split(maxsplit=4)
    if len(head) < 4:
        return "pnm: short"
    magic, width, height, maxval = head[:4]
    pick = rng.randrange(3)
    value = str(rng.choice(_EXTREMES + [-1])).encode()
    fields = [width, height, maxval]
    fields[pick] = value
    tail = bytes(buf[len(b" ".join(head[:4])) + 1:])
    buf[:] = magic + b"\n" + b" ".join(fields) + b"\n" + tail
    return f"pnm header field {pick}"


def _webp_edit(buf: bytearray, rng: random.Random) -> str:
    offset = rng.choice([4, 16, 24, 26, 28])
    if offset + 4 > len(buf):
        return "webp: short"
    struct.pack_into("<I", buf, offset, rng.choice(_EXTREMES) % 2**32)
    return f"webp field {offset}"


def image_header(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """One edit of an image's header structures, chosen by its format."""
    buf = bytearray(data)
    if buf[:8] == b"\x89PNG\r\n\x1a\n":
        what = _png_edit(buf, rng)
    elif buf[:2] == b"\xff\xd8":
        what = _jpeg_edit(buf, rng)
    elif buf[:2] == b"BM":
        what = _bmp_edit(buf, rng)
    elif buf[:2] in (b"II", b"MM"):
        what = _tiff_edit(buf, rng)
    elif buf[:1] == b"P":
        what = _pnm_edit(buf, rng)
    elif buf[:4] == b"RIFF":
        what = _webp_edit(buf, rng)
    else:
        what = "unknown format"
    return bytes(buf), what


# --------------------------------------------------------------------------------- ring geometries
def ring_geometry(rng: random.Random) -> tuple[bytes, str, dict[str, Any]]:
    """UTM positions shaped to make a radius search expensive, and the descriptor counts to check."""
    np_rng = np.random.default_rng(rng.getrandbits(32))
    n_map = int(2 ** rng.uniform(0, 16.6))  # up to 100,000
    n_q = int(2 ** rng.uniform(0, 17)) if rng.random() < 0.995 else 4_000_000
    dims = rng.choice([2, 2, 2, 3, 1])
    radius = 10 ** rng.uniform(-3, 6)
    shape = rng.choice(["ring", "ring", "disk", "line", "grid", "point", "random"])
    if shape == "ring" and dims >= 2:
        angle = np.linspace(0, 2 * np.pi, n_map, endpoint=False)
        db = np.zeros((n_map, dims))
        db[:, 0], db[:, 1] = radius * np.cos(angle), radius * np.sin(angle)
    elif shape == "disk":
        db = np_rng.uniform(-radius, radius, (n_map, dims))
    elif shape == "line":
        db = np.zeros((n_map, dims))
        db[:, 0] = np.linspace(0, radius, n_map)
    elif shape == "grid":
        side = max(1, int(round(n_map ** (1 / dims))))
        db = np.stack(np.meshgrid(*[np.arange(side) * radius / side] * dims), -1).reshape(-1, dims)
        n_map = db.shape[0]
    elif shape == "point":
        db = np.zeros((n_map, dims))
    else:
        db = np_rng.normal(0, radius, (n_map, dims))
    where = "centre" if n_q == 4_000_000 else rng.choice(["centre", "centre", "on", "random"])
    q = (np.zeros((n_q, dims)) if where == "centre" else
         db[np_rng.integers(0, n_map, n_q)] if where == "on" else np_rng.normal(0, radius, (n_q, dims)))
    thr = rng.choice([radius * (1 - 10 ** -rng.randint(1, 12)), radius * (1 + 10 ** -rng.randint(1, 12)),
                      radius, 0.0, radius * 10, radius / 100])
    buffer = io.BytesIO()
    save = np.savez_compressed if n_q == 4_000_000 else np.savez
    save(buffer, utmDb=db, utmQ=q, posDistThr=np.float64(thr))
    counts = rng.random()
    args: dict[str, Any] = ({} if counts < 0.4 else {"n_queries": n_q, "n_map": n_map} if counts < 0.8 else
                            {"n_queries": rng.choice([50, n_q + 1, max(1, n_q - 1)]), "n_map": n_map})
    described = f"{shape} {n_map} map × {n_q} queries ({where}, {dims}-D, thr/r={thr / radius:.3g})"
    return buffer.getvalue(), described, args


# -------------------------------------------------------------------------------------------- names
_NAME_PARTS = ["db", "/", "a", "0001.jpg", " ", "\n", "\r", "\t", "\x0b", "\x1f", "\x7f", "\x85", "\xa0",
               "\u2028", "\u2029", "\u202e", "\u200b", "\ufeff", "é", "日本", "$", "\\frac", "$x^$", '"',
               "'", ",", ";", "..", "@0543256.96@4178906.70@", "INJECTED", "x" * 300, "\U0001F600", "%s",
               "{}", "\ud800"]


def image_names(rng: random.Random) -> tuple[bytes, str]:
    """An hloc file (or a ``btel extract`` sidecar) naming its rows with random, often hostile, names."""
    names: list[str] = []
    for i in range(rng.randint(2, 8)):
        name = "".join(rng.choice(_NAME_PARTS) for _ in range(rng.randint(1, 6)))
        names.append(name if rng.random() < 0.5 else f"img{i}.jpg")
    if rng.random() < 0.3:  # a btel extract .json: file names in a folder
        key = {"descriptor": "hog", "folder": "/nonexistent", "images": [[n, 1, 1] for n in names]}
        return json.dumps(key).encode(), "sidecar " + repr(names)[:200]
    rows = np.random.default_rng(rng.getrandbits(32)).normal(size=(len(names), 8)).astype(np.float32)

    def fill(fh: Any) -> None:
        for name, row in zip(names, rows):
            clean = name.replace("\0", "").strip("/").replace("\ud800", "?") or "x"
            if clean in fh or any(part in (".", "") for part in clean.split("/")):
                continue
            try:
                fh.create_group(clean).create_dataset("global_descriptor", data=row)
            except (ValueError, KeyError, TypeError):
                continue

    return _h5_bytes(fill), "hloc names " + repr(names)[:200]


# ------------------------------------------------------------------------------ memory-mapped .npy
def mmap_seeds() -> list[bytes]:
    """.npy matrices in every layout a mapping must convert or refuse, and declared shapes past the data."""
    X = np.random.default_rng(0).normal(size=(6, 5))
    out = []
    for array in (X.astype(np.float32), np.asfortranarray(X.astype(np.float32)), X, np.asfortranarray(X),
                  X.astype(">f8"), (X * 10).astype(np.int16), (X > 0), X.astype(np.float16),
                  X[:, :1].T.copy()):
        buffer = io.BytesIO()
        np.save(buffer, array)
        out.append(buffer.getvalue())
    for descr, fortran, shape in (("<f4", True, (30_000_000, 100)), ("<f8", False, (10**9, 2)),
                                  ("<f4", False, (3, 0))):
        buffer = io.BytesIO()
        header = {"descr": descr, "fortran_order": fortran, "shape": shape}
        np.lib.format.write_array_header_1_0(buffer, header)
        out.append(buffer.getvalue() + b"\0" * 256)
    return out


# ---------------------------------------------------------------------------------------- readers
def read_names(path: str) -> str:
    """The names reader: names from an hloc file or a sidecar, written into a predictions CSV and a
    pairs file; a name that survives the checks must leave one row (pair) per line."""
    import csv
    import tempfile
    from pathlib import Path

    from btel.cli._names import write_pairs
    from btel.datasets.row_names import row_names
    from btel.datasets import GroundTruth
    from btel.datasets.vpr_names import check_image_names
    from btel.evaluation.records import EvaluationResult
    from btel.evaluation.tables import predictions_csv_text

    data = Path(path).read_bytes()
    if data[:1] == b"{":
        Path(path + ".npy.json").write_bytes(data)
        names = row_names(path + ".npy")
    else:
        from btel.descriptors.hdf5 import load_hloc_global

        names = load_hloc_global(path)[1]
    if names is None:
        return "ok no names"
    check_image_names(names, "names")
    n = len(names)
    result = EvaluationResult(name="m", n_queries=n, predictions=np.arange(n)[::-1].copy(),
                              ground_truth=GroundTruth.frame_aligned(n))
    text = predictions_csv_text(result, names, names)
    rows = list(csv.reader(io.StringIO(text)))
    if text.count("\n") != n + 1 or len(rows) != n + 1 or [r[-3] for r in rows[1:]] != list(names):
        raise AssertionError(f"the predictions CSV does not hold one row per line: {text[:300]!r}")
    ranked = np.stack([np.arange(n), np.arange(n)[::-1]], axis=1)
    with tempfile.TemporaryDirectory() as tmp:
        pairs = Path(tmp) / "pairs.txt"
        written = write_pairs(pairs, ranked, names, names)
        lines = pairs.read_text(encoding="utf-8").split("\n")
    expected = [[names[i], names[j]] for i in range(n) for j in ranked[i]]
    if lines[-1] != "" or [line.split() for line in lines[:-1]] != expected or written != 2 * n:
        raise AssertionError(f"the pairs file does not hold one pair per line: {lines[:6]!r}")
    return f"ok {n} names"
