"""Nothing outside --output is deleted or written through a symbolic link (issue 32, class 1): what a
command replaces of its earlier output (defend's pruned runs, scan's cleaned run, the input-filter
retraining) is removed only inside --output."""

from __future__ import annotations

import pytest
import torch

from stealth_ns.defences.pruned_run import write_pruned_run
from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.output_folder import remove_tree


def _precious(folder):
    (folder / "run").mkdir(parents=True)
    (folder / "run" / "thesis.tex").write_text("years of work")
    return folder / "run" / "thesis.tex"


def test_remove_tree_stays_inside_the_output(tmp_path):
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    thesis = _precious(elsewhere)
    (out / "pruned").symlink_to(elsewhere)  # a link on the way: refused, nothing removed
    with pytest.raises(StealthNSError, match=r"pruned is a symbolic link to .*elsewhere"):
        remove_tree(out / "pruned" / "run", out)
    assert thesis.read_text() == "years of work"
    (out / "run").symlink_to(elsewhere / "run")  # the link itself: removed, not followed
    remove_tree(out / "run", out)
    assert not (out / "run").exists() and thesis.is_file()
    with pytest.raises(StealthNSError, match="is not inside --output"):
        remove_tree(elsewhere / "run", out)
    (out / "mine" / "a").mkdir(parents=True)
    remove_tree(out / "mine", out)
    assert not (out / "mine").exists()


def test_a_pruned_run_is_not_written_through_a_link(tiny_run_pair, tmp_path):
    config = tiny_run_pair[0]
    (checkpoint,) = (config.parent / "nerfstudio_models").glob("*.ckpt")
    n = torch.load(checkpoint, weights_only=True)["pipeline"]["_model.gauss_params.means"].shape[0]
    out, elsewhere = tmp_path / "defended", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (out / "pruned").symlink_to(elsewhere)
    keep = torch.ones(n, dtype=torch.bool)
    with pytest.raises(StealthNSError, match="symbolic link"):
        write_pruned_run(config, checkpoint, keep, out / "pruned", "view-support", {}, within=out)
    assert not any(elsewhere.iterdir())
    (out / "pruned").unlink()
    written = write_pruned_run(config, checkpoint, keep, out / "pruned", "view-support", {}, within=out)
    assert written.is_file() and out in written.parents
