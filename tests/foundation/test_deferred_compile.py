"""splatfacto's ``@torch_compile()`` deferred to its first call (foundation/deferred_compile.py)."""

from __future__ import annotations

import subprocess
import sys

from stealth_ns.foundation.deferred_compile import deferred


def _recording_compile(log: list):
    """A stand-in for nerfstudio's ``torch_compile``: records each call, wraps what it compiles."""

    def torch_compile(*args, **kwargs):
        log.append((args, kwargs))
        if args:
            return ("direct", args, kwargs)

        def decorate(fn):
            return lambda *a, **k: ("compiled", fn(*a, **k))

        return decorate

    return torch_compile


def test_the_decorator_compiles_on_the_first_call_once_with_its_arguments():
    log: list = []
    lazy = deferred(_recording_compile(log))

    @lazy(dynamic=True)
    def add(a, b=1):
        """Adds."""
        return a + b

    assert log == [] and add.__name__ == "add" and add.__doc__ == "Adds."
    assert add(2, b=3) == ("compiled", 5)
    assert add(1) == ("compiled", 2)
    assert log == [((), {"dynamic": True})]


def test_a_direct_call_goes_to_nerfstudios_function_unchanged():
    log: list = []
    lazy = deferred(_recording_compile(log))
    module = object()
    assert lazy(module, mode="x") == ("direct", (module,), {"mode": "x"})
    assert log == [((module,), {"mode": "x"})]


def test_splatfacto_imported_after_install_leaves_inductor_unimported():
    code = (
        "import sys\n"
        "from stealth_ns.foundation import deferred_compile\n"
        "assert deferred_compile.install() and not deferred_compile.install()\n"
        "import nerfstudio.models.splatfacto as splatfacto, nerfstudio.utils.misc as misc\n"
        "assert not deferred_compile.install()\n"
        "print('torch._inductor.compile_fx' in sys.modules,"
        " hasattr(misc.torch_compile, '_stealth_ns_original'), splatfacto.get_viewmat.__name__)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split() == ["False", "True", "get_viewmat"]


def test_the_console_script_installs_it_before_the_command_runs(monkeypatch):
    from stealth_ns import cli
    from stealth_ns.foundation import deferred_compile

    calls: list[str] = []
    monkeypatch.setattr(deferred_compile, "install", lambda: calls.append("install"))
    monkeypatch.setattr(cli, "main", lambda argv=None: calls.append("main"))
    cli.entrypoint()
    assert calls == ["install", "main"]
