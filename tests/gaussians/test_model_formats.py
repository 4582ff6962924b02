"""The model files of the web (issue 58): ``.splat``, the compressed PLY and ``.spz`` read back what
their writers put in, within each format's stated quantisation, and every reading problem is one line
naming the file.

* round trips through stealth-ns's own writers (exact where the format is: the standard PLY, a
  ``.splat``'s centres);
* files written by other projects (tests/data/formats, made once by its make_fixtures.py; README.md
  there says with which versions): gsplat 1.5.3's exporter (``.splat``, compressed PLY), PlayCanvas's
  splat-transform 2.7.1 (compressed PLY, SPZ v3 from a PLY, SPZ v4) and Niantic's C++ library (SPZ v2,
  v3). Each ``NAME.npz`` holds the values handed to the writer and, where there is one, what the
  writer's own reader makes of the file: stealth-ns must agree with that reader to float precision;
* bad input: truncated, empty, of a bad magic or an unknown version, missing an element, NaN;
* a few broken rows (NaN, infinite, a zero rotation) left out and recorded, up to the limit (issue 78).
"""

from __future__ import annotations

import gzip
import struct
from pathlib import Path

import numpy as np
import pytest

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.gaussians.broken_rows import MAX_LEFT_OUT_SHARE
from stealth_ns.gaussians.compressed_ply import compressed_ply_tables, read_compressed_ply
from stealth_ns.gaussians.model_files import (
    MODEL_SUFFIXES,
    model_file_name,
    model_format,
    read_model_file,
    write_model_file,
)
from stealth_ns.gaussians.ply import GaussianCloud, checked_rows, write_gaussian_ply
from stealth_ns.gaussians.splat_file import ROW, read_splat, write_splat
from stealth_ns.gaussians.spz import read_spz, spz_bytes, write_spz

DATA = Path(__file__).resolve().parents[1] / "data" / "formats"
SH_C0 = 0.28209479177387814
FIELDS = ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest")
# Niantic's sign table for the SH coefficients under a change of axes (splat-types.h, ``flipSh``),
# with RUB -> RDF's x, y, z = 1, -1, -1
_X, _Y, _Z = 1, -1, -1
RUB_TO_RDF_SH = np.array(
    [_Y, _Z, _X, _X * _Y, _Y * _Z, 1, _X * _Z, 1, _Y, _X * _Y * _Z, _Y, _Z, _X, _Z, _X], dtype=np.float64
)


def random_cloud(n: int, degree: int, seed: int = 0, rest: float = 0.9, extra: bool = False) -> GaussianCloud:
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2 - 1
    return GaussianCloud(
        means=rng.uniform(-3, 3, (n, 3)).astype(np.float32),
        log_scales=rng.uniform(-6, 0, (n, 3)).astype(np.float32),
        quats=rng.normal(size=(n, 4)).astype(np.float32),
        opacity_logits=rng.uniform(-4, 4, n).astype(np.float32),
        sh_dc=rng.uniform(-1.5, 1.5, (n, 3)).astype(np.float32),
        sh_rest=rng.uniform(-rest, rest, (n, k, 3)).astype(np.float32),
        extra={"poison": (rng.random(n) < 0.2).astype(np.uint8)} if extra else {},
    )


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 1 / (1 + np.exp(-np.asarray(x, np.float64)))


def unit(quats: np.ndarray) -> np.ndarray:
    quats = np.asarray(quats, np.float64)
    return quats / np.linalg.norm(quats, axis=1, keepdims=True)


#: Bound of :func:`rotation_gap` for a smallest-three code (compressed PLY, SPZ v3): the three stored
#: components within half a step (~7e-4) each, the recomputed largest within 3 * 0.71 * 7e-4 / 0.5.
SMALLEST_THREE_GAP = 3e-3


def rotation_gap(a: np.ndarray, b: np.ndarray) -> float:
    """Largest difference of a component between the unit quaternions, up to their sign."""
    a, b = unit(a), unit(b)
    return float(np.minimum(np.abs(a - b).max(axis=1), np.abs(a + b).max(axis=1)).max())


def assert_first_three(read: np.ndarray, written: np.ndarray) -> None:
    """SPZ v2 stores x y z of the unit quaternion made w >= 0, each to half of 1/127.5 (w is
    recomputed: coarse when small)."""
    written = unit(written) * np.where(unit(written)[:, :1] < 0, -1, 1)
    np.testing.assert_allclose(unit(read)[:, 1:], written[:, 1:], atol=0.5 / 127.5 + 1e-5)


