"""The viewer panel's logic without a browser: view lists, camera jumps, view matching, overlays, the
render filter, the PSNR read-out, and the glue on a real (client-less) viser server, fed by a fake pipeline
that satisfies the panel's Protocol (and one check that the real pipeline does too)."""

from __future__ import annotations

import json
import math
import socket
import threading
import time
import typing
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import viser
import viser.transforms as vtf
from model_helpers import build_model, camera, pinhole_cameras
from nerfstudio.cameras.cameras import Cameras
from nerfstudio.viewer.render_state_machine import RenderStateMachine
from nerfstudio.viewer.utils import get_camera
from nerfstudio.viewer.viewer import VISER_NERFSTUDIO_SCALE_RATIO, Viewer

from stealth_ns.attack.config import AttackConfig
from stealth_ns.attack.density import DensityGrid
from stealth_ns.attack.record import PoisonView
from stealth_ns.images.io import save_png
from stealth_ns.images.metrics import masked_psnr
from stealth_ns.method.model import POISON_TAG
from stealth_ns.method.viewer import FILTER_OPTIONS, NO_VIEW, PanelModel, PanelSource, StealthAttackPanel
from stealth_ns.method.viewer.overlays import kde_voxel_cloud, poison_centres
from stealth_ns.method.viewer.poses import (
    VISER_SCALE,
    apply_camera_jump,
    c2w_from_viser_pose,
    camera_jump,
    frustum_spec,
    match_view,
    viser_pose_from_c2w,
)
from stealth_ns.method.viewer.scene import CENTRES_NODE, KDE_NODE, frustum_node
from stealth_ns.method.viewer.views import build_view_entries
from stealth_ns.raster.projection import viewmat_from_c2w


