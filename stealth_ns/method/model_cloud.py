"""A splatfacto-family model's Gaussians as a :class:`~stealth_ns.gaussians.ply.GaussianCloud`, and back.

splatfacto stores SH coefficients in ``features_dc`` / ``features_rest`` when its ``sh_degree`` is
above 0 and a colour logit in ``features_dc`` when it is 0 (``shs_0`` converts); a PLY always holds SH.
Loading pads the cloud's SH with zero coefficients up to the model's degree, which renders the same
colours (a zero coefficient adds nothing), and loads the poison tag when the cloud has one.
"""

from __future__ import annotations

import numpy as np
import torch
from nerfstudio.models.splatfacto import RGB2SH, num_sh_bases

from stealth_ns.gaussians.ply import GaussianCloud
from stealth_ns.method.model import POISON_TAG, StealthSplatModel

#: What the loaded model's ``step`` is set to: late enough that every SH degree is active.
LOADED_STEP = 30000


def cloud_of_params(params: dict[str, torch.Tensor], sh_degree: int) -> GaussianCloud:
    """The rows of a splatfacto ``gauss_params`` (a checkpoint's or a live model's) of SH degree
    ``sh_degree`` as a cloud; a ``poison`` entry becomes ``extra["poison"]`` (uint8)."""
    p = {k: v.detach().float().cpu() for k, v in params.items()}
    dc = p["features_dc"] if sh_degree > 0 else RGB2SH(torch.sigmoid(p["features_dc"]))
    rest = p["features_rest"] if sh_degree > 0 else torch.zeros(len(dc), 0, 3)
    extra = {}
    if POISON_TAG in p:
        extra["poison"] = (p[POISON_TAG].reshape(-1) > 0.5).numpy().astype(np.uint8)
    return GaussianCloud(
        means=p["means"].numpy(),
        log_scales=p["scales"].numpy(),
        quats=p["quats"].numpy(),
        opacity_logits=p["opacities"].reshape(-1).numpy(),
        sh_dc=dc.numpy(),
        sh_rest=rest.numpy(),
        extra=extra,
    )


def cloud_of_model(model: StealthSplatModel) -> GaussianCloud:
    """Every row of ``model`` as a cloud (poison tag in ``extra["poison"]``)."""
    return cloud_of_params(dict(model.gauss_params.items()), model.config.sh_degree)


@torch.no_grad()
def load_cloud(model: StealthSplatModel, cloud: GaussianCloud) -> None:
    """Replace every row of ``model`` (whose ``sh_degree`` must be at least the cloud's and above 0)
    by ``cloud``; the model's ``step`` becomes :data:`LOADED_STEP` (all SH degrees active)."""
    degree = model.config.sh_degree
    if degree < max(cloud.sh_degree, 1):
        raise ValueError(f"a model of SH degree {degree} cannot hold a cloud of degree {cloud.sh_degree}")
    n, k = len(cloud), num_sh_bases(degree) - 1
    rest = np.zeros((n, k, 3), dtype=np.float32)
    rest[:, : cloud.sh_rest.shape[1]] = cloud.sh_rest
    tag = cloud.extra.get("poison")
    state = model.state_dict()
    rows = {
        "means": cloud.means,
        "scales": cloud.log_scales,
        "quats": cloud.quats,
        "features_dc": cloud.sh_dc,
        "features_rest": rest,
        "opacities": cloud.opacity_logits.reshape(n, 1),
        POISON_TAG: np.zeros(n, np.float32) if tag is None else (np.asarray(tag) > 0).astype(np.float32),
    }
    for name, values in rows.items():
        state[f"gauss_params.{name}"] = torch.from_numpy(np.ascontiguousarray(values, dtype=np.float32))
    model.load_state_dict(state)  # splatfacto's resizes every row to the state's count, on the model's device
    model.step = LOADED_STEP
