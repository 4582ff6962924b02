"""A faster start for the ``stealth-ns`` commands that import nerfstudio's splatfacto.

nerfstudio 1.1.5 decorates a helper of ``nerfstudio.models.splatfacto`` (``get_viewmat``) with
``@torch_compile()`` (``nerfstudio.utils.misc``), and ``torch.compile`` imports torch's dynamo and
inductor when it builds the decorator: seconds of each command's start, for a function no stealth-ns
code calls (measured in docs/design/testing.md, "Where a command's start-up goes").

:func:`install` puts a finder on ``sys.meta_path`` that, just before splatfacto is first imported,
replaces ``nerfstudio.utils.misc.torch_compile`` by :func:`deferred`: the decorator form compiles the
function the first time it is called, with the same arguments, so whoever calls it gets nerfstudio's
compiled function; a direct call (``torch_compile(module)``) is passed to nerfstudio's unchanged. Nothing
is imported before splatfacto is (a command that refuses its options still starts without torch).
"""

from __future__ import annotations

import functools
import importlib
import importlib.abc
import sys
from collections.abc import Callable
from typing import Any

#: the module whose import builds the decorator
TARGET = "nerfstudio.models.splatfacto"


def deferred(original: Callable[..., Any]) -> Callable[..., Any]:
    """``original`` (nerfstudio's ``torch_compile``) with its decorator form compiling on first call."""

    def torch_compile(*args: Any, **kwargs: Any) -> Any:
        if args:
            return original(*args, **kwargs)

        def decorate(fn: Callable[..., Any]) -> Callable[..., Any]:
            compiled: Callable[..., Any] | None = None

            @functools.wraps(fn)
            def call(*a: Any, **k: Any) -> Any:
                nonlocal compiled
                if compiled is None:
                    compiled = original(**kwargs)(fn)
                return compiled(*a, **k)

            return call

        return decorate

    torch_compile._stealth_ns_original = original  # type: ignore[attr-defined]
    return torch_compile


class _BeforeSplatfacto(importlib.abc.MetaPathFinder):
    """Patches ``torch_compile`` when splatfacto is about to be imported, then steps aside."""

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> None:
        if name != TARGET:
            return None
        sys.meta_path.remove(self)
        misc = importlib.import_module("nerfstudio.utils.misc")
        if getattr(misc.torch_compile, "_stealth_ns_original", None) is None:
            misc.torch_compile = deferred(misc.torch_compile)
        return None  # the usual finders import the module


def install() -> bool:
    """Defer splatfacto's compile in this process; False (nothing changed) when splatfacto is already
    imported or the finder is already in place."""
    if TARGET in sys.modules or any(isinstance(f, _BeforeSplatfacto) for f in sys.meta_path):
        return False
    sys.meta_path.insert(0, _BeforeSplatfacto())
    return True
