"""Whether a model sits on the cameras it is scanned on: no verdict on a model that does not fit.

A model moved by a similarity the scan does not know, or trained on another scene, can still have
half its Gaussians inside the training views; its renders then show nothing of the photos (9-16 dB,
depending on the scene), its groups cover nothing and it would be called clean. The *render match*
(:func:`~stealth_ns.runs.imported.frame_match`: the PSNR of three training views rendered against
their photos) is measured against what a flat image of each photo's mean colour reaches: a model that
fits explains some of the photos and beats it, even early in training; one that does not, does not.
Below ``ScanConfig.render_match_floor`` dB above it, in every frame tried, the scan refuses the model
(docs/design/scan.md, "Does the model fit the cameras?").
"""

from __future__ import annotations

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.runs.imported import ImportedModel, describe_matches, frame_match


def render_matches(imported: ImportedModel) -> dict[str, dict[str, float]]:
    """Each frame tried -> its render match (``psnr``, dB), the flat image's (``flat_psnr``) and the share
    of Gaussians in view (``in_view``): those ``--frame auto`` measured, or the frame the model was
    loaded in, measured now."""
    return imported.frame_match or {imported.frame: frame_match(imported.run)}


def check_fit(imported: ImportedModel, floor: float) -> float:
    """The render match of the model in the frame it was loaded in, in dB above a flat image of each
    photo's mean colour; a one-line StealthNSError naming every frame tried when it is below ``floor``."""
    matches = render_matches(imported)
    chosen = matches[imported.frame]
    gain = chosen["psnr"] - chosen["flat_psnr"]
    if gain < floor:
        raise StealthNSError(
            f"the model {imported.run.config_path} fits none of the frames tried on the cameras of "
            f"{imported.run.data}: {describe_matches(matches)}; the floor is "
            f"{chosen['flat_psnr'] + floor:.1f} dB, {floor:g} dB above a flat image of each photo's mean "
            "colour (--render-match-floor, docs/design/scan.md): the model was trained on another scene, or "
            "in a frame the scan does not know"
        )
    return gain