def look_at_c2w(eye, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """[3, 4] OpenGL camera-to-world at ``eye`` looking at ``target``."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    return np.stack([right, np.cross(back, right), back, eye], axis=1)


def orbit_cameras(n: int, width: int = 48, height: int = 32, radius: float = 3.0) -> Cameras:
    c2w = np.stack(
        [
            look_at_c2w((radius * math.cos(a), radius * math.sin(a), 0.8))
            for a in np.linspace(0, 2 * math.pi, n + 1)[:-1]
        ]
    )
    return pinhole_cameras(torch.from_numpy(c2w), width, height)


# ----------------------------------------------------------------------------------------------- view lists
def test_view_entries_roles_order_and_labels():
    train = ["images/a.png", "images/b.png", "images/c.png", "images/d.png"]
    entries = build_view_entries(train, ["images/t0.png", "images/t1.png"], poisoned=[2, 0])
    assert [(e.role, e.split, e.index) for e in entries] == [
        ("poisoned", "train", 2),
        ("poisoned", "train", 0),
        ("innocent", "train", 1),
        ("innocent", "train", 3),
        ("held-out", "eval", 0),
        ("held-out", "eval", 1),
    ]
    assert entries[0].label == "poisoned: images/c.png" and entries[-1].label == "held-out: images/t1.png"
    assert len({e.label for e in entries}) == len(entries)
    assert NO_VIEW not in {e.label for e in entries}
    with pytest.raises(ValueError, match="out of range"):
        build_view_entries(train, [], poisoned=[4])


# ----------------------------------------------------------------------------------------------- poses
@pytest.mark.parametrize("eye", [(3.0, 0.5, 1.0), (-1.0, -2.0, 0.3), (0.2, 0.1, -2.5)])
def test_viser_pose_round_trip(eye):
    c2w = look_at_c2w(eye, target=(0.1, -0.2, 0.05))
    wxyz, position = viser_pose_from_c2w(c2w)
    np.testing.assert_allclose(position, np.asarray(eye) * VISER_NERFSTUDIO_SCALE_RATIO)
    assert VISER_SCALE == VISER_NERFSTUDIO_SCALE_RATIO
    # viser's camera looks down its +Z: the nerfstudio camera's -Z
    np.testing.assert_allclose(vtf.SO3(wxyz).as_matrix()[:, 2], -c2w[:, 2], atol=1e-12)
    np.testing.assert_allclose(c2w_from_viser_pose(wxyz, position), c2w, atol=1e-12)


class _FakeConnection:
    def __init__(self) -> None:
        self.messages: list = []

    def queue_message(self, message) -> None:
        self.messages.append(message)


class _FakeClient:
    """Enough of a viser ClientHandle for a real CameraHandle: atomic() and a message queue."""

    def __init__(self) -> None:
        self._websock_connection = _FakeConnection()
        self.camera = viser.CameraHandle(self)
        state = self.camera._state
        state.position, state.look_at = np.array([3.0, 3.0, 3.0]), np.zeros(3)
        state.up_direction, state.fov, state.aspect = np.array([0.0, 0.0, 1.0]), 1.3, 1.5
        state.update_timestamp = time.time()
        self.camera._update_wxyz()

    def atomic(self):
        import contextlib

        return contextlib.nullcontext()


@pytest.mark.parametrize("eye", [(2.5, 1.0, 1.2), (-0.5, 2.0, -0.4), (1.0, -1.5, 2.5)])
def test_camera_jump_gives_the_view_nerfstudio_renders(eye):
    """Set a viser camera as the panel does, then build the render camera exactly as nerfstudio's viewer
    does (``Viewer.get_camera_state`` + ``get_camera``): same pose, same vertical focal length."""
    width, height = 64, 48
    c2w = look_at_c2w(eye, target=(0.2, 0.1, 0.0))
    fy = 55.4
    client = _FakeClient()
    apply_camera_jump(client.camera, camera_jump(c2w, fy, height))
    fake_viewer = SimpleNamespace(ready=False, current_camera_idx=3)
    state = Viewer.get_camera_state(fake_viewer, client)  # nerfstudio's own conversion, unbound
    render_camera = get_camera(state, height, width)
    np.testing.assert_allclose(render_camera.camera_to_worlds[0].double().numpy(), c2w, atol=1e-5)
    assert float(render_camera.fy) == pytest.approx(fy, rel=1e-5)
    assert float(render_camera.cx) == width / 2 and float(render_camera.cy) == height / 2
    np.testing.assert_allclose(
        viewmat_from_c2w(render_camera.camera_to_worlds).numpy(),
        viewmat_from_c2w(torch.from_numpy(c2w)[None].float()).numpy(),
        atol=1e-5,
    )
    # the orbit centre is on the optical axis, in front of the camera
    look = (client.camera.look_at - client.camera.position) / VISER_SCALE
    assert np.dot(look, -c2w[:, 2]) > 0 and np.linalg.norm(np.cross(look, -c2w[:, 2])) < 1e-6
    # and the panel recognises that pose as this view
    assert match_view(c2w_from_viser_pose(client.camera.wxyz, client.camera.position), c2w[None]) == 0


def test_camera_jump_renders_the_dataset_view():
    """The viewer's camera after a jump renders the same image as the dataset camera."""
    model, _ = build_model(n_points=200)
    model.eval()
    cam = camera(width=48, height=32, eye=(0.3, -0.2, 3.0))
    c2w = cam.camera_to_worlds[0].double().numpy()
    client = _FakeClient()
    apply_camera_jump(client.camera, camera_jump(c2w, float(cam.fy), 32))
    state = Viewer.get_camera_state(SimpleNamespace(ready=False, current_camera_idx=0), client)
    with torch.no_grad():
        via_viewer = model.get_outputs_for_camera(get_camera(state, 32, 48))["rgb"]
        direct = model.get_outputs_for_camera(cam)["rgb"]
    assert torch.allclose(via_viewer, direct, atol=1e-4)


def test_match_view_tolerances():
    poses = np.stack(
        [look_at_c2w((3.0, 0.0, 1.0)), look_at_c2w((0.0, 3.0, 1.0)), look_at_c2w((3.003, 0.0, 1.0))]
    )
    assert match_view(poses[1], poses) == 1
    assert match_view(poses[0], poses) == 0  # nearest of the two within tolerance
    moved = poses[1].copy()
    moved[:, 3] += [0.02, 0.0, 0.0]
    assert match_view(moved, poses) is None
    assert match_view(moved, poses, pos_tol=0.05) == 1
    turned = poses[1].copy()
    turned[:, :3] = vtf.SO3.from_z_radians(math.radians(2.0)).as_matrix() @ turned[:, :3]
    assert match_view(turned, poses) is None
    assert match_view(turned, poses, rot_tol_deg=3.0) == 1
    assert match_view(poses[0], np.zeros((0, 3, 4))) is None


def test_frustum_spec():
    c2w = look_at_c2w((1.0, 2.0, 0.5))
    spec = frustum_spec(c2w, fy=50.0, width=64, height=48)
    assert spec.fov == pytest.approx(2 * math.atan(24 / 50))
    assert spec.aspect == pytest.approx(64 / 48)
    np.testing.assert_allclose(spec.position, [10.0, 20.0, 5.0])


# ----------------------------------------------------------------------------------------------- overlays
def test_poison_centres():
    means = torch.arange(12, dtype=torch.float32).reshape(4, 3)
    tags = torch.tensor([0.0, 1.0, 0.0, 1.0])
    np.testing.assert_array_equal(poison_centres(means, tags), means[[1, 3]].numpy())
    assert poison_centres(means, torch.zeros(4)).shape == (0, 3)


def test_kde_voxel_cloud_threshold_colours_and_cap():
    kde = np.zeros((4, 3, 2), np.float32)
    kde[0, 0, 0], kde[1, 2, 1], kde[3, 1, 0] = 1.0, 0.6, 0.2
    grid = DensityGrid(values=np.zeros_like(kde), origin=np.array([-1.0, 0.0, 2.0]), voxel_size=0.5)
    cloud = kde_voxel_cloud(grid, kde, threshold=0.5)
    assert cloud.n_above == 2 and cloud.voxel_size == 0.5
    np.testing.assert_allclose(cloud.points, [[-0.75, 0.25, 2.25], [-0.25, 1.25, 2.75]])
    assert cloud.colors.dtype == np.uint8
    hot, cold = cloud.colors[0].astype(int), cloud.colors[1].astype(int)  # 1.0 -> red end, 0.5 -> blue end
    assert hot[0] > hot[2] and cold[2] > cold[0]
    assert kde_voxel_cloud(grid, kde, threshold=0.1).n_above == 3
    capped = kde_voxel_cloud(grid, np.ones_like(kde), threshold=0.0, max_points=5)
    assert capped.n_above == 24 and capped.points.shape == (5, 3)
    assert kde_voxel_cloud(grid, np.zeros_like(kde)).points.shape == (0, 3)
    with pytest.raises(ValueError, match="does not match"):
        kde_voxel_cloud(grid, np.zeros((2, 2, 2)))


# ----------------------------------------------------------------------------------------------- attack data
def write_attack_dir(attack_dir: Path, index: int, name: str, height: int = 32, width: int = 48) -> tuple:
    """An attack record as the first version wrote it (no cameras in the JSON, 8-bit PNGs): the panel must
    hand ``AttackRecord.read`` the training cameras."""
    rng = np.random.default_rng(index)
    target = rng.random((height, width, 3)).astype(np.float32)
    mask = np.zeros((height, width), bool)
    mask[8:20, 10:30] = True
    save_png(attack_dir / f"view{index:04d}_target.png", target)
    save_png(attack_dir / f"view{index:04d}_mask.png", mask.astype(np.float32))
    record = {"poisoned_views": [{"index": index, "name": name, "mask_pixels": int(mask.sum())}]}
    (attack_dir / "attack.json").write_text(json.dumps(record))
    return np.round(target * 255) / 255, mask


# ----------------------------------------------------------------------------------------------- the panel
def tagged_model(n_points: int = 300):
    model, _ = build_model(n_points=n_points)
    tags = torch.zeros(n_points)
    tags[::3] = 1.0
    model.gauss_params[POISON_TAG].data = tags
    model.eval()
    return model


class FakeSource:
    """A pipeline as the panel sees it (:class:`PanelSource`): ``n_train`` training and ``n_eval`` held-out
    views on an orbit, named as users name them."""

    def __init__(self, model, n_train: int = 6, n_eval: int = 2, poison_views=(), attack_dir=None) -> None:
        cams = orbit_cameras(n_train + n_eval)
        self.model = model
        self.attack_dir: Path | None = attack_dir
        self.poison_views: list[PoisonView] = list(poison_views)
        self.train_cameras, self.eval_cameras = cams[:n_train], cams[n_train:]
        self.train_names = [f"images/f{i}.png" for i in range(n_train)]
        self.eval_names = [f"images/t{i}.png" for i in range(n_eval)]

    def split_views(self) -> dict[str, tuple[list[str], Cameras]]:
        return {"train": (self.train_names, self.train_cameras), "eval": (self.eval_names, self.eval_cameras)}


def test_fake_source_satisfies_the_protocol():
    source = FakeSource(tagged_model(30))
    assert isinstance(source, PanelSource) and isinstance(source.model, PanelModel)
    assert not isinstance(SimpleNamespace(model=source.model, attack_dir=None), PanelSource)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def server():
    srv = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    yield srv
    srv.stop()


def set_up_panel(pipeline: PanelSource, server, run_dir: Path) -> StealthAttackPanel:
    panel = StealthAttackPanel(pipeline)
    panel.install(server)
    viewer = SimpleNamespace(
        viser_server=server,
        log_filename=run_dir / "viewer_log_filename.txt",
        train_lock=threading.Lock(),
        config=SimpleNamespace(camera_frustum_scale=0.1),
        camera_handles={
            i: SimpleNamespace(visible=True) for i in range(len(pipeline.split_views()["train"][1]))
        },
        hide_images=SimpleNamespace(visible=True),  # nerfstudio's "Hide Train Cams" button: cams shown
        current_camera_idx=0,
        step=7,
    )
    panel._setup(viewer)
    return panel


def render_in_viewer_thread(model, cam) -> torch.Tensor:
    """Render through ``get_outputs_for_camera`` from a thread that is a nerfstudio RenderStateMachine."""
    result = {}

    class FakeRenderThread(RenderStateMachine):
        def __init__(self) -> None:
            threading.Thread.__init__(self)

        def run(self) -> None:
            result["rgb"] = model.get_outputs_for_camera(cam)["rgb"]

    thread = FakeRenderThread()
    thread.start()
    thread.join()
    return result["rgb"]


def test_render_filter_applies_to_viewer_renders_only(tmp_path, server):
    model = tagged_model()
    panel = set_up_panel(FakeSource(model), server, tmp_path / "run")
    cam = camera(width=48, height=32)

    def direct(render_filter: str) -> torch.Tensor:
        model.render_filter = render_filter
        with torch.no_grad():
            out = model.get_outputs(cam)["rgb"]
        model.render_filter = "all"
        return out

    n_kept = {}
    for label, render_filter in FILTER_OPTIONS.items():
        panel._gui["filter"].value = label  # as a user would; the callback runs on viser's thread pool
        deadline = time.time() + 5
        while panel.render_filter != render_filter and time.time() < deadline:
            time.sleep(0.01)
        assert panel.render_filter == render_filter == model.viewer_render_filter
        with torch.no_grad():
            assert torch.allclose(render_in_viewer_thread(model, cam), direct(render_filter))
            # everything else (training, evaluation, metrics) still sees every Gaussian
            assert torch.allclose(model.get_outputs_for_camera(cam)["rgb"], direct("all"))
        assert model.render_filter == "all"
        model.render_filter = render_filter
        n_kept[render_filter] = model._gaussians_to_render()["means"].shape[0]
        model.render_filter = "all"
    assert n_kept == {"all": 300, "hide_poison": 200, "only_poison": 100}
    assert "get_outputs_for_camera" not in vars(model)  # the model's own render path, not a patched one
    with pytest.raises(ValueError, match="unknown render filter"):
        panel.set_render_filter("nope")


def test_panel_without_attack_folder_says_so(tmp_path, server):
    panel = set_up_panel(FakeSource(tagged_model()), server, tmp_path / "run")
    assert "no attack record" in panel._gui["status"].content
    assert str(tmp_path / "run" / "attack" / "attack.json") in panel._gui["status"].content
    # innocent and held-out views still work
    assert panel._gui["view"].options[0] == NO_VIEW
    assert [e.role for e in panel.entries] == ["innocent"] * 6 + ["held-out"] * 2
    panel._gui["kde"].value = True
    deadline = time.time() + 5
    while "no KDE" not in panel._gui["status"].content and time.time() < deadline:
        time.sleep(0.01)
    assert "no KDE" in panel._gui["status"].content
    # an unreadable record: its one-line message
    (tmp_path / "run" / "attack").mkdir(parents=True)
    (tmp_path / "run" / "attack" / "attack.json").write_text("{")
    panel.load_views()
    assert len(panel.views.problems) == 1 and "cannot read" in panel.views.problems[0]


def test_panel_from_attack_folder(tmp_path, server):
    model = tagged_model()
    run_dir = tmp_path / "run"
    target, mask = write_attack_dir(run_dir / "attack", 2, "images/f2.png")
    grid = DensityGrid(values=np.zeros((4, 4, 4), np.float32), origin=np.zeros(3), voxel_size=0.25)
    kde = np.linspace(0, 1, 64, dtype=np.float32).reshape(4, 4, 4)
    grid.save_npz(run_dir / "attack" / "density_grid.npz", extras={"kde": kde})
    pipeline = FakeSource(model)
    panel = set_up_panel(pipeline, server, run_dir)
    assert [v.index for v in panel.poisoned] == [2]
    assert panel._gui["view"].options[:2] == (NO_VIEW, "poisoned: images/f2.png")
    assert "100 poison Gaussians of 300" in panel._gui["status"].content
    nodes = panel._scene.nodes
    assert frustum_node(2) in nodes

    # overlays: poison centres and thresholded KDE voxels
    panel._gui["centres"].value = True
    panel._gui["kde"].value = True
    panel.refresh_overlays()
    assert "100 poison centres" in panel._gui["status"].content
    threshold = panel._gui["kde_threshold"].value
    assert f"{int((kde >= threshold).sum())} KDE voxels" in panel._gui["status"].content
    assert {CENTRES_NODE, KDE_NODE} <= set(nodes)
    attack_dir = run_dir / "attack"
    assert panel._kde.cloud(attack_dir, threshold) is panel._kde.cloud(attack_dir, threshold)  # cached
    panel._gui["centres"].value = False
    panel._gui["kde"].value = False
    panel.refresh_overlays()
    assert not {CENTRES_NODE, KDE_NODE} & set(nodes)

    # the read-out: a camera on the poisoned view gets its masked PSNR, computed as the metrics do
    cam = pipeline.train_cameras[2:3]
    with torch.no_grad():
        expected = masked_psnr(model.get_outputs(cam)["rgb"], target, mask)
    assert torch.equal(panel.poisoned[0].mask, torch.from_numpy(mask))
    assert panel.masked_psnr(2) == pytest.approx(expected)
    client = _FakeClient()
    (entry,) = [e for e in panel.entries if e.role == "poisoned"]
    apply_camera_jump(client.camera, panel.jump_for(entry))
    panel.update_readout(client.camera)
    deadline = time.time() + 10
    while "dB" not in panel._gui["readout"].content and time.time() < deadline:
        time.sleep(0.02)
    assert f"{expected:.2f} dB" in panel._gui["readout"].content
    assert "images/f2.png" in panel._gui["readout"].content
    # frusta: the ones at the view the camera sits on are hidden (they would cover the render) and come
    # back afterwards; nerfstudio's frustum of the poisoned view (clean image) gives way to the red one
    ours, theirs = nodes[frustum_node(2)], panel._viewer.camera_handles
    assert ours.visible is False and theirs[2].visible is False and theirs[1].visible is True
    (innocent,) = [e for e in panel.entries if e.role == "innocent" and e.index == 1]
    apply_camera_jump(client.camera, panel.jump_for(innocent))
    panel.update_readout(client.camera)
    assert panel._gui["readout"].content == "Camera on innocent view `images/f1.png`"
    assert ours.visible is True and theirs[2].visible is False and theirs[1].visible is False
    client.camera.position = client.camera.position + 1.0
    panel.update_readout(client.camera)
    assert panel._gui["readout"].content == "Camera: free"
    assert ours.visible is True and theirs[1].visible is True and theirs[2].visible is False
    panel._gui["frusta"].value = False
    panel.refresh_overlays()
    assert frustum_node(2) not in nodes and theirs[2].visible is True


def test_panel_prefers_the_pipelines_poisoned_views(tmp_path, server):
    target = torch.rand(32, 48, 3)
    mask = torch.zeros(32, 48, dtype=torch.bool)
    mask[4:10, 4:10] = True
    cams = orbit_cameras(8)
    view = PoisonView(
        index=4, name="images/f4.png", c2w=cams.camera_to_worlds[4], fx=1.0, fy=1.0, cx=1.0, cy=1.0,
        mask=mask, target=target,
    )  # fmt: skip
    panel = set_up_panel(FakeSource(tagged_model(), poison_views=[view]), server, tmp_path / "run")
    (data,) = panel.poisoned
    assert data is view
    assert "no attack record" not in panel._gui["status"].content
    assert panel._gui["view"].options[1] == "poisoned: images/f4.png"


def test_real_pipeline_satisfies_the_protocol(tiny_orbit_scene, server, tmp_path):
    """A real StealthPipeline has what ``PanelSource`` names, and the panel lists its views."""
    from attack_helpers import build_pipeline

    from stealth_ns.method.pipeline import StealthPipeline

    hints = typing.get_type_hints
    assert hints(StealthPipeline.split_views)["return"] == hints(PanelSource.split_views)["return"]
    pipeline = build_pipeline(tiny_orbit_scene, AttackConfig(density_guided=False))
    assert isinstance(pipeline, PanelSource) and isinstance(pipeline.model, PanelModel)
    assert isinstance(pipeline.stealth_attack, StealthAttackPanel)
    views = pipeline.split_views()
    names, cameras = views["train"]
    assert len(names) == len(cameras) and all(n.startswith("images/") for n in names)
    panel = set_up_panel(pipeline, server, tmp_path / "run")
    (view,) = pipeline.poison_views
    assert panel._gui["view"].options[1] == f"poisoned: {view.name}"
    assert len(panel.entries) == sum(len(split_names) for split_names, _ in views.values())
