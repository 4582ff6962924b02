"""The attack's settings on a command line: how each command spells them, and the one function that
writes typed settings as options.

Two commands take the :class:`~stealth_ns.attack.config.AttackConfig` fields: ``ns-train`` as
``--pipeline.attack.NAME VALUE`` (nerfstudio turns tyro's flag conversion off, so a boolean takes
``True`` or ``False``), and ``stealth-ns poison-dataset`` / ``ipa-poison`` as ``--NAME`` (stealth-ns'
tyro makes a boolean a flag: ``--NAME`` / ``--no-NAME``). :class:`OptionSpelling` says which;
:data:`NS_TRAIN` and :data:`STEALTH_NS` are the two.

A run that sets some of the attack's options carries them typed, as :class:`AttackSettings` (fields
and values in the order given); :func:`command_options` writes them, and decisions read the
:class:`AttackConfig` they make (:meth:`AttackSettings.config`, :func:`draws_view_noise`), never the
option strings.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stealth_ns.attack.config import AttackConfig

__all__ = [
    "NS_TRAIN",
    "STEALTH_NS",
    "AttackSettings",
    "OptionSpelling",
    "command_options",
    "command_spelling",
    "draws_view_noise",
    "option_name",
    "option_words",
    "spelled_as",
]

_FIELDS = frozenset(f.name for f in dataclasses.fields(AttackConfig))


@dataclass(frozen=True)
class OptionSpelling:
    """How a command spells the attack's options."""

    prefix: str
    """Before the option's name: ``--pipeline.attack.`` (ns-train), ``--`` (stealth-ns commands)."""
    flags: bool
    """True: a boolean is a flag (``--NAME`` / ``--no-NAME``); False: it takes ``True`` or ``False``."""

    def name(self, field: str) -> str:
        """``t_min`` -> ``PREFIX t-min`` (as tyro spells a field)."""
        return self.prefix + field.replace("_", "-")


NS_TRAIN = OptionSpelling("--pipeline.attack.", flags=False)
"""``ns-train stealth-splat*``: ``--pipeline.attack.view-noise False``."""
STEALTH_NS = OptionSpelling("--", flags=True)
"""``stealth-ns poison-dataset`` / ``ipa-poison``: ``--no-view-noise``."""


_COMMAND_SPELLING: ContextVar[OptionSpelling] = ContextVar("attack_option_spelling", default=NS_TRAIN)


@contextlib.contextmanager
def spelled_as(spelling: OptionSpelling) -> Iterator[None]:
    """Within it (a ``with`` block or a decorated function), the attack's messages name options as
    ``spelling``: the spelling of the command the user typed (ns-train's outside any block)."""
    token = _COMMAND_SPELLING.set(spelling)
    try:
        yield
    finally:
        _COMMAND_SPELLING.reset(token)


def command_spelling() -> OptionSpelling:
    """The spelling of the command running: :data:`NS_TRAIN` unless inside :func:`spelled_as`."""
    return _COMMAND_SPELLING.get()


def option_name(field: str, spelling: OptionSpelling | None = None) -> str:
    """``t_min`` -> ``--pipeline.attack.t-min`` (or ``--t-min`` with :data:`STEALTH_NS`); None: the
    spelling of the command running (:func:`spelled_as`)."""
    return (spelling or _COMMAND_SPELLING.get()).name(field)


def option_words(field: str, value: Any, spelling: OptionSpelling | None = None) -> str:
    """One setting as the user would type it: ``--pipeline.attack.density-guided False``, or
    ``--no-density-guided`` with :data:`STEALTH_NS`; None: the command running's spelling."""
    return " ".join(command_options(AttackSettings.of(**{field: value}), spelling or _COMMAND_SPELLING.get()))


@dataclass(frozen=True)
class AttackSettings:
    """Some of the attack's options as a run gives them: (AttackConfig field, value) pairs in the order
    given. A field given twice takes its later value, as on a command line."""

    given: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        unknown = [name for name, _ in self.given if name not in _FIELDS]
        if unknown:
            raise ValueError(f"not AttackConfig fields: {', '.join(unknown)}")

    @classmethod
    def of(cls, **values: Any) -> AttackSettings:
        """Settings of ``values``, in keyword order."""
        return cls(tuple(values.items()))

    def then(self, **values: Any) -> AttackSettings:
        """These settings followed by ``values`` (in keyword order)."""
        return AttackSettings(self.given + tuple(values.items()))

    def __add__(self, other: AttackSettings) -> AttackSettings:
        return AttackSettings(self.given + other.given)

    def config(self, base: AttackConfig | None = None) -> AttackConfig:
        """The attack these settings make from ``base`` (None: the attack's defaults, ``AttackConfig()``)."""
        return dataclasses.replace(AttackConfig() if base is None else base, **dict(self.given))


def command_options(settings: AttackSettings, spelling: OptionSpelling = NS_TRAIN) -> tuple[str, ...]:
    """The command-line words of ``settings``, in their order, spelled as ``spelling`` says.

    Values: a boolean ``True`` / ``False`` (a flag with :attr:`OptionSpelling.flags`), a float in the
    shortest of ``{:g}`` and ``repr`` that reads back as the same number (``7.5``, ``100``), None as
    ``None``, a tuple as one word per item (``--pipeline.attack.views a.png b.png``).
    """
    words: list[str] = []
    for field, value in settings.given:
        if isinstance(value, bool) and spelling.flags:
            words.append(spelling.name(field) if value else spelling.prefix + "no-" + field.replace("_", "-"))
        else:
            words += [spelling.name(field), *_value_words(value)]
    return tuple(words)


def _value_words(value: Any) -> list[str]:
    if isinstance(value, (tuple, list)):
        return [word for item in value for word in _value_words(item)]
    if isinstance(value, float):
        short = f"{value:g}"
        return [short if float(short) == value else repr(value)]
    if isinstance(value, (bool, int, str, Path)) or value is None:
        return [str(value)]
    raise TypeError(f"no command-line spelling for {value!r}")


def draws_view_noise(attack: AttackConfig) -> bool:
    """Whether a training with ``attack`` draws the view-consistency noise: the attack on, its view
    noise on, with a strength above 0."""
    return bool(attack.enabled and attack.view_noise and attack.noise_sigma0 > 0)