def chunk_half_steps(values: np.ndarray, bits: tuple[int, ...]) -> np.ndarray:
    """``[N, 3]`` half a quantisation step of each value within its 256-row chunk's range."""
    n = len(values)
    starts = np.arange(0, n, 256)
    span = np.maximum.reduceat(values, starts, axis=0) - np.minimum.reduceat(values, starts, axis=0)
    return span[np.arange(n) // 256] / (2 * (2.0 ** np.array(bits) - 1))


def expected(name: str, kind: str) -> dict[str, np.ndarray]:
    """The ``kind`` values (input or decoded) of fixture ``name``, in the PLY's frame."""
    data = np.load(DATA / f"{name}.npz")
    values = {key: np.asarray(data[f"{kind}_{key}"], np.float64) for key in FIELDS}
    if str(data["frame"]) == "stored":  # SPZ's RUB, as Niantic's library was handed them
        values["means"] = values["means"] * [1, -1, -1]
        values["quats"] = values["quats"] * [1, 1, -1, -1]
        values["sh_rest"] = values["sh_rest"] * RUB_TO_RDF_SH[: values["sh_rest"].shape[1]][None, :, None]
    return values


def assert_same_as_decoded(cloud: GaussianCloud, name: str) -> None:
    """``cloud`` is what the writer's own reader made of fixture ``name`` (to float32 precision)."""
    ref = expected(name, "decoded")
    for key in ("means", "log_scales", "sh_dc", "sh_rest"):
        np.testing.assert_allclose(getattr(cloud, key), ref[key], atol=2e-6, rtol=1e-6, err_msg=key)
    np.testing.assert_allclose(sigmoid(cloud.opacity_logits), sigmoid(ref["opacity_logits"]), atol=1e-6)
    assert rotation_gap(cloud.quats, ref["quats"]) < 1e-5


def one_line_error(call, *words: str) -> str:
    with pytest.raises(StealthNSError) as caught:
        call()
    message = str(caught.value)
    assert "\n" not in message and all(w in message for w in words), message
    return message


# ----------------------------------------------------------------------------------- round trips


def test_the_poison_mask_is_the_tag_or_none():
    tagged = random_cloud(20, 1, extra=True)
    assert np.array_equal(tagged.poison_mask(), tagged.extra["poison"] > 0)
    assert tagged.subset(np.arange(5)).poison_mask().shape == (5,)
    assert random_cloud(20, 1).poison_mask() is None  # no tag
    tagged.extra["poison"] = tagged.extra["poison"][:-1]
    assert tagged.poison_mask() is None  # a tag of another length than the rows


def test_a_standard_ply_goes_through_the_dispatch_unchanged(tmp_path):
    cloud = random_cloud(30, 3, extra=True)
    path = tmp_path / "model.ply"
    write_model_file(path, cloud, like=tmp_path / "input.ply")
    assert model_format(path) == "ply"
    back = read_model_file(path)
    for key in FIELDS:
        np.testing.assert_array_equal(getattr(back, key), getattr(cloud, key))
    np.testing.assert_array_equal(back.extra["poison"], cloud.extra["poison"])


def test_splat_round_trip(tmp_path):
    """Centres exact, scales to float32's exp/log, colour and opacity to half an 8-bit step, the
    rotation to half a step of 1/128; the SH above degree 0 and the extras are dropped."""
    cloud = random_cloud(50, 2, extra=True)
    path = tmp_path / "model.splat"
    write_splat(path, cloud)
    assert path.stat().st_size == 50 * 32
    back = read_splat(path)
    np.testing.assert_array_equal(back.means, cloud.means)
    np.testing.assert_allclose(back.log_scales, cloud.log_scales, atol=1e-6)
    colour = np.clip(0.5 + SH_C0 * cloud.sh_dc.astype(np.float64), 0, 1)
    np.testing.assert_allclose(0.5 + SH_C0 * back.sh_dc.astype(np.float64), colour, atol=0.5 / 255 + 1e-6)
    np.testing.assert_allclose(
        sigmoid(back.opacity_logits), sigmoid(cloud.opacity_logits), atol=0.5 / 255 + 1e-6
    )
    assert rotation_gap(back.quats, cloud.quats) < 2 * 0.5 / 128  # each component, then normalised
    assert back.sh_rest.shape == (50, 0, 3) and back.extra == {}


def test_compressed_ply_round_trip(tmp_path):
    """Three chunks (600 rows): each value within half a step of its chunk's range, the higher SH to
    half of 8/256, rows in their order."""
    cloud = random_cloud(600, 3, rest=3.5, extra=True)
    path = tmp_path / "model.compressed.ply"
    write_model_file(path, cloud, like=DATA / "gsplat-1.5.3.compressed.ply")
    assert model_format(path) == "compressed-ply"
    back = read_model_file(path)
    steps = (11, 10, 11)
    for key in ("means", "log_scales"):
        original = getattr(cloud, key).astype(np.float64)
        assert (
            np.abs(getattr(back, key) - original) <= chunk_half_steps(original, steps) * 1.001 + 1e-6
        ).all()
    colour = 0.5 + SH_C0 * cloud.sh_dc.astype(np.float64)
    bound = chunk_half_steps(colour, (8, 8, 8)) * 1.001 + 1e-6
    assert (np.abs(0.5 + SH_C0 * back.sh_dc.astype(np.float64) - colour) <= bound).all()
    np.testing.assert_allclose(
        sigmoid(back.opacity_logits), sigmoid(cloud.opacity_logits), atol=0.5 / 255 + 1e-6
    )
    assert rotation_gap(back.quats, cloud.quats) < SMALLEST_THREE_GAP
    np.testing.assert_allclose(back.sh_rest, cloud.sh_rest, atol=4 / 256 + 1e-6)
    assert back.extra == {}


@pytest.mark.parametrize("version", [2, 3])
def test_spz_round_trip(tmp_path, version):
    """Centres to 1/8192, log scales to 1/32, colour to half of 1/(0.15 * 255), the higher SH to 1/256,
    the rotation to 9 bits (v3) or 8 (v2); the frame turns to SPZ's RUB and back."""
    cloud = random_cloud(40, 3, seed=version)
    path = tmp_path / "model.spz"
    write_spz(path, cloud, version=version)
    header = gzip.decompress(path.read_bytes())[:16]
    assert struct.unpack("<4sIIBBBB", header) == (b"NGSP", version, 40, 3, 12, 0, 0)
    back = read_spz(path)
    np.testing.assert_allclose(back.means, cloud.means, atol=0.5 / 4096 + 1e-6)
    np.testing.assert_allclose(back.log_scales, cloud.log_scales, atol=1 / 32 + 1e-6)
    np.testing.assert_allclose(back.sh_dc, cloud.sh_dc, atol=0.5 / (0.15 * 255) + 1e-6)
    np.testing.assert_allclose(
        sigmoid(back.opacity_logits), sigmoid(cloud.opacity_logits), atol=0.5 / 255 + 1e-6
    )
    np.testing.assert_allclose(back.sh_rest, cloud.sh_rest, atol=0.5 / 128 + 1e-6)
    if version == 3:
        assert rotation_gap(back.quats, cloud.quats) < SMALLEST_THREE_GAP
    else:
        assert_first_three(back.quats, cloud.quats)


def test_spz_stores_the_turned_frame(tmp_path):
    """What is stored is the cloud turned half a turn about x: the centre (1, 2, 3) is stored as
    (1, -2, -3), and an SH coefficient odd in y (the first of degree 1) changes sign."""
    cloud = random_cloud(1, 1)
    cloud.means[:] = [1, 2, 3]
    cloud.sh_rest[:] = 0
    cloud.sh_rest[0, 0, 0] = 0.5
    payload = spz_bytes(tmp_path / "x.spz", cloud)
    fixed = np.frombuffer(payload[16:25], np.uint8).reshape(3, 3).astype(np.int64)
    values = fixed[:, 0] | fixed[:, 1] << 8 | fixed[:, 2] << 16
    values = np.where(values & 0x800000, values - (1 << 24), values) / 4096
    np.testing.assert_array_equal(values, [1, -2, -3])
    assert payload[-9] == 64  # 128 + 128 * -0.5


def test_spz_far_centres_get_fewer_fractional_bits(tmp_path):
    cloud = random_cloud(5, 0)
    cloud.means[0] = [5000.25, -3000.5, 0]
    path = tmp_path / "far.spz"
    write_spz(path, cloud)
    assert gzip.decompress(path.read_bytes())[13] == 10  # 5000 * 2^10 < 2^23
    np.testing.assert_allclose(read_spz(path).means, cloud.means, atol=0.5 / 1024 + 1e-6)
    cloud.means[0] = [1e7, 0, 0]
    one_line_error(lambda: write_spz(tmp_path / "too-far.spz", cloud), "far.spz", "24-bit")


def test_model_file_names_and_formats(tmp_path):
    assert MODEL_SUFFIXES == (".ply", ".splat", ".spz")
    assert model_file_name("cleaned", DATA / "gsplat-1.5.3.compressed.ply") == "cleaned.compressed.ply"
    assert model_file_name("cleaned", DATA / "niantic-v3.spz") == "cleaned.spz"
    assert model_file_name("cleaned", DATA / "gsplat-1.5.3.splat") == "cleaned.splat"
    write_gaussian_ply(tmp_path / "plain.ply", random_cloud(3, 0))
    assert model_file_name("cleaned", tmp_path / "plain.ply") == "cleaned.ply"
    # a compressed PLY is told by its header, whatever its name
    (tmp_path / "renamed.ply").write_bytes((DATA / "gsplat-1.5.3.compressed.ply").read_bytes())
    assert model_format(tmp_path / "renamed.ply") == "compressed-ply"
    one_line_error(lambda: read_model_file(tmp_path / "model.ksplat"), "model.ksplat", ".ply, .splat, .spz")


# ---------------------------------------------------------------------------- independent writers


def test_gsplat_splat_file():
    """gsplat 1.5.3's .splat (it truncates colour, opacity and rotation to 8 bits): within a step."""
    cloud = read_model_file(DATA / "gsplat-1.5.3.splat")
    ref = expected("gsplat-1.5.3.splat", "input")
    np.testing.assert_array_equal(cloud.means, ref["means"])
    np.testing.assert_allclose(cloud.log_scales, ref["log_scales"], atol=1e-6)
    np.testing.assert_allclose(cloud.sh_dc, ref["sh_dc"], atol=1 / 255 / SH_C0 + 1e-5)
    np.testing.assert_allclose(
        sigmoid(cloud.opacity_logits), sigmoid(ref["opacity_logits"]), atol=1 / 255 + 1e-6
    )
    assert rotation_gap(cloud.quats, ref["quats"]) < 2 * 1 / 128  # truncated, then normalised
    assert cloud.sh_rest.shape == (40, 0, 3)


@pytest.mark.parametrize(
    "name",
    [
        "gsplat-1.5.3.compressed.ply",
        "gsplat-1.5.3-sh0.compressed.ply",
        "splat-transform-2.7.1.compressed.ply",
    ],
)
def test_compressed_ply_files(name):
    """gsplat's and PlayCanvas's compressed PLYs (two chunks and an sh element; gsplat's of SH degree 0
    has an sh element of no properties): what splat-transform decodes (it refuses the latter), and the
    values written within half a step of their chunk's range."""
    cloud = read_model_file(DATA / name)
    if "sh0" not in name:
        assert_same_as_decoded(cloud, name)
    ref = expected(name, "input")
    for key in ("means", "log_scales"):
        bound = chunk_half_steps(ref[key], (11, 10, 11)) * 1.001 + 1e-6
        assert (np.abs(getattr(cloud, key) - ref[key]) <= bound).all(), key
    colour = 0.5 + SH_C0 * ref["sh_dc"]
    bound = chunk_half_steps(colour, (8, 8, 8)) * 1.001 + 1e-6
    assert (np.abs(0.5 + SH_C0 * cloud.sh_dc.astype(np.float64) - colour) <= bound).all()
    np.testing.assert_allclose(
        sigmoid(cloud.opacity_logits), sigmoid(ref["opacity_logits"]), atol=0.5 / 255 + 1e-6
    )
    assert rotation_gap(cloud.quats, ref["quats"]) < SMALLEST_THREE_GAP
    assert cloud.sh_rest.shape == ref["sh_rest"].shape
    np.testing.assert_allclose(cloud.sh_rest, ref["sh_rest"], atol=4 / 256 + 1e-6)


def test_compressed_ply_of_twelve_chunk_properties(tmp_path):
    """SuperSplat's first layout has no colour bounds: the packed colour is the colour itself."""
    tables = compressed_ply_tables(random_cloud(20, 0))
    chunk = tables["chunk"][[p for p in tables["chunk"].dtype.names if p[-1] not in "rgb"]]
    assert len(chunk.dtype.names) == 12
    path = compressed_file(tmp_path, "old.compressed.ply", {"chunk": chunk, "vertex": tables["vertex"]})
    cloud = read_model_file(path)
    codes = np.stack([(tables["vertex"]["packed_color"] >> s) & 0xFF for s in (24, 16, 8)], axis=-1)
    np.testing.assert_allclose(0.5 + SH_C0 * cloud.sh_dc.astype(np.float64), codes / 255, atol=1e-6)
    assert cloud.sh_rest.shape == (20, 0, 3)


@pytest.mark.parametrize("name", ["niantic-v2.spz", "niantic-v3.spz", "splat-transform-2.7.1-v3.spz"])
def test_spz_files(name):
    """Niantic's library (v2, v3: handed RUB values, read back turned into the PLY's frame) and
    splat-transform (v3 from a PLY: read back in that PLY's frame): what their readers decode, and
    the values written within Niantic's quantisation (degree-1 SH to 5 bits, higher to 4)."""
    cloud = read_model_file(DATA / name)
    assert_same_as_decoded(cloud, name)
    ref = expected(name, "input")
    np.testing.assert_allclose(cloud.means, ref["means"], atol=0.5 / 4096 + 1e-6)
    np.testing.assert_allclose(cloud.log_scales, ref["log_scales"], atol=1 / 32 + 1e-6)
    np.testing.assert_allclose(cloud.sh_dc, ref["sh_dc"], atol=0.5 / (0.15 * 255) + 1e-6)
    np.testing.assert_allclose(
        sigmoid(cloud.opacity_logits), sigmoid(ref["opacity_logits"]), atol=0.5 / 255 + 1e-6
    )
    np.testing.assert_allclose(cloud.sh_rest[:, :3], ref["sh_rest"][:, :3], atol=4.5 / 128 + 1e-6)
    np.testing.assert_allclose(cloud.sh_rest[:, 3:], ref["sh_rest"][:, 3:], atol=8.5 / 128 + 1e-6)
    if "v2" in name:
        assert_first_three(cloud.quats, ref["quats"])
    else:
        assert rotation_gap(cloud.quats, ref["quats"]) < SMALLEST_THREE_GAP


def test_an_spz_from_the_web_is_written_back_as_it_reads(tmp_path):
    """Read, written (v3) and read again, a third-party .spz keeps its values: the quantised codes
    (centres, scales, colours, opacities, SH) come back the same."""
    cloud = read_model_file(DATA / "splat-transform-2.7.1-v3.spz")
    write_model_file(tmp_path / "cleaned.spz", cloud, like=DATA / "splat-transform-2.7.1-v3.spz")
    again = read_model_file(tmp_path / "cleaned.spz")
    for key in ("means", "log_scales", "sh_dc", "opacity_logits", "sh_rest"):
        np.testing.assert_allclose(getattr(again, key), getattr(cloud, key), atol=1e-6, err_msg=key)
    assert rotation_gap(again.quats, cloud.quats) < SMALLEST_THREE_GAP


# -------------------------------------------------------------------------------------- bad input


def test_splat_errors(tmp_path):
    good = (DATA / "gsplat-1.5.3.splat").read_bytes()
    cut = tmp_path / "cut.splat"
    cut.write_bytes(good[:-5])
    one_line_error(lambda: read_model_file(cut), str(cut), "32-byte", "39 rows and 27 bytes over")
    empty = tmp_path / "empty.splat"
    empty.write_bytes(b"")
    one_line_error(lambda: read_model_file(empty), str(empty), "no Gaussians")
    one_line_error(lambda: read_model_file(tmp_path / "none.splat"), "no .splat file", "none.splat")
    rows = bytearray(good)
    rows[32:36] = struct.pack("<f", float("nan"))
    nan = tmp_path / "nan.splat"
    nan.write_bytes(bytes(rows))
    one_line_error(lambda: read_model_file(nan), str(nan), "1 of 40 Gaussians have a NaN", "rows 1", "2.5%")


def spz_file(tmp_path: Path, payload: bytes, name: str = "bad.spz") -> Path:
    path = tmp_path / name
    path.write_bytes(gzip.compress(payload))
    return path


def test_spz_errors(tmp_path):
    good = gzip.decompress((DATA / "niantic-v3.spz").read_bytes())
    v4 = DATA / "splat-transform-2.7.1-v4.spz"
    one_line_error(lambda: read_model_file(v4), str(v4), "version 4", "versions 2 and 3")
    for version in (1, 7):
        path = spz_file(tmp_path, good[:4] + struct.pack("<I", version) + good[8:], f"v{version}.spz")
        one_line_error(
            lambda p=path: read_model_file(p), str(path), f"SPZ version {version} is not supported"
        )
    path = spz_file(tmp_path, b"SPZN" + good[4:])
    one_line_error(lambda: read_model_file(path), str(path), "bad SPZ magic")
    path = spz_file(tmp_path, good[:-10], "short.spz")
    one_line_error(lambda: read_model_file(path), str(path), "cut short", "40 Gaussians")
    path = spz_file(tmp_path, good[:10], "header.spz")
    one_line_error(lambda: read_model_file(path), str(path), "header is cut short")
    path = spz_file(tmp_path, good[:12] + bytes([4]) + good[13:], "degree.spz")
    one_line_error(lambda: read_model_file(path), str(path), "SH degree 4")
    path = spz_file(tmp_path, good[:8] + struct.pack("<I", 0) + good[12:], "zero.spz")
    one_line_error(lambda: read_model_file(path), str(path), "no Gaussians")
    truncated = tmp_path / "truncated.spz"
    truncated.write_bytes((DATA / "niantic-v3.spz").read_bytes()[:-100])
    one_line_error(lambda: read_model_file(truncated), str(truncated), "gzip stream is broken")
    plain = tmp_path / "plain.spz"
    plain.write_bytes(b"this is not a model")
    one_line_error(lambda: read_model_file(plain), str(plain), "not an SPZ file")


def compressed_file(tmp_path: Path, name: str, tables: dict[str, np.ndarray]) -> Path:
    from numpy.lib.recfunctions import repack_fields
    from plyfile import PlyData, PlyElement

    path = tmp_path / name
    elements = [PlyElement.describe(repack_fields(rows), key) for key, rows in tables.items()]
    PlyData(elements, byte_order="<").write(str(path))
    return path


def test_compressed_ply_errors(tmp_path):
    tables = compressed_ply_tables(random_cloud(300, 1))
    path = compressed_file(tmp_path, "no-vertex.ply", {"chunk": tables["chunk"]})
    one_line_error(lambda: read_model_file(path), str(path), "without its 'vertex' element")
    chunk = tables["chunk"][[n for n in tables["chunk"].dtype.names if n != "max_scale_y"]]
    path = compressed_file(tmp_path, "no-bound.ply", {**tables, "chunk": chunk})
    one_line_error(lambda: read_model_file(path), str(path), "'chunk' element lacks max_scale_y")
    path = compressed_file(tmp_path, "one-chunk.ply", {**tables, "chunk": tables["chunk"][:1]})
    one_line_error(lambda: read_model_file(path), str(path), "1 chunks for 300 Gaussians")
    sh = tables["sh"][[f"f_rest_{i}" for i in range(8)]]
    path = compressed_file(tmp_path, "sh8.ply", {**tables, "sh": sh})
    one_line_error(lambda: read_model_file(path), str(path), "8 properties", "SH degree 1-3")
    path = compressed_file(tmp_path, "sh-rows.ply", {**tables, "sh": tables["sh"][:299]})
    one_line_error(lambda: read_model_file(path), str(path), "299 rows for 300 Gaussians")
    nan_chunk = tables["chunk"].copy()
    nan_chunk["max_x"][1] = np.nan  # the second chunk's 44 rows: far above the share left out
    path = compressed_file(tmp_path, "nan.ply", {**tables, "chunk": nan_chunk})
    one_line_error(
        lambda: read_compressed_ply(path), str(path), "44 of 300 Gaussians have a NaN", "14.7% of its rows"
    )
    broken = tmp_path / "broken.compressed.ply"
    broken.write_bytes((DATA / "gsplat-1.5.3.compressed.ply").read_bytes()[:-200])
    one_line_error(lambda: read_model_file(broken), str(broken), "not a readable PLY file")


# ------------------------------------------------------------------------------- broken rows


def test_a_few_broken_rows_of_a_ply_are_left_out_and_recorded(tmp_path):
    """Up to 1 % of the rows may be broken (here 5 of 500, one a zero rotation): they are left out, the
    others read in their order, poison tag included; a sixth is one too many."""
    assert MAX_LEFT_OUT_SHARE == 0.01
    cloud = random_cloud(500, 1, extra=True)
    cloud.means[5, 0] = np.nan
    cloud.log_scales[17, 2] = np.inf
    cloud.sh_rest[17, 1, 0] = np.nan  # the same row twice: counted once, under both reasons
    cloud.quats[99] = 0.0
    cloud.opacity_logits[250] = -np.inf
    cloud.sh_dc[499, 1] = np.nan
    path = tmp_path / "model.ply"
    write_gaussian_ply(path, cloud)
    back = read_model_file(path)
    keep = np.ones(500, bool)
    keep[[5, 17, 99, 250, 499]] = False
    assert len(back) == 495
    for key in FIELDS:
        assert np.array_equal(getattr(back, key), getattr(cloud.subset(keep), key)), key
    assert np.array_equal(back.poison_mask(), cloud.poison_mask()[keep])
    record = back.left_out
    assert (record.count, record.total, record.rows) == (5, 500, (5, 17, 99, 250, 499))
    assert record.reasons == {
        "NaN or infinite centre": 1,
        "NaN or infinite scale": 1,
        "NaN or infinite opacity": 1,
        "NaN or infinite colour (SH degree 0)": 1,
        "NaN or infinite colour (higher SH)": 1,
        "zero rotation": 1,
    }
    said = record.line()
    assert said.startswith("left out 5 of 500 Gaussians (1%, at most 1%): NaN or infinite centre (1), ")
    assert said.endswith(", zero rotation (1); rows 5, 17, 99, 250, 499")
    assert record.record()["rows"] == [5, 17, 99, 250, 499] and record.record()["limit_share"] == 0.01
    assert back.subset(np.arange(3)).left_out is None  # a record of the file, not of a selection
    cloud.means[300, 1] = np.inf
    write_gaussian_ply(path, cloud)
    one_line_error(
        lambda: read_model_file(path),
        str(path),
        "6 of 500 Gaussians have a NaN, infinite or zero-rotation value (rows 5, 17, 99, 250, 300, ...)",
        "1.2% of its rows, more than the 1% a reader leaves out",
    )


def test_a_few_broken_rows_of_a_splat_are_left_out(tmp_path):
    """A .splat of 400 rows, 3 broken (a NaN centre, a zero scale, a zero rotation): left out, the rest
    as the unbroken file reads; 5 broken (1.25 %) are refused."""
    path = tmp_path / "model.splat"
    write_splat(path, random_cloud(400, 0))
    whole = read_splat(path)
    assert whole.left_out is None
    rows = np.frombuffer(path.read_bytes(), dtype=ROW).copy()
    rows["mean"][7, 2] = np.nan
    rows["scale"][123, 0] = 0.0  # log scale -inf
    rows["rot"][300] = 128  # every component 0
    broken = tmp_path / "broken.splat"
    broken.write_bytes(rows.tobytes())
    back = read_model_file(broken)
    keep = np.ones(400, bool)
    keep[[7, 123, 300]] = False
    for key in FIELDS:
        assert np.array_equal(getattr(back, key), getattr(whole.subset(keep), key)), key
    assert (back.left_out.count, back.left_out.total, back.left_out.rows) == (3, 400, (7, 123, 300))
    reasons = {"NaN or infinite centre": 1, "NaN or infinite scale": 1, "zero rotation": 1}
    assert back.left_out.reasons == reasons
    rows["mean"][[8, 9], 0] = np.inf
    broken.write_bytes(rows.tobytes())
    one_line_error(lambda: read_model_file(broken), str(broken), "5 of 400 Gaussians", "1.25% of its rows")


def test_leaving_rows_out_is_pure_and_every_broken_row_is_refused(tmp_path):
    cloud = random_cloud(10, 0)
    same, record = cloud.without_broken_rows()
    assert same is cloud and (record.count, record.total, record.reasons, record.rows) == (0, 10, {}, ())
    assert checked_rows(tmp_path / "x.ply", cloud) is cloud and cloud.left_out is None
    cloud.means[:] = np.nan
    kept, record = cloud.without_broken_rows()
    assert len(kept) == 0 and record.count == 10 and record.rows == (0, 1, 2, 3, 4)
    assert np.isnan(cloud.means).all()  # the input is left as it was
    one_line_error(
        lambda: checked_rows(tmp_path / "x.ply", cloud), "x.ply", "10 of 10 Gaussians", "every row is broken"
    )
