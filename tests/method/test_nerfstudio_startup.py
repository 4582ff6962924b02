"""stealth_ns.method.nerfstudio_startup: nerfstudio's external-method placeholders without inspect.stack()."""

from __future__ import annotations

import inspect

import pytest
from nerfstudio.configs import external_methods
from nerfstudio.configs.external_methods import ExternalMethodDummyTrainerConfig as Dummy

from stealth_ns.method import nerfstudio_startup


def _no_stack(*args, **kwargs):
    raise AssertionError("inspect.stack() was called")


def test_method_list_is_built_without_inspect_stack(monkeypatch):
    import nerfstudio.configs.method_configs as method_configs  # imports our entry points: installed

    assert getattr(Dummy.__post_init__, "_stealth_ns_original", None) is not None
    assert nerfstudio_startup.install()  # a second call changes nothing
    assert Dummy.__post_init__._stealth_ns_original.__qualname__.startswith("ExternalMethodDummy")
    monkeypatch.setattr(inspect, "stack", _no_stack)
    placeholders, descriptions = external_methods.get_external_methods()
    slugs = {slug for method in external_methods.external_methods for slug, _ in method.configurations}
    assert set(placeholders) == slugs == set(descriptions) and len(slugs) > 10
    assert slugs <= set(method_configs.all_methods)
    assert {"stealth-splat", "stealth-splat-lite", "splatfacto"} <= set(method_configs.all_methods)


def test_a_placeholder_chosen_on_the_command_line_still_offers_its_install(monkeypatch, capsys):
    """Created anywhere else (tyro, when the user names an uninstalled external method), nerfstudio's
    own __post_init__ runs: install instructions, the offer to install, exit 0."""
    nerfstudio_startup.install()
    asked = []
    monkeypatch.setattr(external_methods.Confirm, "ask", lambda *a, **k: asked.append(a) or False)
    method = next(m for m in external_methods.external_methods if m.pip_package)
    with pytest.raises(SystemExit) as exit_info:
        Dummy(method_name=method.configurations[0][0], method=method)
    assert exit_info.value.code == 0 and len(asked) == 1
    assert "pip install" in capsys.readouterr().out
