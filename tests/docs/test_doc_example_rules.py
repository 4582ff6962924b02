"""How a page's command lines are read and shrunk (tests/doc_examples.py), on small made-up pages."""

from __future__ import annotations

from pathlib import Path

import pytest
from doc_examples import at_test_scale, examples, not_run_reason

PAGE = """# A guide

```bash
stealth-ns make-scene --preset object --output scenes/object
# writes: scenes/object/transforms_train.json
ns-train stealth-splat-lite --vis tensorboard \\
    --pipeline.attack.injection-step 1500 nerfstudio-data --data scenes/orbit
```

```text
stealth-ns this-is-output-not-a-command
```

```bash
source .venv/bin/activate
make test
```
"""


def test_a_page_gives_its_commands_with_their_outputs_and_joined_lines():
    found = examples(PAGE, "guide.md")
    assert [e.source for e in found] == ["guide.md:4", "guide.md:6", "guide.md:15", "guide.md:16"]
    assert found[0].writes == ["scenes/object/transforms_train.json"]
    assert found[1].argv == [
        "ns-train", "stealth-splat-lite", "--vis", "tensorboard", "--pipeline.attack.injection-step", "1500",
        "nerfstudio-data", "--data", "scenes/orbit",
    ]  # fmt: skip
    assert [not_run_reason(e.argv) is not None for e in found] == [False, False, True, True]


@pytest.mark.parametrize(
    "line",
    [
        "stealth-ns scan --model a.ply | tee log",
        "stealth-ns scan --model $MODEL",
        "stealth-ns scan --model outputs/<timestamp>/config.yml",
        "python -c 'print(1)'",
        "stealth-ns make-scene --output a && stealth-ns check-data --data a",
    ],
)
def test_lines_a_reader_cannot_paste_as_they_are_are_refused(line: str):
    with pytest.raises(ValueError):
        examples(f"```bash\n{line}\n```\n", "guide.md")


def test_an_unclosed_block_and_a_stray_writes_line_are_refused():
    with pytest.raises(ValueError, match="never closed"):
        examples("```bash\nstealth-ns demo\n", "guide.md")
    with pytest.raises(ValueError, match="before any command"):
        examples("```bash\n# writes: x\n```\n", "guide.md")


def test_commands_are_shrunk_the_same_way_and_nothing_else_changes(tmp_path: Path):
    scene = at_test_scale(["stealth-ns", "make-scene", "--output", "s", "--resolution", "1008x756"], tmp_path)
    assert scene == ["stealth-ns", "make-scene", "--output", "s", "--resolution", "64x48", "--views", "16"]
    obj = at_test_scale(["stealth-ns", "make-scene", "--preset", "object", "--output", "o"], tmp_path)
    assert obj[-4:] == ["--resolution", "48x48", "--views", "24"]
    train = at_test_scale(
        ["ns-train", "stealth-splat", "--vis", "tensorboard", "nerfstudio-data", "--data", "s"], tmp_path
    )
    assert train[:2] == ["ns-train", "stealth-splat"] and train[-5:] == [
        "--vis",
        "tensorboard",
        "nerfstudio-data",
        "--data",
        "s",
    ]
    assert train[train.index("--max-num-iterations") + 1] == "60"
    assert train.index("--pipeline.attack.injection-step") < train.index("nerfstudio-data")
    with pytest.raises(ValueError, match="--vis tensorboard"):
        at_test_scale(["ns-train", "stealth-splat-lite", "nerfstudio-data", "--data", "s"], tmp_path)
    viewer = at_test_scale(["ns-viewer", "--load-config", "c.yml"], tmp_path, port=7100)
    assert viewer[-4:] == ["--viewer.websocket-host", "127.0.0.1", "--viewer.websocket-port", "7100"]
    report = ["stealth-ns", "report", "--poisoned", "p.yml", "--clean", "c.yml", "--output", "r"]
    assert at_test_scale(report, tmp_path) == report
