"""The "StealthAttack" panel of nerfstudio's viewer (viser): inspect poisoned vs innocent views.

One object, :class:`StealthAttackPanel`, is a public attribute of the pipeline (``pipeline.stealth_attack``),
installed by nerfstudio's viewer during ``ns-train`` (viewer on) and ``ns-viewer --load-config``.

The panel offers a view dropdown (jump to any poisoned, innocent-training or held-out view, with the view's
role), a poison-Gaussian render filter (shown / hidden / only poison, applied to the viewer's renders only),
3D overlays (poison centres, the thresholded KDE density as voxels coloured by density, the poisoned cameras'
frusta) and, while the camera sits on a poisoned view, that view's masked PSNR against its illusion target.

Modules, one concept each:

* :mod:`~stealth_ns.method.viewer.source`: what the panel reads from the pipeline (:class:`PanelSource`,
  its model :class:`PanelModel`) and the error it shows (:class:`PanelError`);
* :mod:`~stealth_ns.method.viewer.views`: the views it offers, their roles and poses (read once);
* :mod:`~stealth_ns.method.viewer.poses`: viser <-> nerfstudio poses, camera jumps, view matching,
  frusta (and the axis conventions);
* :mod:`~stealth_ns.method.viewer.overlays`: poison centres and KDE voxels as point clouds, density colours;
* :mod:`~stealth_ns.method.viewer.scene`: the panel's nodes in the viser scene and frustum visibility;
* :mod:`~stealth_ns.method.viewer.readout`: the masked-PSNR worker thread and its cache;
* :mod:`~stealth_ns.method.viewer.panel`: :class:`StealthAttackPanel`, the GUI and the glue.
"""

from stealth_ns.method.viewer.panel import FILTER_OPTIONS, NO_VIEW, StealthAttackPanel
from stealth_ns.method.viewer.source import PanelError, PanelModel, PanelSource

__all__ = ["FILTER_OPTIONS", "NO_VIEW", "PanelError", "PanelModel", "PanelSource", "StealthAttackPanel"]
