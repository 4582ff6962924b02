"""Make the model-format fixtures beside this file with writers independent of stealth-ns.

Run once, in a throwaway environment (README.md beside this file says which versions, and how they
were installed); the test (tests/gaussians/test_model_formats.py) only reads what this leaves:

    python tests/data/formats/make_fixtures.py --splat-transform /path/to/node_modules/.bin/splat-transform

Each fixture ``NAME`` comes with ``NAME.npz``: ``input_*`` the values handed to the writer, row for
row in the file's order, and, where the writer's project has a reader, ``decoded_*`` what that reader
gives back. Arrays follow stealth-ns's GaussianCloud: ``means [N, 3]``, ``log_scales [N, 3]``,
``quats [N, 4]`` (w x y z), ``opacity_logits [N]``, ``sh_dc [N, 3]``, ``sh_rest [N, K, 3]``
(coefficient-major); ``frame`` says whether they are in the file's own frame (``stored``: the SPZ's
RUB as written) or the PLY's (``ply``).
"""

from __future__ import annotations

import argparse
import subprocess
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
FIELDS = ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest")


def random_model(seed: int, n: int, degree: int, rest_range: float) -> dict[str, np.ndarray]:
    """``n`` Gaussians with SH up to ``degree`` (the higher SH uniform in +-``rest_range``)."""
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2 - 1
    return {
        "means": rng.uniform(-2, 2, (n, 3)).astype(np.float32),
        "log_scales": rng.uniform(-5, -1, (n, 3)).astype(np.float32),
        "quats": rng.normal(size=(n, 4)).astype(np.float32),
        "opacity_logits": rng.uniform(-3, 5, n).astype(np.float32),
        "sh_dc": rng.uniform(-1.5, 1.5, (n, 3)).astype(np.float32),
        "sh_rest": rng.uniform(-rest_range, rest_range, (n, k, 3)).astype(np.float32),
    }


def save(name: str, frame: str, inputs: dict, decoded: dict | None = None) -> None:
    arrays = {f"input_{key}": np.asarray(value) for key, value in inputs.items()}
    arrays.update({f"decoded_{key}": np.asarray(value) for key, value in (decoded or {}).items()})
    np.savez_compressed(HERE / f"{name}.npz", frame=np.array(frame), **arrays)


def rows(model: dict, order: np.ndarray) -> dict:
    return {key: value[order] for key, value in model.items()}


def gsplat_export(model: dict, fmt: str, path: Path) -> np.ndarray:
    """Write ``model`` with gsplat's exporter; the file's row order (its Morton sort)."""
    import torch
    from gsplat.exporter import export_splats, sort_centers

    tensors = {key: torch.from_numpy(value) for key, value in model.items()}
    export_splats(
        tensors["means"],
        tensors["log_scales"],
        tensors["quats"],
        tensors["opacity_logits"],
        tensors["sh_dc"][:, None, :],
        tensors["sh_rest"],
        format=fmt,
        save_to=str(path),
    )
    return sort_centers(tensors["means"], torch.arange(len(tensors["means"]))).numpy()


