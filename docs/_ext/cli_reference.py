"""The ``cli-help`` directive: a command's ``--help`` text, generated from its tyro definitions at build
time, so the CLI reference cannot drift from the code.

``{cli-help} stealth-ns scan`` renders ``stealth-ns scan --help`` (the class of
:data:`stealth_ns.cli.COMMANDS`); ``{cli-help} ns-train stealth-splat-lite --pipeline.attack`` renders the
attack's options (:class:`~stealth_ns.attack.config.AttackConfig`) with the flags ns-train gives them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import os

from docutils import nodes
from docutils.parsers.rst import Directive

HELP_COLUMNS = "80"


def _help_text(cls: type, prog: str) -> str:
    import tyro

    out = io.StringIO()
    columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = HELP_COLUMNS
    try:
        with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
            tyro.cli(cls, args=["--help"], prog=prog)
    finally:
        if columns is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = columns
    return "\n".join(line.rstrip() for line in out.getvalue().rstrip().splitlines())


def _attack_options() -> type:
    """A dataclass whose only options are ``--pipeline.attack.*``, as ns-train names them."""
    from stealth_ns.attack.config import AttackConfig

    pipeline = dataclasses.make_dataclass(
        "pipeline", [("attack", AttackConfig, dataclasses.field(default_factory=AttackConfig))]
    )
    pipeline.__doc__ = "The attack's options of ns-train stealth-splat and stealth-splat-lite."
    return dataclasses.make_dataclass(
        "options", [("pipeline", pipeline, dataclasses.field(default_factory=pipeline))]
    )


def help_for(words: list[str]) -> str:
    """The help text of ``words``: ``stealth-ns NAME ...`` or ``ns-train METHOD --pipeline.attack``."""
    if words[0] == "stealth-ns":
        from stealth_ns.cli import COMMANDS

        name = " ".join(words[1:])
        if name not in COMMANDS:
            raise ValueError(f"cli-help: no stealth-ns command {name!r}; commands: {', '.join(COMMANDS)}")
        return _help_text(COMMANDS[name], f"stealth-ns {name}")
    if words[0] == "ns-train" and words[2:] == ["--pipeline.attack"]:
        return _help_text(_attack_options(), f"ns-train {words[1]}")
    raise ValueError(f"cli-help: cannot render {' '.join(words)!r}")


class CliHelp(Directive):
    required_arguments = 1
    final_argument_whitespace = True

    def run(self) -> list[nodes.Node]:
        words = self.arguments[0].split()
        try:
            text = help_for(words)
        except ValueError as err:
            raise self.error(str(err)) from err
        env = self.state.document.settings.env
        env.cli_help_rendered = getattr(env, "cli_help_rendered", set()) | {" ".join(words)}
        block = nodes.literal_block(text, text)
        block["language"] = "text"
        return [block]


def _merge(app, env, docnames, other) -> None:
    env.cli_help_rendered = getattr(env, "cli_help_rendered", set()) | getattr(
        other, "cli_help_rendered", set()
    )


def _check_every_command(app, env) -> None:
    """A warning (an error under ``-W``) for each stealth-ns command no page renders."""
    from sphinx.util import logging

    from stealth_ns.cli import COMMANDS

    rendered = getattr(env, "cli_help_rendered", set())
    for name in COMMANDS:
        if f"stealth-ns {name}" not in rendered:
            logging.getLogger(__name__).warning(f"cli-help: stealth-ns {name} is in no page of the reference")


def setup(app) -> dict:
    app.add_directive("cli-help", CliHelp)
    app.connect("env-merge-info", _merge)
    app.connect("env-check-consistency", _check_every_command)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
