"""stealth_ns.images.io: the one place images are read, written and converted. Fast, CPU only.

PIL appears here only to check compatibility with the outside world: files written by
``save_png`` read back the same with Pillow (what nerfstudio decodes with), and files written by
Pillow (16-bit, palette) read back right with ``read_image``.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest
import torch
from PIL import Image

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.images.io import (
    image_info,
    image_size,
    read_image,
    save_png,
    split_alpha,
    to_float32,
    to_uint8,
)


def test_save_png_roundtrip_and_pillow_reads_it(tmp_path):
    arr = np.linspace(0, 1, 30, dtype=np.float32).reshape(5, 6)
    p = save_png(tmp_path / "a" / "b.png", arr)  # creates the parent folder
    expected = np.round(arr * 255).astype(np.uint8)
    np.testing.assert_array_equal(read_image(p), expected)
    np.testing.assert_array_equal(np.asarray(Image.open(p)), expected)
    np.testing.assert_array_equal(
        read_image(save_png(tmp_path / "m.png", torch.tensor([[True, False]]))), [[255, 0]]
    )
    rgba = np.random.default_rng(0).integers(0, 256, (7, 9, 4), dtype=np.uint8)
    p = save_png(tmp_path / "rgba.png", rgba)
    assert Image.open(p).mode == "RGBA" and image_size(p) == (9, 7)
    np.testing.assert_array_equal(read_image(p), rgba)
    with pytest.raises(ValueError, match="save_png expects"):
        save_png(tmp_path / "bad.png", np.zeros((2, 2, 2)))


def test_save_png_is_deterministic(tmp_path):
    image = np.random.default_rng(1).random((12, 16, 3))
    a, b = save_png(tmp_path / "a.png", image), save_png(tmp_path / "b.png", image)
    assert a.read_bytes() == b.read_bytes()


def test_read_image_keeps_16_bit_and_expands_palettes(tmp_path):
    deep = (np.arange(12, dtype=np.uint16).reshape(3, 4) * 5000).astype(np.uint16)
    Image.fromarray(deep).save(tmp_path / "deep.png")
    got = read_image(tmp_path / "deep.png")
    assert got.dtype == np.uint16
    np.testing.assert_array_equal(got, deep)
    np.testing.assert_allclose(to_float32(got), deep / 65535.0, atol=1e-7)
    rgb = np.zeros((4, 5, 3), np.uint8)
    rgb[1:3, 1:4] = (200, 30, 10)
    Image.fromarray(rgb).convert("P", palette=Image.Palette.ADAPTIVE, colors=4).save(tmp_path / "pal.png")
    np.testing.assert_array_equal(read_image(tmp_path / "pal.png"), rgb)
    assert image_info(tmp_path / "pal.png").channels == 3


def test_unreadable_files_are_one_line_naming_the_file(tmp_path):
    (tmp_path / "notes.png").write_text("this is not an image")
    good = save_png(tmp_path / "good.png", np.random.default_rng(2).random((64, 64, 3)))
    data = good.read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    cases = {
        tmp_path / "missing.png": "does not exist",
        tmp_path: "is not a file",
        tmp_path / "notes.png": "cannot be read as an image (not a format Pillow can read)",
        tmp_path / "cut.png": "cannot be read as an image",
    }
    for path, needle in cases.items():
        with pytest.raises(StealthNSError) as info:
            read_image(path, "frame 3: image")
        message = str(info.value)
        assert message.startswith(f"frame 3: image {path} ") and needle in message and "\n" not in message
    assert image_size(tmp_path / "cut.png") == (64, 64)  # the header alone is intact


def test_conversions():
    np.testing.assert_array_equal(
        to_uint8(np.array([0.0, 0.5 / 255, 1.5 / 255, np.nan, 2.0, -1.0])), [0, 0, 2, 0, 255, 0]
    )
    np.testing.assert_array_equal(to_uint8(np.array([True, False])), [255, 0])
    np.testing.assert_array_equal(to_uint8(np.array([0, 65535], np.uint16)), [0, 255])
    assert to_float32(np.array([-32768, 0, 32767], np.int16)).tolist() == [0.0, 0.0, 1.0]
    assert to_float32(np.array([0, 255], np.uint8)).dtype == np.float32
    u8 = np.arange(256, dtype=np.uint8)
    np.testing.assert_array_equal(to_uint8(to_float32(u8)), u8)
    np.testing.assert_array_equal(to_uint8(torch.tensor([0.0, 1.0])), [0, 255])


def test_split_alpha():
    grey_alpha = np.stack([np.full((2, 3), 51, np.uint8), np.full((2, 3), 255, np.uint8)], axis=-1)
    rgb, alpha = split_alpha(grey_alpha)
    assert rgb.shape == (2, 3, 3) and np.allclose(rgb, 0.2) and np.allclose(alpha, 1.0)
    rgb, alpha = split_alpha(np.zeros((2, 3, 3), np.uint8))
    assert alpha is None and rgb.shape == (2, 3, 3)
    rgb, alpha = split_alpha(np.ones((2, 3)))
    assert alpha is None and rgb.shape == (2, 3, 3)


def test_importing_it_does_not_import_torch():
    import subprocess

    code = "import sys, stealth_ns.images.io; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