def read_plain_ply(path: Path) -> dict[str, np.ndarray]:
    """A standard 3DGS PLY (as splat-transform decodes to) as GaussianCloud arrays."""
    from plyfile import PlyData

    data = PlyData.read(str(path))["vertex"].data
    names = data.dtype.names
    n_rest = sum(1 for p in names if p.startswith("f_rest_"))

    def stack(keys: list[str]) -> np.ndarray:
        return np.stack([np.asarray(data[key], np.float32) for key in keys], axis=-1)

    rest = stack([f"f_rest_{i}" for i in range(n_rest)]) if n_rest else np.zeros((len(data), 0), np.float32)
    return {
        "means": stack(["x", "y", "z"]),
        "log_scales": stack([f"scale_{i}" for i in range(3)]),
        "quats": stack([f"rot_{i}" for i in range(4)]),
        "opacity_logits": np.asarray(data["opacity"], np.float32),
        "sh_dc": stack([f"f_dc_{i}" for i in range(3)]),
        "sh_rest": rest.reshape(len(data), 3, n_rest // 3).transpose(0, 2, 1).copy(),
    }


def splat_transform(tool: str, *args: str) -> None:
    subprocess.run([tool, "-q", "-w", *args], check=True)


def decode(tool: str, path: Path, work: Path) -> dict[str, np.ndarray]:
    """``path`` as splat-transform reads it (through a standard PLY it writes)."""
    splat_transform(tool, str(path), str(work / "decoded.ply"))
    return read_plain_ply(work / "decoded.ply")


def match_order(decoded_means: np.ndarray, input_means: np.ndarray) -> np.ndarray:
    """For each decoded row, the input row it came from (nearest centre; must be a permutation)."""
    distances = np.linalg.norm(decoded_means[:, None, :] - input_means[None, :, :], axis=-1)
    order = distances.argmin(axis=1)
    assert len(set(order.tolist())) == len(order), "rows could not be matched one to one"
    return order


def niantic_spz(name: str, model: dict, degree: int, version: int) -> None:
    """Write ``model`` with Niantic's C++ (through alspz), as it stands: no frame conversion."""
    import alspz

    n = len(model["means"])
    data = alspz.save_spz(
        model["means"],
        model["log_scales"],
        np.ascontiguousarray(model["quats"][:, [1, 2, 3, 0]]),
        model["opacity_logits"],
        model["sh_dc"],
        np.ascontiguousarray(model["sh_rest"].reshape(n, -1)) if degree else None,
        degree,
        version=version,
    )
    (HERE / name).write_bytes(data)
    back = alspz.load_spz(data)
    decoded = {
        "means": back["positions"],
        "log_scales": back["scales"],
        "quats": back["rotations"][:, [3, 0, 1, 2]],
        "opacity_logits": back["alphas"],
        "sh_dc": back["colors"],
        "sh_rest": np.asarray(back["sh"]).reshape(n, -1, 3) if degree else np.zeros((n, 0, 3), np.float32),
    }
    save(name, "stored", model, decoded)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--splat-transform", required=True, help="the splat-transform command (2.7.1)")
    tool = parser.parse_args().splat_transform
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        # gsplat 1.5.3's exporter: .splat (40 rows) and its compressed PLY (260 rows: two chunks)
        model = random_model(1, 40, 0, 0.0)
        order = gsplat_export(model, "splat", HERE / "gsplat-1.5.3.splat")
        centres = np.frombuffer((HERE / "gsplat-1.5.3.splat").read_bytes(), np.float32).reshape(-1, 8)[:, :3]
        assert (centres == model["means"][order]).all()
        save("gsplat-1.5.3.splat", "ply", rows(model, order))
        model = random_model(2, 260, 1, 2.0)
        order = gsplat_export(model, "ply_compressed", HERE / "gsplat-1.5.3.compressed.ply")
        decoded = decode(tool, HERE / "gsplat-1.5.3.compressed.ply", work)
        assert (match_order(decoded["means"], model["means"]) == order).all()
        save("gsplat-1.5.3.compressed.ply", "ply", rows(model, order), decoded)
        # SH degree 0: gsplat writes an "sh" element of no properties (splat-transform refuses it)
        model = random_model(8, 20, 0, 0.0)
        order = gsplat_export(model, "ply_compressed", HERE / "gsplat-1.5.3-sh0.compressed.ply")
        save("gsplat-1.5.3-sh0.compressed.ply", "ply", rows(model, order))
        # splat-transform 2.7.1 (PlayCanvas) from a standard PLY written by gsplat: compressed PLY and
        # SPZ v3 (Adobe's build of Niantic's library, which turns the PLY's frame into SPZ's) and v4
        model = random_model(3, 260, 2, 2.0)
        gsplat_export(model, "ply", work / "input.ply")
        splat_transform(tool, str(work / "input.ply"), str(HERE / "splat-transform-2.7.1.compressed.ply"))
        decoded = decode(tool, HERE / "splat-transform-2.7.1.compressed.ply", work)
        order = match_order(decoded["means"], model["means"])
        save("splat-transform-2.7.1.compressed.ply", "ply", rows(model, order), decoded)
        model = random_model(4, 40, 3, 0.9)
        gsplat_export(model, "ply", work / "input.ply")
        splat_transform(
            tool, "--spz-version", "3", str(work / "input.ply"), str(HERE / "splat-transform-2.7.1-v3.spz")
        )
        decoded = decode(tool, HERE / "splat-transform-2.7.1-v3.spz", work)
        save(
            "splat-transform-2.7.1-v3.spz",
            "ply",
            rows(model, match_order(decoded["means"], model["means"])),
            decoded,
        )
        gsplat_export(random_model(5, 5, 0, 0.0), "ply", work / "small.ply")
        splat_transform(
            tool, "--spz-version", "4", str(work / "small.ply"), str(HERE / "splat-transform-2.7.1-v4.spz")
        )
    # Niantic's C++ library (alspz 0.2.0's copy), versions 2 and 3
    niantic_spz("niantic-v2.spz", random_model(6, 40, 1, 0.9), 1, 2)
    niantic_spz("niantic-v3.spz", random_model(7, 40, 3, 0.9), 3, 3)


if __name__ == "__main__":
    main()
