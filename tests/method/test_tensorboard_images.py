"""TensorBoard's evaluation images: nerfstudio's pixels, a faster PNG level (tensorboard_images.py)."""

from __future__ import annotations

import io

import numpy as np
import torch
from PIL import Image
from tensorboard.backend.event_processing.event_accumulator import IMAGES, EventAccumulator

from stealth_ns.method import tensorboard_images
from stealth_ns.method.tensorboard_images import FastPngTensorboardWriter, use_fast_png

writer = tensorboard_images.writer  # nerfstudio's, imported the way that module does


def _written_images(log_dir) -> dict[str, np.ndarray]:
    events = EventAccumulator(str(log_dir), size_guidance={IMAGES: 0})
    events.Reload()
    return {
        tag: np.asarray(Image.open(io.BytesIO(events.Images(tag)[-1].encoded_image_string)))
        for tag in events.Tags()[IMAGES]
    }


def test_fast_writer_writes_nerfstudios_pixels(tmp_path, monkeypatch):
    g = torch.Generator().manual_seed(0)
    image = torch.rand(37, 53, 3, generator=g) * 1.2 - 0.1  # out of range both ways: to8b clamps
    stock = writer.TensorboardWriter(log_dir=tmp_path / "stock")
    fast = writer.TensorboardWriter(log_dir=tmp_path / "fast")
    monkeypatch.setattr(writer, "EVENT_WRITERS", [fast])
    use_fast_png()
    assert type(fast) is FastPngTensorboardWriter
    for w in (stock, fast):
        w.write_image("Eval Images/img", image, step=100)
        w.write_image("Eval Images/grey", image[..., :1], step=100)  # [H, W, 1]: depth, opacity
        w.tb_writer.flush()
    ours, theirs = _written_images(tmp_path / "fast"), _written_images(tmp_path / "stock")
    assert set(ours) == set(theirs) == {"Eval Images/img", "Eval Images/grey"}
    for tag in ours:
        np.testing.assert_array_equal(ours[tag], theirs[tag])
    np.testing.assert_array_equal(ours["Eval Images/img"], writer.to8b(image).numpy())


def test_other_writers_are_left_alone(monkeypatch):
    class Subclassed(writer.TensorboardWriter):  # somebody else's writer: not ours to change
        def __init__(self) -> None:
            pass

    others = [Subclassed(), writer.LocalWriter.__new__(writer.LocalWriter)]
    monkeypatch.setattr(writer, "EVENT_WRITERS", list(others))
    use_fast_png()
    assert [type(w) for w in writer.EVENT_WRITERS] == [type(w) for w in others]
    assert 0 <= tensorboard_images.PNG_COMPRESS_LEVEL <= 9
