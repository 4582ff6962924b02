"""TensorBoard's evaluation images with the same pixels, encoded at a faster PNG level.

nerfstudio writes an evaluation image every ``steps_per_eval_image`` steps (100 in splatfacto and
stealth-splat): the ground truth beside the render. TensorBoard encodes it as a PNG through Pillow
at zlib level 6, a large part of such a step at 1 MP. Zlib level 1 encodes the same pixels faster
into a somewhat larger file (timings and sizes: docs/design/training_step.md).
"""

from __future__ import annotations

import nerfstudio.configs.base_config  # noqa: F401  (imported first, nerfstudio's writer imports cleanly)
import numpy as np
import torch
from nerfstudio.utils import writer

from stealth_ns.images.io import encode_png

#: zlib level of the evaluation images' PNGs (0-9; TensorBoard's own is Pillow's default, 6).
PNG_COMPRESS_LEVEL = 1


class FastPngTensorboardWriter(writer.TensorboardWriter):
    """nerfstudio's TensorBoard writer, its images encoded at :data:`PNG_COMPRESS_LEVEL`."""

    def write_image(self, name: str, image: torch.Tensor, step: int) -> None:
        from tensorboard.compat.proto.summary_pb2 import Summary

        pixels = writer.to8b(image).cpu().numpy()  # nerfstudio's conversion: the same pixels
        if pixels.shape[2] == 1:  # grey (depth, opacity) as RGB, as add_image writes it
            pixels = np.repeat(pixels, 3, axis=2)
        height, width, channels = pixels.shape
        png = Summary.Image(
            height=height,
            width=width,
            colorspace=channels,
            encoded_image_string=encode_png(pixels, PNG_COMPRESS_LEVEL),
        )
        summary = Summary(value=[Summary.Value(tag=name, image=png)])
        # what SummaryWriter.add_image does with the Summary it builds
        self.tb_writer._get_file_writer().add_summary(summary, step)


def use_fast_png() -> None:
    """Make nerfstudio's TensorBoard writers (set up by ``Trainer.setup``) write faster PNGs."""
    for event_writer in writer.EVENT_WRITERS:
        if type(event_writer) is writer.TensorboardWriter:
            event_writer.__class__ = FastPngTensorboardWriter
